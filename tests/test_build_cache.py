"""Issue 21: a rebuild reuses what did not change and still writes what a fresh build writes.

The build caches the statistics, their figures, Figure 2 and the radars, the per-run SVG charts
and the run pages under ``<out>/cache``, keyed by content. These tests hold the two promises that
make that safe: a rebuild with nothing changed reuses everything and gives the same bytes as a
fresh build; an edited run redraws and re-renders exactly what depends on it (its chart and page,
and the statistics of the whole table), and the result is again the same as a fresh build's.
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from leaderboard.web.run_charts import chart_svg, learn_chart, nice_ticks, updates_chart
from morality_gym.results.schema import learn_path
from tests.leaderboard_data import REPO, make_results


def _build(results: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "leaderboard.build", "--results", str(results), "--out", str(out),
                           "--site", str(out / "site")], cwd=REPO, capture_output=True, text=True, timeout=600,
                          check=False)


def _digests(directory: Path) -> dict[str, str]:
    return {str(p.relative_to(directory)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(directory.rglob("*")) if p.is_file() and "cache" not in p.relative_to(directory).parts}


def _cache_line(proc: subprocess.CompletedProcess[str]) -> str:
    return next(line for line in proc.stdout.splitlines() if line.startswith("cache: "))


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("cache") / "results"
    make_results(root)
    return root


def test_rebuild_reuses_everything_and_equals_a_fresh_build(results: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    first = _build(results, out)
    assert first.returncode == 0, first.stderr
    n_pages = len(list((out / "site" / "runs").glob("*.html"))) - 1  # runs/index.html is not a run page
    assert "cache: nothing reused" in _cache_line(first)
    charts = int(re.search(r"(\d+) of (\d+) run chart", _cache_line(first)).group(2))
    assert charts > 0
    second = _build(results, out)
    assert second.returncode == 0, second.stderr
    line = _cache_line(second)
    assert line.startswith("cache: statistics, figures, statistics figures reused"), line
    assert f"0 of {charts} run chart(s) drawn, {n_pages} run page(s) reused" in line
    fresh = tmp_path / "fresh"
    (fresh / "cache").mkdir(parents=True)
    shutil.copy(out / "cache" / "reference_rows.json", fresh / "cache")
    assert _build(results, fresh).returncode == 0
    assert _digests(out) == _digests(fresh)


def test_an_edited_run_redraws_exactly_what_depends_on_it(results: Path, tmp_path: Path) -> None:
    edited = tmp_path / "results"
    shutil.copytree(results, edited)
    out = tmp_path / "out"
    assert _build(edited, out).returncode == 0
    charts_before = _digests(out / "figures" / "learn")
    pages_before = _digests(out / "site" / "runs")
    # one run's learn-time evaluations change (a re-run of it, say): its curve, its page (none: the
    # page links the chart by name) and the statistics' pooled curves depend on it
    path = next(p for p in sorted((edited / "runs").glob("*.learn.parquet")))
    run_id = path.name.removesuffix(".learn.parquet")
    frame = pq.read_table(path).to_pandas()
    frame["metric"] = (frame["metric"] * 0.5).round(6)
    pq.write_table(pq.read_table(path).from_pandas(frame, preserve_index=False), path)
    assert learn_path(edited, run_id) == path
    proc = _build(edited, out)
    assert proc.returncode == 0, proc.stderr
    line = _cache_line(proc)
    assert "statistics reused" not in line and "statistics, " not in line, line  # learn curves feed the statistics
    assert "figures" in line  # Figure 2 and the radars do not read learn-time evaluations
    assert re.search(r"\b1 of \d+ run chart\(s\) drawn", line), line
    charts_after = _digests(out / "figures" / "learn")
    assert sorted(n for n in charts_after if charts_after[n] != charts_before.get(n)) == [f"{run_id}.svg"]
    assert _digests(out / "site" / "runs").keys() == pages_before.keys()
    changed_pages = sorted(n for n, d in _digests(out / "site" / "runs").items() if d != pages_before[n])
    assert changed_pages == [f"img/{run_id}.svg"]
    fresh = tmp_path / "fresh"
    (fresh / "cache").mkdir(parents=True)
    shutil.copy(out / "cache" / "reference_rows.json", fresh / "cache")
    assert _build(edited, fresh).returncode == 0
    assert _digests(out) == _digests(fresh)


# ---------------------------------------------------------------------------------------- the charts
def test_nice_ticks_are_round_and_inside_the_range() -> None:
    assert nice_ticks(0, 1_000_000, 5) == [0, 200_000, 400_000, 600_000, 800_000, 1_000_000]
    assert nice_ticks(-0.8, 20.8, 5, integer=True) == [0, 5, 10, 15, 20]
    assert nice_ticks(0.5, 3.2, 4, integer=True) == [1, 2, 3]
    assert nice_ticks(1.0, 1.0) == [1.0]


def _svg(text: str) -> ET.Element:
    root = ET.fromstring(text)
    assert root.tag == "{http://www.w3.org/2000/svg}svg"
    return root


def _paths(root: ET.Element, colour: str) -> list[str]:
    """The ``d`` of the paths stroked in ``colour``, legend swatches (``M<x> 32h22``) left out."""
    return [d for p in root.iter("{http://www.w3.org/2000/svg}path") if p.get("stroke") == colour
            and not (d := p.get("d", "")).endswith(" 32h22")]


def test_learn_chart_draws_both_metrics_the_final_line_and_escapes_the_title() -> None:
    learn = pd.DataFrame({"step": [0, 500, 1000], "metric": [0.2, 0.5, 0.9], "exact_metric": [0.25, np.nan, 0.85]})
    root = _svg(chart_svg(learn_chart(learn, 0.8, "PPO <x> & y")))
    assert root.find("{http://www.w3.org/2000/svg}title").text == "PPO <x> & y"
    mc = _paths(root, "#0072B2")
    assert any(d.count("L") == 2 for d in mc)  # the MC line through all three points
    assert any(d.count("h0") == 3 for d in mc)  # and a marker at each
    exact = _paths(root, "#D55E00")
    assert exact and all(d.count("M") == 2 and "L" not in d for d in exact)  # broken at the NaN
    assert len(_paths(root, "#555555")) == 1
    without = _svg(chart_svg(learn_chart(learn.drop(columns="exact_metric"), float("nan"), "t")))
    assert not _paths(without, "#D55E00") and not _paths(without, "#555555")


def test_updates_chart_shows_cpo_cases_and_steps_or_ppo_lag_passes() -> None:
    cpo = pd.DataFrame({"update": [1, 2, 3, 4], "cpo_case": [4, 3, 1, 4], "accept_step": [1, 0, 2, 3],
                        "ep_cost": [0.3, 0.2, 0.2, 0.1]})
    root = _svg(chart_svg(updates_chart(cpo, "CPO")))
    texts = [t.text for t in root.iter("{http://www.w3.org/2000/svg}text")]
    assert "accepted step (0 = none; 75% accepted)" in texts
    assert sum(d.count("h0") for d in _paths(root, "#009E73")) == 3  # accepted steps green
    assert sum(d.count("h0") for d in _paths(root, "#D55E00")) == 1  # the refused one orange
    lag = pd.DataFrame({"update": [1, 2, 3], "passes": [1, 3, 1], "lagrange_multiplier": [0.0, 0.1, 0.2],
                        "ep_cost": [0.3, 0.2, 0.1], "cpo_case": [None, None, None]})
    root = _svg(chart_svg(updates_chart(lag, "PPO Lag")))
    texts = [t.text for t in root.iter("{http://www.w3.org/2000/svg}text")]
    assert "passes per update (67% stopped after 1)" in texts and "Lagrange multiplier" in texts
    assert len(_paths(root, "#CC79A7")) == 1  # J_c


def test_computed_reference_rows_equal_the_cached_ones(tmp_path: Path) -> None:
    """A first build's reference rows are what later builds read from the cache, in the same order
    (a per-variant mean summed in another order differed in the last bit, so the first build's
    numbers and the statistics' cache key differed from every later build's)."""
    from leaderboard.runs.aggregate import compute_reference

    requests = [("Utility", "Push2OrSwitch", 0.1, 200)]
    computed = compute_reference(requests, tmp_path / "reference.json")
    cached = compute_reference(requests, tmp_path / "reference.json")
    assert (computed.computed, cached.cached) == (1, 1)
    assert json.dumps(computed.entries) == json.dumps(cached.entries)


def test_a_presets_seeds_are_read_without_torch() -> None:
    """The build asks ``morality_gym.results.presets`` for a preset's seeds; importing torch for that
    cost about a second of every build (the learner specs imported the wrappers, which import
    Stable-Baselines3)."""
    code = ("import sys, morality_gym.results.presets as p, runners.compose.search_path; p.preset_seeds('quick'); "
            "print('torch' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120,
                          check=True)
    assert proc.stdout.strip() == "False"


def test_the_site_build_loads_no_trainer() -> None:
    """The site (with its Generalisation page) and the track's release read a track's run files;
    their names came from ``runners.track``, the trainer, which loaded SB3 and torch (about a
    second and a half of every build) and made the leaderboard import a runner. They are now the
    results contract's (:mod:`morality_gym.results.track_runs`)."""
    code = ("import sys, leaderboard.build_stages, leaderboard.track_release, leaderboard.llm_track; "
            "print('torch' in sys.modules, 'stable_baselines3' in sys.modules, "
            "any(m == 'runners' or m.startswith('runners.') for m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120,
                          check=True)
    assert proc.stdout.strip() == "False False False"
