"""The leaderboard site in a real browser (Debian's Chromium via Playwright), opened from file://.

Checks what only a browser can: the script sorts and filters the table, links work without a
server, every image (figures, layout picture, GIFs) actually decodes, and nothing is logged as an
error. Uses the synthetic build shared with test_leaderboard.py (built once per test process).
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from leaderboard.screenshot import CHROMIUM, launch_browser
from tests.leaderboard_data import LEARNERS, ROWS, BuiltSite, shared_build

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> BuiltSite:
    out = shared_build(tmp_path_factory.getbasetemp() / "leaderboard-shared")
    assert out.proc.returncode == 0, out.proc.stderr + out.proc.stdout
    return out


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    if not CHROMIUM.is_file():
        pytest.skip(f"Debian's chromium is not installed at {CHROMIUM} (apt-get install chromium, or make test)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright Python package is not installed")
    with tempfile.TemporaryDirectory(prefix="lb-chromium-") as profile, sync_api.sync_playwright() as pw:
        context = launch_browser(pw, Path(profile))
        try:
            yield context
        finally:
            context.close()


@pytest.fixture()
def page(browser: Any) -> Iterator[Any]:
    """A page that records console errors and uncaught exceptions (asserted empty by each test)."""
    page = browser.new_page()
    page.errors = []  # type: ignore[attr-defined]
    page.on("console", lambda msg: page.errors.append(f"console: {msg.text}") if msg.type == "error" else None)
    page.on("pageerror", lambda exc: page.errors.append(f"pageerror: {exc}"))
    yield page
    page.close()


def _visible_rows(page: Any) -> list[dict[str, str]]:
    return page.eval_on_selector_all(
        "#table1 tbody tr",
        """rows => rows.filter(r => !r.hidden).map(r => ({
            learner: r.dataset.learner, scenario: r.dataset.scenario, sweep: r.dataset.sweep,
            ours: r.cells[4].getAttribute('data-sort'), chain: r.dataset.chain}))""",
    )


def test_table_sorts_filters_and_links_to_scenarios(site: BuiltSite, page: Any) -> None:
    page.goto((site.site / "index.html").resolve().as_uri())
    all_rows = page.locator("#table1 tbody tr")
    assert all_rows.count() == len(ROWS) * len(LEARNERS) + len(LEARNERS)  # paper sweep + the corrected row
    initial = _visible_rows(page)
    assert len(initial) == len(ROWS) * len(LEARNERS)  # the primary sweep is selected at load
    assert {r["sweep"] for r in initial} == {"paper-quick"}
    assert page.locator('[data-count="table1"]').inner_text() == f"Showing {len(initial)} of {all_rows.count()} rows"

    # sort by "Ours": numbers sort descending first, then ascending
    header = page.locator("#table1 thead th", has_text="Ours")
    header.locator("button").click()
    assert header.get_attribute("aria-sort") == "descending"
    values = [float(r["ours"]) for r in _visible_rows(page)]
    assert values == sorted(values, reverse=True)
    assert values != [float(r["ours"]) for r in initial]  # the paper order is not already sorted
    header.locator("button").click()
    assert header.get_attribute("aria-sort") == "ascending"
    values = [float(r["ours"]) for r in _visible_rows(page)]
    assert values == sorted(values)

    # text column: learner names ascending
    page.locator("#table1 thead th", has_text="Learner").locator("button").click()
    learners = [r["learner"] for r in _visible_rows(page)]
    assert learners == sorted(learners, key=str.lower)

    # filters: one learner, then every sweep, then a chain
    page.select_option('select[data-filter="learner"]', "PPO")
    rows = _visible_rows(page)
    assert len(rows) == len(ROWS) and {r["learner"] for r in rows} == {"PPO"}
    page.select_option('select[data-filter="sweep"]', "")
    assert len(_visible_rows(page)) == len(ROWS) + 1
    page.select_option('select[data-filter="chain"]', "Utility")
    rows = _visible_rows(page)
    assert [(r["chain"], r["learner"]) for r in rows] == [("Utility", "PPO")]
    assert page.locator('[data-count="table1"]').inner_text() == f"Showing 1 of {all_rows.count()} rows"
    page.click('button[data-reset="table1"]')
    assert len(_visible_rows(page)) == len(initial)

    # Figure 2 images of the selected sweep are shown and decoded
    images = page.eval_on_selector_all("#figure2 img", "imgs => imgs.map(i => [i.naturalWidth, i.offsetParent !== null])")
    assert images and all(width > 0 for width, _ in images)
    assert sum(shown for _, shown in images) == len(ROWS)  # the corrected sweep's figure is hidden

    # follow a scenario link; every image there (layout, radar, GIFs) must load
    page.locator("#table1 tbody tr:not([hidden]) a", has_text="Switch5").first.click()
    page.wait_for_load_state("load")
    assert page.url.split("#")[0].endswith("/scenarios/Switch5.html")
    assert "paper-quick--Utility" in page.url
    page.wait_for_function("Array.from(document.images).every(i => i.complete)")
    loaded = page.eval_on_selector_all("img", "imgs => imgs.map(i => [i.getAttribute('src'), i.naturalWidth])")
    assert len(loaded) >= 2 + len(LEARNERS)  # layout picture, radar, one GIF per learner
    assert all(width > 0 for _, width in loaded), loaded
    assert any(src.endswith(".gif") for src, _ in loaded)
    assert page.locator("pre.ascii").count() == 1
    assert page.errors == []


def test_failed_run_page_and_runs_index(site: BuiltSite, page: Any) -> None:
    page.goto((site.site / "runs" / "index.html").resolve().as_uri())
    # issue 36: a source column and a sweep filter
    assert page.locator("#runs thead th", has_text="Source").count() == 1
    page.select_option('select[data-filter="sweep"]', "corrected-quick")
    sweeps = page.eval_on_selector_all("#runs tbody tr", "rows => rows.filter(r => !r.hidden).map(r => r.cells[3].innerText)")
    assert sweeps and set(sweeps) == {"corrected · quick"}
    assert set(page.eval_on_selector_all("#runs tbody tr", "rows => rows.filter(r => !r.hidden).map(r => r.cells[2].innerText)")) == {"your runs"}
    page.select_option('select[data-filter="sweep"]', "")
    page.select_option('select[data-filter="status"]', "failed")
    visible = page.eval_on_selector_all("#runs tbody tr", "rows => rows.filter(r => !r.hidden).map(r => r.cells[0].innerText)")
    assert visible == [site.data.failed_run_id]
    page.locator("#runs tbody tr:not([hidden]) a").first.click()
    page.wait_for_load_state("load")
    assert "policy loss is NaN at <step 4096>" in page.locator("#error").inner_text()  # escaped in HTML, shown verbatim
    assert "Traceback (most recent call last)" in page.locator("#error pre").inner_text()
    assert page.errors == []


def test_ranking_page_matrix_and_learning_curves(site: BuiltSite, page: Any) -> None:
    """Issue 13: the ranking page (aggregates with intervals, P(X > Y) matrix, profile figure), the
    matrix view of Table 1 (coloured cells, interval on hover) and a scenario's pooled learning curves."""
    page.goto((site.site / "index.html").resolve().as_uri())
    matrix = page.locator("#matrix-paper-quick")
    assert matrix.is_visible()
    assert matrix.locator("tbody tr:not(.chain)").count() == len(ROWS)  # issue 36: plus a header row per chain
    cells = matrix.locator("td.mcell")
    assert cells.count() == len(ROWS) * len(LEARNERS)
    titles = cells.evaluate_all("cs => cs.map(c => c.getAttribute('title'))")
    # three seeds per variant: every cell shows its per-seed means, too few seeds for an interval (issue 48)
    assert all(" · seeds " in t and "95% CI" not in t for t in titles), titles[:3]
    colours = set(cells.evaluate_all("cs => cs.map(c => getComputedStyle(c).backgroundColor)"))
    assert len(colours) > 3  # coloured by score, not one flat colour
    page.select_option('select[data-pane="sweep"]', "corrected-quick")  # issue 36: the grid's own sweep choice
    assert not matrix.is_visible() and page.locator("#matrix-corrected-quick").is_visible()
    # issue 36: a second sweep beside it, for comparison, labelled with its sweep and where its runs come from
    assert not page.locator('[data-pane-slot="beside"]').is_visible()  # no release here: nothing beside at load
    page.select_option('select[data-pane="beside"]', "paper-quick")
    beside = page.locator("#beside-paper-quick")
    assert beside.is_visible() and page.locator("#matrix-corrected-quick").is_visible()
    label = page.locator('[data-pane-beside="paper-quick"]').inner_text()
    assert "paper · quick" in label and "your runs in" in label and "not comparable: preset quick" in label
    page.select_option('select[data-pane="beside"]', "")
    assert not beside.is_visible()

    page.locator("nav.pages a", has_text="Ranking").click()
    page.wait_for_load_state("load")
    assert page.url.endswith("/ranking.html")
    section = page.locator("#ranking-paper-quick")
    table = section.locator("table.aggregates").first
    learners = table.locator("tbody tr").evaluate_all("rs => rs.map(r => r.dataset.learner)")
    assert learners == list(LEARNERS)
    first = table.locator("tbody tr").first.locator("td").all_inner_texts()
    assert first[2].startswith("[") and first[2].endswith("]")  # the mean's 95% interval
    improvement = section.locator("table.improvement")
    assert improvement.locator("tbody tr").count() == len(LEARNERS)
    assert improvement.locator("td.pcell").count() == len(LEARNERS) * (len(LEARNERS) - 1)
    assert "P(" in improvement.locator("td.pcell").first.get_attribute("title")
    assert "Rows in the ranking" in section.inner_text() and "normalised score aggregates" in section.inner_text()
    page.wait_for_function("Array.from(document.images).every(i => i.complete)")
    images = section.locator("img").evaluate_all("is => is.map(i => [i.getAttribute('src'), i.naturalWidth])")
    assert any("profile-score" in src and width > 300 for src, width in images), images
    assert page.locator("a[href$='data/runs.parquet']").count() >= 1
    assert page.errors == []

    page.goto((site.site / "scenarios" / "Switch5.html").resolve().as_uri())
    page.wait_for_function("Array.from(document.images).every(i => i.complete)")
    curves = page.locator("figure.curves img").evaluate_all("is => is.map(i => i.naturalWidth)")
    assert curves and all(width > 300 for width in curves)  # pooled learning curves, decoded
    assert page.locator("figure.tradeoff img").count() >= 1
    assert page.locator("table.violations tbody tr").count() >= 1
    assert page.errors == []
