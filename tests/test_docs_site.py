"""The documentation site builds with ``mkdocs build --strict`` and works in a real browser.

The build (what ``make docs`` runs) fails on any warning: a broken link or anchor, a page left out
of the navigation, an API reference mkdocstrings cannot resolve. The browser tests serve the built
folder over HTTP (Material's search runs in a web worker, which ``file://`` does not allow) and
open it in Debian's Chromium: the index, a scenario page with its pictures decoded, the API page of
``morality_gym.make``, the formulas of the concepts page drawn as MathML, and the search. Requests
to other hosts are refused, so the test runs offline. With ``DOCS_SHOTS=DIR`` it also saves
screenshots of four pages to DIR. The formulas are rendered while the site builds
(docs/_hooks/mathml.py); a formula that cannot be rendered fails the build, naming its page.
"""

from __future__ import annotations

import functools
import http.server
import os
import re
import socketserver
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = "PushOrSwitch"


@functools.cache
def hooks(name: str = "generate") -> Any:
    """A MkDocs hook of docs/_hooks/ (by default generate.py, which generates pages), imported by its path."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(f"docs_{name}", ROOT / "docs" / "_hooks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


# ------------------------------------------------------------------------------------------------ formulas


def _formula(tex: str, display: bool = False) -> str:
    """A formula as pymdownx.arithmatex (generic mode) leaves it in a page's HTML."""
    import html

    tag, start, end = ("div", "\\[", "\\]") if display else ("span", "\\(", "\\)")
    return f'<{tag} class="arithmatex">{start}{html.escape(tex, quote=False)}{end}</{tag}>'


def test_formulas_become_mathml() -> None:
    render = hooks("mathml").render_formulas
    inline, display = _formula("N = \\langle \\sigma, d \\rangle"), _formula("a < \\frac{1}{\\beta}", display=True)
    out, count = render(f"<p>A norm {inline} and</p>{display}", "concepts.md")
    assert count == 2 and "\\(" not in out and "\\[" not in out and "arithmatex" in out
    assert out.count("<math ") == 2 and 'display="inline"' in out and 'display="block"' in out
    assert "&#x0003C;" in out  # the escaped < of the TeX is a MathML operator, not markup
    out, _ = render(_formula("w_n \\, \\mathbb{1}[\\chi(n, t)]"), "concepts.md")
    assert "\U0001d7d9" in out and "mathvariant" not in out  # MathML Core ignores mathvariant: 𝟙 itself


@pytest.mark.parametrize(("tex", "why"), [
    ("x^", "MissingSuperScriptOrSubscriptError"),  # latex2mathml raises
    ("\\left( a", "ExtraLeftOrMissingRightError"),
    ("a \\notacommand b", "unknown command \\notacommand"),  # latex2mathml would pass these through
    ("\\frac{a}", "<mfrac> with 1 arguments"),
    ("\\begin{aligned} a &= b \\end{aligned}", "environment {aligned} is not supported"),
    ("\\text{a < b}", "malformed MathML"),
])
def test_a_bad_formula_fails_the_build_naming_its_page(tex: str, why: str) -> None:
    from mkdocs.exceptions import PluginError

    fine, broken = _formula("x^2"), _formula(tex, display=tex.startswith("\\begin"))
    with pytest.raises(PluginError) as caught:
        hooks("mathml").render_formulas(f"<p>Fine: {fine}</p><p>Broken: {broken}</p>", "how-to/broken-page.md")
    message = str(caught.value)
    assert "\n" not in message and message.startswith("how-to/broken-page.md: ")
    assert f'"{tex}"' in message and why in message, message


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("docs") / "site"
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)], cwd=ROOT,
                          capture_output=True, text=True, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"}, timeout=600,
                          check=False)
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{proc.stdout}\n{proc.stderr}"
    print(f"mkdocs build --strict: {time.perf_counter() - start:.1f}s")
    return out


def test_every_documented_command_exposes_the_parser_it_parses_with() -> None:
    """The command-line reference is made from each command's build_parser(); parse_args must use
    the same parser, so an option added to one shows on the page."""
    import importlib

    for module, _ in hooks().COMMANDS:
        parser = hooks().capture_parser(module)
        assert parser.prog.endswith(module), (module, parser.prog)
        mod = importlib.import_module(module + (".__main__" if module == "morality_gym" else ""))
        if hasattr(mod, "parse_args"):
            with pytest.raises(SystemExit) as exit_:
                mod.parse_args(["--help"])
            assert exit_.value.code == 0, module


def test_module_map_lists_every_module_with_its_docstring() -> None:
    page = hooks().module_map_page()
    for package in hooks().MAP_PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            if path.read_text(encoding="utf-8").strip():
                assert f"| `{path.name}` |" in page and f"`{path.parent.relative_to(ROOT).as_posix()}/`" in page, path
    import ast

    first = ast.get_docstring(ast.parse((ROOT / "runners" / "sweep.py").read_text())).splitlines()[0]
    sweep = [line for line in page.splitlines() if line.startswith("| `sweep.py` |")]
    assert len(sweep) == 1 and hooks()._cell(first) in sweep[0]
    assert "(no docstring)" not in page  # every module says what it is for


def test_site_has_every_generated_page(site: Path) -> None:
    import morality_gym

    for name, scenario in morality_gym.scenarios().items():
        page = (site / "envs" / f"{name}.html").read_text()
        for variant in scenario.variants:
            env_id = scenario.env_id(variant)
            assert f"MoralityGym/{env_id}" in page, env_id
            assert (site / "envs" / "img" / f"{env_id}.png").stat().st_size > 1000, env_id
    for name, chains in hooks()._paper_chains().items():
        assert (site / "envs" / "img" / f"{name}.gif").stat().st_size > 1000, name
        assert all(chain in (site / "envs" / f"{name}.html").read_text() for chain in chains)
    cli = (site / "reference" / "cli.html").read_text()
    for module, _ in hooks().COMMANDS:
        assert f"python -m {module}" in cli, module
    assert "--update-stride" in cli and "--dry-run" in cli  # flags of leaderboard.release and runners.migrate
    config = (site / "reference" / "configuration.html").read_text()
    assert "fleet_size" in config and "rollout_cap" in config and "array_parallelism" in config
    schema = (site / "reference" / "results-schema.html").read_text()
    from morality_gym.results.schema import RUN_COLUMNS, UPDATE_COLUMNS

    assert all(f"<code>{c}</code>" in schema for c in RUN_COLUMNS + UPDATE_COLUMNS)


def test_every_picture_of_the_site_is_there(site: Path) -> None:
    """mkdocs --strict checks links between pages but not images: a Markdown picture whose file was
    never committed builds without a warning and shows a broken image (it happened: getting-started
    named a screenshot that did not exist)."""
    missing = []
    for page in site.rglob("*.html"):
        for src in re.findall(r'<img[^>]*\ssrc="([^"]+)"', page.read_text()):
            if src.startswith(("http:", "https:", "data:")):
                continue
            if not (page.parent / src.split("#")[0].split("?")[0]).is_file():
                missing.append(f"{page.relative_to(site)}: {src}")
    assert not missing, missing


def test_site_formulas_are_mathml(site: Path) -> None:
    """Every formula of the site was rendered while it built: no TeX left for a script, no script."""
    concepts = (site / "concepts.html").read_text()
    assert concepts.count("<math ") >= 40 and 'display="block"' in concepts
    for path in site.rglob("*.html"):
        text = path.read_text()
        assert not re.search(r'class="arithmatex">\s*(\\\(|\\\[|\$)', text), path
        assert not re.search(r"<script[^>]*mathjax", text, re.IGNORECASE), path


def test_catalogue_values_are_the_evaluators(site: Path) -> None:
    """The Random and oracle numbers on a scenario page are what the evaluators give."""
    from morality_gym import exact_evaluate, oracle

    page = (site / "envs" / f"{SCENARIO}.html").read_text()
    random = exact_evaluate("random", f"{SCENARIO}-Human-v1", "DualProcess").metric
    best = oracle(f"{SCENARIO}-Human-v1", "DualProcess")
    assert f"<td>DualProcess</td>\n<td>{random:.3f}</td>\n<td>{best.best.metric:.3f}</td>\n<td>{best.worst.metric:.3f}</td>" in page


# ------------------------------------------------------------------------------------------------ browser


@pytest.fixture(scope="module")
def served(site: Path) -> Iterator[str]:
    handler = functools.partial(_QuietHandler, directory=str(site))
    with socketserver.TCPServer(("127.0.0.1", 0), handler) as server:
        thread = threading.Thread(target=server.serve_forever, daemon=True)
        thread.start()
        try:
            yield f"http://127.0.0.1:{server.server_address[1]}"
        finally:
            server.shutdown()


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:
        pass


@pytest.fixture(scope="module")
def page(served: str) -> Iterator[Any]:
    from leaderboard.screenshot import CHROMIUM, launch_browser

    if not CHROMIUM.is_file():
        pytest.skip(f"Debian's chromium is not installed at {CHROMIUM} (apt-get install chromium, or make test)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright Python package is not installed")
    with tempfile.TemporaryDirectory(prefix="docs-chromium-") as profile, sync_api.sync_playwright() as pw:
        context = launch_browser(pw, Path(profile))
        context.route("**/*", lambda route: route.continue_() if route.request.url.startswith(served)
                      else route.abort())
        page = context.new_page()
        page.errors = []  # type: ignore[attr-defined]
        page.on("pageerror", lambda exc: page.errors.append(str(exc)))
        try:
            yield page
        finally:
            context.close()


def _shot(page: Any, name: str) -> None:
    folder = os.environ.get("DOCS_SHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(folder) / f"{name}.png"), full_page=False)


@pytest.mark.browser
def test_index_opens(page: Any, served: str) -> None:
    page.goto(f"{served}/index.html")
    assert page.title().startswith("MoralityGym")
    assert page.locator("nav").first.inner_text()
    gif = page.locator("article img").first
    gif.scroll_into_view_if_needed()
    page.wait_for_function("img => img.complete && img.naturalWidth > 0", arg=gif.element_handle(), timeout=10_000)
    _shot(page, "index")
    assert not page.errors, page.errors


@pytest.mark.browser
def test_scenario_page_shows_its_pictures(page: Any, served: str) -> None:
    page.goto(f"{served}/envs/{SCENARIO}.html")
    assert page.locator("h1").first.inner_text().startswith(SCENARIO)
    images = page.locator("article img")
    assert images.count() >= 11  # the GIF and one picture per variant
    for i in (0, 1, images.count() - 1):
        image = images.nth(i)
        image.scroll_into_view_if_needed()
        page.wait_for_function("img => img.complete && img.naturalWidth > 0", arg=image.element_handle(), timeout=10_000)
    page.goto(f"{served}/envs/{SCENARIO}.html")
    _shot(page, "scenario")
    assert not page.errors, page.errors


@pytest.mark.browser
def test_catalogue_tables_keep_their_words_whole(page: Any, served: str) -> None:
    """Issue 36: the catalogue index's "what happens" gets room beside the pictures (it was squeezed
    to a word per line), and env ids in "Registered Configurations" do not break mid-word."""
    page.goto(f"{served}/envs/index.html")
    widths = page.eval_on_selector_all(".catalogue-index table tbody tr",
                                       "rows => rows.map(r => r.cells[r.cells.length - 1].getBoundingClientRect().width)")
    assert widths and min(widths) >= 200, widths
    page.goto(f"{served}/envs/{SCENARIO}.html")
    ids = page.locator("article table td:first-child > code")
    assert ids.count() >= 10
    lines = ids.evaluate_all("cs => cs.map(c => c.getClientRects().length)")  # a wrapped inline box has 2+ rects
    assert set(lines) == {1}, lines
    assert not page.errors, page.errors


@pytest.mark.browser
def test_api_page_documents_make(page: Any, served: str) -> None:
    page.goto(f"{served}/reference/api.html")
    heading = page.locator('[id="morality_gym.api.make"]')
    assert heading.count() == 1
    assert "morality_gym.make" in heading.inner_text()
    assert "Create an env and the morality chain bound to it" in page.locator("article").inner_text()
    heading.scroll_into_view_if_needed()
    _shot(page, "api")
    assert not page.errors, page.errors


@pytest.mark.browser
def test_concepts_formulas_are_drawn(page: Any, served: str) -> None:
    """The browser draws the MathML itself: offline, with no script."""
    page.goto(f"{served}/concepts.html")
    formulas = page.locator("article math")
    assert formulas.count() >= 40
    sizes = page.evaluate("() => [...document.querySelectorAll('article math')].map(m => "
                          "[m.getAttribute('display'), m.getBoundingClientRect().width, m.getBoundingClientRect().height])")
    assert all(w > 0 and h > 0 for _, w, h in sizes), sizes
    # laid out as mathematics, not as a line of text: the fractions and sums of the display formulas
    # stand well above the tallest inline formula
    tallest_inline = max(h for display, _, h in sizes if display == "inline")
    assert all(h > 2 * tallest_inline for display, _, h in sizes if display == "block"), sizes
    text = page.locator("article").inner_text()
    assert "\\(" not in text and "\\[" not in text and "\\frac" not in text
    page.evaluate("document.getElementById('norms-and-modalities').scrollIntoView()")  # the first display formula
    _shot(page, "concepts_math")
    assert not page.errors, page.errors


@pytest.mark.browser
def test_search_finds_dualprocess(page: Any, served: str) -> None:
    page.goto(f"{served}/index.html")
    page.keyboard.press("/")  # Material's shortcut to the search box
    page.locator("input.md-search__input").press_sequentially("DualProcess", delay=20)  # typed: fill() sends no keys
    results = page.locator(".md-search-result__item")
    results.first.wait_for(timeout=20_000)
    assert results.count() >= 1
    assert "DualProcess" in page.locator(".md-search-result").inner_text()
    assert "matching document" in page.locator(".md-search-result__meta").inner_text()
    assert not page.errors, page.errors


def test_reference_pages_have_every_exported_name_and_every_command() -> None:
    """Issue 45: the API page lacked nine exported names (load_split, TrolleyVectorEnv, RewardCostSpec, ...)
    and the command-line page two commands (runners.track, leaderboard.track). The API page is made from
    ``morality_gym.__all__``; every module with a parser that runs as a program needs its line in COMMANDS."""
    import morality_gym

    page = hooks().api_page()
    missing = [name for name in morality_gym.__all__ if f"heading: morality_gym.{name}\n" not in page]
    assert missing == [], f"exported but not on the API page: {missing}"
    described = {module for module, _ in hooks().COMMANDS}
    commands = hooks().command_modules()
    assert {"runners.track", "leaderboard.track", "leaderboard.build", "morality_gym"} <= set(commands)
    gaps = [m for m in commands if m not in described]
    assert gaps == [], f"commands without a line in docs/_hooks/generate.py COMMANDS: {gaps}"
    cli = hooks().cli_page()
    assert all(f"## `python -m {m}`" in cli for m in commands)
