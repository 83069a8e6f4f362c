"""The leaderboard: Table 1 numbers, the report of missing and failed runs, the files and the site.

Expected numbers are computed here with plain Python from the rows the synthetic generator wrote
(never with the leaderboard's own pandas code), and on a tiny frame whose means are worked out
by hand. The build is run once per module as a user runs it (``python -m leaderboard.build``).
"""

from __future__ import annotations

import csv
import math
import re
import statistics
from collections import defaultdict
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from PIL import Image

from leaderboard.runs.aggregate import CSV_COLUMNS, aggregate, compute_reference, reference_requests
from morality_gym.paper import table1
from morality_gym.results.manifest import planned_runs, write_manifest
from morality_gym.results.schema import read_runs
from tests.leaderboard_data import BOTH_PROTOCOLS, LEARNERS, ROWS, BuiltSite, run_build, shared_build, snapshot

PAPER = {(r.chain, r.scenario): r.paper for r in table1()}


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> BuiltSite:
    out = shared_build(tmp_path_factory.getbasetemp() / "leaderboard-shared")
    assert out.proc.returncode == 0, out.proc.stderr + out.proc.stdout
    return out


def _expected_cells(records: list[dict[str, Any]]) -> dict[tuple[str, ...], tuple[float, float, int]]:
    """(mean over all runs, stdev over seeds of per-seed means, n) per (protocol, preset, chain, scenario, learner)."""
    cells: dict[tuple[str, ...], list[tuple[int, float]]] = defaultdict(list)
    for r in records:
        if r["status"] == "ok":
            cells[(r["protocol"], r["preset"], r["chain"], r["scenario"], r["learner"])].append((r["seed"], r["metric"]))
    out = {}
    for key, values in cells.items():
        per_seed: dict[int, list[float]] = defaultdict(list)
        for seed, metric in values:
            per_seed[seed].append(metric)
        seed_means = [sum(v) / len(v) for v in per_seed.values()]
        out[key] = (sum(m for _, m in values) / len(values), statistics.stdev(seed_means), len(values))
    return out


def _csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


# ---------------------------------------------------------------------------------------- numbers
def test_tiny_frame_worked_out_by_hand() -> None:
    """Two variants x two seeds: mean 0.55, per-seed means 0.3 and 0.8, so std = 0.5 / sqrt(2)."""
    base = {"status": "ok", "error": None, "chain": "Utility", "scenario": "SwitchStandard", "protocol": "paper",
            "preset": "quick", "beta": 0.1, "max_steps": 200}
    rows = []
    for i, (learner, variant, seed, metric, mhh, relevant) in enumerate([
        ("PPO", "HumanA", 41, 0.2, 0.1, ["n_human_harm"]),
        ("PPO", "HumanB", 41, 0.4, 0.0, ["n_animal_harm"]),  # MHH not relevant here: excluded from the bar
        ("PPO", "HumanA", 42, 0.6, 0.5, ["n_human_harm"]),
        ("PPO", "HumanB", 42, 1.0, 0.9, ["n_human_harm"]),
        ("CPO", "HumanA", 41, 0.5, 0.5, ["n_human_harm"]),
        ("CPO", "HumanB", 41, 0.7, 0.5, ["n_human_harm"]),
    ]):
        rows.append(base | {"run_id": f"r{i}", "learner": learner, "variant": variant, "seed": seed, "metric": metric,
                            "env_id": f"SwitchStandard-{variant}-v1", "relevant_norms": relevant,
                            "mf_n_human_harm": mhh, "gif_path": None, "config": "{}", "traceback": None})
    planned = {"r9": {"run_id": "r9", "env_id": "SwitchStandard-HumanA-v1", "scenario": "SwitchStandard",
                      "variant": "HumanA", "chain": "Utility", "algo": "cpo", "learner": "CPO", "protocol": "paper",
                      "preset": "quick", "seed": 42}}
    lb = aggregate(pd.DataFrame(rows), planned)
    table = lb.table.set_index("learner")
    assert table.loc["PPO", "mean"] == pytest.approx(0.55)
    assert table.loc["PPO", "std"] == pytest.approx(0.5 / math.sqrt(2))
    assert table.loc["PPO", "n_runs"] == 4
    assert table.loc["PPO", "paper"] == pytest.approx(0.037)
    assert table.loc["CPO", "mean"] == pytest.approx(0.6)
    assert math.isnan(table.loc["CPO", "std"])  # one seed: no spread, not zero
    assert (table.loc["CPO", "n_runs"], table.loc["CPO", "n_planned"], table.loc["CPO", "n_missing"]) == (2, 3, 1)
    # Both cells cover 2 of SwitchStandard's 12 variants (issue 11): shown with their means, but marked
    # incomplete, never best and never compared with the paper.
    assert (table.loc["PPO", "n_variants"], table.loc["PPO", "n_variants_expected"]) == (2, 12)
    assert (table.loc["PPO", "n_seeds"], table.loc["PPO", "n_seeds_expected"]) == (2, 2)  # quick's 41 + seen 42
    assert not table.loc["PPO", "complete"] and not table.loc["CPO", "complete"]
    assert table.loc["PPO", "incomplete_reason"] == "4 of 24 runs (2/12 variants, 2/2 seeds; 20 never planned)"
    assert table.loc["CPO", "incomplete_reason"] == "2 of 24 runs (2/12 variants, 1/2 seeds; 1 missing; 21 never planned)"
    assert math.isnan(table.loc["PPO", "delta"]) and math.isnan(table.loc["CPO", "delta"])
    assert not bool(table.loc["CPO", "best"]) and not bool(table.loc["PPO", "best"])
    assert list(lb.missing["run_id"]) == ["r9"]
    norms = lb.norms_by_chain.set_index(["learner", "norm"])
    # MHH of PPO pools runs r0, r2, r3 only (r1 has it irrelevant): mean 0.5; per-seed 0.1 and 0.7
    assert norms.loc[("PPO", "n_human_harm"), "mean"] == pytest.approx(0.5)
    assert norms.loc[("PPO", "n_human_harm"), "n"] == 3
    assert norms.loc[("PPO", "n_human_harm"), "std"] == pytest.approx(statistics.stdev([0.1, 0.7]))
    assert ("PPO", "n_animal_harm") not in norms.index  # relevant in r1, but the frame has no mf_n_animal_harm


def test_runs_of_an_earlier_configuration_are_superseded_not_averaged() -> None:
    """A rerun after a config change leaves the old runs (other ids) on disk: each slot counts one run.

    Slot HumanA/41 has an old run (o1, finished first, no longer planned) and the current one (n1):
    n1 counts. Slot HumanB/41 has two runs that no manifest plans: the newer ok one counts, even
    though the older one is listed first. HumanA/42 has only an old run: it still counts.
    """
    from leaderboard.outputs.tables import superseded_markdown

    base = {"status": "ok", "error": None, "chain": "Utility", "scenario": "SwitchStandard", "protocol": "paper",
            "preset": "quick", "beta": 0.1, "max_steps": 200, "learner": "CPO", "relevant_norms": ["n_human_harm"],
            "gif_path": None, "config": "{}", "traceback": None}
    rows = []
    for run_id, variant, seed, metric, finished in [
        ("o1", "HumanA", 41, 0.9, "2026-11-20T10:00:00+00:00"),
        ("n1", "HumanA", 41, 0.1, "2026-11-21T10:00:00+00:00"),
        ("o2", "HumanB", 41, 0.8, "2026-11-20T10:00:00+00:00"),
        ("n2", "HumanB", 41, 0.3, "2026-11-21T10:00:00+00:00"),
        ("o3", "HumanA", 42, 0.5, "2026-11-20T10:00:00+00:00"),
    ]:
        rows.append(base | {"run_id": run_id, "variant": variant, "seed": seed, "metric": metric, "finished_at": finished,
                            "env_id": f"SwitchStandard-{variant}-v1", "mf_n_human_harm": metric})
    rows[2], rows[3] = rows[3], rows[2]  # file order must not matter
    planned = {"n1": {"run_id": "n1", "env_id": "SwitchStandard-HumanA-v1", "scenario": "SwitchStandard",
                      "variant": "HumanA", "chain": "Utility", "algo": "cpo", "learner": "CPO", "protocol": "paper",
                      "preset": "quick", "seed": 41}}
    lb = aggregate(pd.DataFrame(rows), planned)
    assert sorted(lb.runs["run_id"]) == ["n1", "n2", "o3"]
    assert dict(zip(lb.superseded["run_id"], lb.superseded["superseded_by"])) == {"o1": "n1", "o2": "n2"}
    cell = lb.table.set_index("learner").loc["CPO"]
    assert cell["mean"] == pytest.approx((0.1 + 0.3 + 0.5) / 3) and cell["n_runs"] == 3 and cell["n_missing"] == 0
    text = "\n".join(superseded_markdown(lb))
    assert "Superseded runs (2)" in text and "`o1`" in text and "`n2`" in text
    # A different beta is a different slot, not a replacement.
    other = pd.DataFrame(rows + [rows[0] | {"run_id": "b1", "beta": 0.2}])
    assert "b1" in set(aggregate(other, planned).runs["run_id"])


def test_csv_has_exactly_the_contract_columns(built: BuiltSite) -> None:
    with (built.results / "table1.csv").open() as fh:
        assert next(csv.reader(fh)) == CSV_COLUMNS == [
            "chain", "scenario", "learner", "mean", "std", "ci_low", "ci_high", "ci_low_mcse", "ci_high_mcse",
            "ci_kind", "seed_means", "borderline", "n_runs", "paper", "delta",
            "n_variants", "n_variants_expected", "n_seeds", "n_seeds_expected", "complete", "incomplete_reason",
            "delta_note"]


def _bold_expected(rows: list[dict[str, str]]) -> set[tuple[str, str, str]]:
    """(chain, scenario, learner) that must be bold, from the CSV alone: the highest mean among the
    complete cells of the row, whose interval overlaps no other complete cell's interval."""
    by_row: dict[tuple[str, str], list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        if r["learner"] in LEARNERS and r["complete"] == "True":
            by_row[(r["chain"], r["scenario"])].append(r)
    bold = set()
    for (chain, scenario), cells in by_row.items():
        top = max(cells, key=lambda r: float(r["mean"]))
        others = [r for r in cells if r is not top]
        if any(r["ci_low"] == "" for r in cells) or any(float(r["mean"]) == float(top["mean"]) for r in others):
            continue
        if all(float(top["ci_low"]) > float(r["ci_high"]) or float(top["ci_high"]) < float(r["ci_low"]) for r in others):
            bold.add((chain, scenario, top["learner"]))
    return bold


def test_csv_intervals_hold_the_mean_and_need_two_seeds(built: BuiltSite) -> None:
    """Three seeds per variant: every learner cell has an interval around its mean; references have none."""
    rows = _csv(built.results / "table1.csv")
    for r in rows:
        if r["learner"] not in LEARNERS:
            assert r["ci_low"] == r["ci_high"] == "", r
            continue
        low, mean, high = float(r["ci_low"]), float(r["mean"]), float(r["ci_high"])
        assert low <= mean <= high and high - low < 0.5, r
    # the bold rule is not vacuous on this data: some rows have a separated best, some do not
    assert 0 < len(_bold_expected(rows)) < len(ROWS) * 2 or len(_bold_expected(rows)) > 0


def test_table1_means_and_spreads_match_hand_computation(built: BuiltSite) -> None:
    expected = _expected_cells(built.data.records)
    rows = [r for r in _csv(built.results / "table1.csv") if r["learner"] in LEARNERS]
    assert len(rows) == len(ROWS) * len(LEARNERS)
    for r in rows:
        mean, std, n = expected[("paper", "quick", r["chain"], r["scenario"], r["learner"])]
        assert float(r["mean"]) == pytest.approx(mean, abs=2e-6), r
        assert float(r["std"]) == pytest.approx(std, abs=2e-6), r
        assert int(r["n_runs"]) == n, r
    # the corrected protocol lives in table1_all.csv, with its own numbers
    everything = _csv(built.results / "table1_all.csv")
    corrected = [r for r in everything if r["protocol"] == "corrected" and r["kind"] == "learner"]
    assert {(r["chain"], r["scenario"]) for r in corrected} == {BOTH_PROTOCOLS}
    for r in corrected:
        mean, std, _ = expected[("corrected", "quick", r["chain"], r["scenario"], r["learner"])]
        assert float(r["mean"]) == pytest.approx(mean, abs=2e-6)
        assert float(r["std"]) == pytest.approx(std, abs=2e-6)


def test_incomplete_cells_count_only_their_results(built: BuiltSite) -> None:
    rows = {r["learner"]: r for r in _csv(built.results / "table1.csv") if r["scenario"] == "Switch5" and r["learner"] in LEARNERS}
    counts = {learner: int(r["n_runs"]) for learner, r in rows.items()}
    assert counts == {"CPO": 20, "PPO": 21, "PPO Lag": 20, "PPO Shaped": 21, "Random": 21}  # 1 missing, 1 failed
    complete = {learner: r["complete"] for learner, r in rows.items()}
    assert complete == {"CPO": "False", "PPO": "True", "PPO Lag": "False", "PPO Shaped": "True", "Random": "True"}
    assert rows["CPO"]["incomplete_reason"] == "20 of 21 runs (7/7 variants, 3/3 seeds; 1 missing)"
    assert rows["PPO Lag"]["incomplete_reason"] == "20 of 21 runs (7/7 variants, 3/3 seeds; 1 failed)"
    assert rows["PPO"]["incomplete_reason"] == "" and rows["PPO"]["n_variants"] == rows["PPO"]["n_variants_expected"] == "7"
    assert rows["PPO"]["n_seeds"] == rows["PPO"]["n_seeds_expected"] == "3"


def test_paper_and_delta_columns(built: BuiltSite) -> None:
    """Issue 36: the synthetic sweep is preset quick, not the paper's budget, so no learner gets a Δ
    (the row says why); Random (exact) has no budget and keeps its Δ (issue 11: complete cells only)."""
    for r in _csv(built.results / "table1.csv"):
        published = PAPER[(r["chain"], r["scenario"])]
        if r["learner"] in LEARNERS:
            assert float(r["paper"]) == pytest.approx(published[r["learner"]])
            assert r["delta"] == "" and r["delta_note"] == "not comparable: preset quick", r
            continue
        if r["learner"] == "Random (exact)":
            assert float(r["paper"]) == pytest.approx(published["Random"])
        else:
            assert r["paper"] == "" and r["delta"] == "" and r["delta_note"] == ""
            continue
        assert r["complete"] == "True" and r["delta_note"] == ""
        assert float(r["delta"]) == pytest.approx(float(r["mean"]) - float(r["paper"]), abs=3e-6)


def test_delta_only_at_the_papers_budget_and_for_complete_cells() -> None:
    """Issue 36: Δ only where the runs are the paper's: preset paper and complete (else the reason)."""
    from leaderboard.runs.cells import delta_note

    cell = {"kind": "learner", "preset": "paper", "complete": True, "paper": 0.5}
    assert delta_note(cell) == ""
    assert delta_note(cell | {"complete": False}) == "not compared: incomplete"
    assert delta_note(cell | {"preset": "smoke"}) == "not comparable: preset smoke"
    assert delta_note(cell | {"preset": "smoke", "paper": math.nan}) == ""  # nothing to compare with
    assert delta_note(cell | {"kind": "reference", "preset": "smoke"}) == ""  # exact: no budget


def test_reference_rows_are_exact_and_cached(built: BuiltSite) -> None:
    from morality_gym.envs.registry import env_ids
    from morality_gym.evaluation.exact import exact_evaluate
    from morality_gym.evaluation.oracle import oracle

    rows = {r["learner"]: r for r in _csv(built.results / "table1.csv") if r["scenario"] == "SwitchSelfSacrifice"}
    ids = env_ids("SwitchSelfSacrifice")
    random_exact = sum(exact_evaluate("random", e, "UtilityAgentHarm", max_steps=200, beta=0.1).metric for e in ids) / len(ids)
    extremes = [oracle(e, "UtilityAgentHarm", beta=0.1, max_steps=200) for e in ids]
    best = sum(o.best.metric for o in extremes) / len(ids)
    worst = sum(o.worst.metric for o in extremes) / len(ids)
    assert float(rows["Random (exact)"]["mean"]) == pytest.approx(random_exact, abs=2e-6)
    assert float(rows["Oracle best"]["mean"]) == pytest.approx(best, abs=2e-6)
    assert float(rows["Oracle worst"]["mean"]) == pytest.approx(worst, abs=2e-6)
    assert rows["Random (exact)"]["n_runs"] == ""  # computed, not run
    cache = built.results / "cache" / "reference_rows.json"
    assert cache.is_file()
    lb = aggregate(read_runs(built.results), planned_runs(built.results))
    again = compute_reference(reference_requests(lb.table), cache)
    assert (again.computed, again.cached, again.errors) == (0, len(ROWS), {})
    assert "reference rows: 3 computed, 0 from cache" in built.proc.stdout


def test_per_norm_figure_data_pools_only_relevant_runs(built: BuiltSite) -> None:
    lb = aggregate(read_runs(built.results), planned_runs(built.results))
    data = lb.norms_by_chain.set_index(["protocol", "preset", "chain", "learner", "norm"])
    for chain, norm, learner in [("Utility", "n_animal_harm", "CPO"), ("DualProcessAgentHarm", "personal_action_caused_human_harm", "PPO"),
                                 ("UtilityAgentHarm", "agent_harm", "PPO Shaped")]:
        values = [(r["seed"], r[f"mf_{norm}"]) for r in built.data.ok_records
                  if r["protocol"] == "paper" and r["chain"] == chain and r["learner"] == learner and norm in r["relevant_norms"]]
        everywhere = [r for r in built.data.ok_records if r["protocol"] == "paper" and r["chain"] == chain and r["learner"] == learner]
        assert 0 < len(values) <= len(everywhere)
        per_seed: dict[int, list[float]] = defaultdict(list)
        for seed, v in values:
            per_seed[seed].append(v)
        row = data.loc[("paper", "quick", chain, learner, norm)]
        assert row["n"] == len(values)
        assert row["mean"] == pytest.approx(sum(v for _, v in values) / len(values))
        assert row["std"] == pytest.approx(statistics.stdev([sum(v) / len(v) for v in per_seed.values()]))
    # norms are in chain order (highest force first) for the x axis of Figure 2
    order = list(lb.norms_by_chain.query("protocol == 'paper' and chain == 'DualProcessAgentHarm' and learner == 'CPO'")["norm"])
    from morality_gym.norms.chain import get_chain

    assert order == [n for n in get_chain("DualProcessAgentHarm").norm_names if n in order]


# ---------------------------------------------------------------------------------------- markdown and latex
def _md_row(text: str, chain: str, scenario: str) -> list[str]:
    for line in text.splitlines():
        if line.startswith(f"| {chain} | {scenario} |"):
            return [c.strip() for c in line.strip().strip("|").split(" | ")]
    raise AssertionError(f"no row {chain} / {scenario}")


def test_markdown_bolds_the_best_learner_and_shows_paper_and_delta(built: BuiltSite) -> None:
    text = (built.results / "table1.md").read_text()
    primary = text.split("## Protocol `corrected`")[0]  # the primary (paper protocol) table comes first
    header = next(line for line in primary.splitlines() if line.startswith("| Chain |"))
    columns = [c.strip() for c in header.strip().strip("|").split(" | ")]
    expected = _expected_cells(built.data.records)
    bold = _bold_expected(_csv(built.results / "table1.csv"))
    assert "**bold** = highest mean of the row whose 95% interval overlaps no other learner's" in text
    assert "**not comparable: preset quick**: these learners trained at another budget" in primary
    for chain, scenario in ROWS:
        cells = dict(zip(columns, _md_row(primary, chain, scenario)))
        means = {lr: expected[("paper", "quick", chain, scenario, lr)][0] for lr in LEARNERS}
        for learner in LEARNERS:
            # issue 13: bold = best and separated by its interval (was: best mean)
            assert cells[learner].startswith("**") == ((chain, scenario, learner) in bold), (chain, scenario, learner)
            # three seeds per variant: no interval but the per-seed means (issue 48)
            assert "<br>seeds " in cells[learner] and "95% CI" not in cells[learner]
            assert f"{means[learner]:.3f}" in cells[learner]
            paper = PAPER[(chain, scenario)][learner]
            assert f"paper {paper:.3f}" in cells[learner]
            # issue 36: preset quick is not the paper's budget: no Δ, the reason instead
            assert "Δ — (not comparable: preset quick)" in cells[learner], cells[learner]
            if scenario == "Switch5" and learner in ("CPO", "PPO Lag"):  # incomplete (issue 11)
                assert "⚠ incomplete: 20 of 21 runs" in cells[learner]
        for column in ("Random (exact)", "Oracle best", "Oracle worst"):
            assert re.fullmatch(r"\d\.\d{3}", cells[column]), cells[column]


def test_markdown_reports_missing_and_failed_runs(built: BuiltSite) -> None:
    text = (built.results / "table1.md").read_text()
    section = text.split("## Missing and failed runs")[1]
    assert built.data.failed_run_id in section and built.data.missing_run_id in section
    assert "policy loss is NaN at &lt;step 4096&gt;" in section
    assert "1 run(s) failed and 1 planned run(s) have no result" in section
    assert "⚠ incomplete: 20 of 21 runs (7/7 variants, 3/3 seeds; 1 failed)" in text
    assert "⚠ incomplete: 20 of 21 runs (7/7 variants, 3/3 seeds; 1 missing)" in text


def test_latex_is_booktabs_with_the_interval_bold_rule(built: BuiltSite) -> None:
    tex = (built.results / "table1.tex").read_text()
    assert "\\toprule" in tex and "\\midrule" in tex and "\\bottomrule" in tex
    assert "overlaps no other learner" in tex  # the bold rule is stated under the table
    assert "not comparable: preset quick: trained at another budget" in tex  # issue 36
    body = [line for line in tex.splitlines() if line.endswith("\\\\") and ("PSS" in line or "SSS" in line or "Switch5" in line)]
    assert len(body) == len(ROWS)
    bold = _bold_expected(_csv(built.results / "table1.csv"))
    assert bold, "the synthetic profile should separate at least one row's best learner"
    abbreviation = {"PushSelfSacrifice": "PSS", "SwitchSelfSacrifice": "SSS", "Switch5": "Switch5"}
    for line in body:
        cells = [c.strip() for c in line.removesuffix("\\\\").split("&")]
        chain, scenario = next((c, s) for c, s in ROWS if abbreviation[s] == cells[1])
        for i, learner in enumerate(LEARNERS):
            # issue 13: bold = best and separated by its interval (was: one bold per row, the best mean)
            assert cells[2 + i].startswith("\\textbf{") == ((chain, scenario, learner) in bold), (chain, scenario, learner)
            # three seeds: the per-seed means, after a space ("\\scriptsizeseeds" would be an undefined command)
            assert "{\\scriptsize seeds " in cells[2 + i] or "--" in cells[2 + i]


def test_protocol_comparison(built: BuiltSite) -> None:
    text = (built.results / "table1_protocols.md").read_text()
    rows = [line for line in text.splitlines() if line.startswith("| DualProcessAgentHarm | PushSelfSacrifice |")]
    assert len(rows) == len(LEARNERS) + 3
    assert "Switch5" not in text  # run under one protocol only: nothing to compare
    expected = _expected_cells(built.data.records)
    cpo = next(line for line in rows if "| CPO |" in line)
    a = expected[("paper", "quick", *BOTH_PROTOCOLS, "CPO")][0]
    b = expected[("corrected", "quick", *BOTH_PROTOCOLS, "CPO")][0]
    assert f"{a:.3f} ±" in cpo and f"{b:.3f} ±" in cpo and f"{b - a:+.3f}" in cpo


# ---------------------------------------------------------------------------------------- figures and site
def test_figures_are_written(built: BuiltSite) -> None:
    figures = built.results / "figures"
    expected = [f"paper-quick/fig2_{c}.png" for c, _ in ROWS] + [f"paper-quick/radar_{c}_{s}.png" for c, s in ROWS]
    expected += [f"corrected-quick/fig2_{BOTH_PROTOCOLS[0]}.png"]
    for name in expected:
        with Image.open(figures / name) as image:
            assert image.width > 300 and image.height > 200, name
    assert sorted(p.stem for p in (figures / "learn").glob("*.svg") if ".updates" not in p.name) == sorted(built.data.learn_runs)


def test_site_is_self_contained_with_relative_links(built: BuiltSite) -> None:
    pages = sorted(built.site.rglob("*.html"))
    assert len(pages) == 4 + len(ROWS) + len(built.data.records)  # index, ranking (issue 13), track (35), runs index
    for page in pages:
        text = page.read_text()
        assert "http://" not in text and "https://" not in text, page
        assert "fetch(" not in text
        for target in re.findall(r'(?:src|href)="([^"]+)"', text):
            if target.startswith(("#", "data:")):
                continue
            assert not target.startswith("/") and "://" not in target, (page, target)
            resolved = (page.parent / target.split("#")[0]).resolve()
            assert resolved.is_file() and built.site.resolve() in resolved.parents, (page, target)
    for chain, scenario in ROWS:
        assert (built.site / "scenarios" / f"{scenario}.html").is_file()
    gifs = sorted(p.stem for p in (built.site / "gifs").glob("*.gif"))
    ok = {r["run_id"] for r in built.data.ok_records}
    assert set(gifs) == set(built.data.gif_runs) & ok  # issue 36: every run's episode, for its run page
    for run_id in gifs:
        assert f'src="../gifs/{run_id}.gif"' in (built.site / "runs" / f"{run_id}.html").read_text()


def test_site_reports_missing_and_failed(built: BuiltSite) -> None:
    index = (built.site / "index.html").read_text()
    status = index.split('id="status"')[1].split("</section>")[0]
    assert built.data.failed_run_id in status and built.data.missing_run_id in status
    assert "policy loss is NaN at &lt;step 4096&gt; &amp; training diverged" in status
    assert "<step 4096>" not in index  # escaped everywhere
    failed_page = (built.site / "runs" / f"{built.data.failed_run_id}.html").read_text()
    assert "Traceback (most recent call last)" in failed_page and "learner.learn(budget)" in failed_page
    assert "&lt;step 4096&gt;" in failed_page
    switch5 = (built.site / "scenarios" / "Switch5.html").read_text()
    assert "s42?" in switch5 and "s43✗" in switch5


def test_site_table_marks_best_and_links_scenarios(built: BuiltSite) -> None:
    index = (built.site / "index.html").read_text()
    rows = re.findall(r"<tr data-sweep=\"([^\"]+)\" data-chain=\"([^\"]+)\" data-scenario=\"([^\"]+)\" "
                      r"data-learner=\"([^\"]+)\" data-best=\"(\d)\" data-complete=\"(\d)\" data-bold=\"(\d)\">(.*?)</tr>",
                      index)
    assert len(rows) == len(ROWS) * len(LEARNERS) + len(LEARNERS)
    expected = _expected_cells(built.data.records)
    bold = _bold_expected(_csv(built.results / "table1.csv"))
    assert "overlaps no other learner" in index  # the bold rule is stated on the page
    for sweep, chain, scenario, learner, best, complete, is_bold, html in rows:
        protocol, preset = sweep.split("-")
        means = {lr: expected[(protocol, preset, chain, scenario, lr)][0] for lr in LEARNERS}
        assert (best == "1") == (learner == max(means, key=means.get))  # still shaded: highest mean
        # issue 13: <strong> = bold by the interval rule (was: highest mean)
        if sweep == "paper-quick":
            assert (is_bold == "1") == ((chain, scenario, learner) in bold), (chain, scenario, learner)
        assert ("<strong>" in html) == (is_bold == "1")
        assert f'href="scenarios/{scenario}.html#{sweep}--{chain}"' in html


def test_the_long_tables_paper_values_are_starred_on_rows_of_another_protocol(built: BuiltSite) -> None:
    """Issue 45: under the corrected protocol the paper's value (and a Δ against it) was shown as if the
    paper had run that protocol; it is marked paper* with a title saying it is the paper protocol's."""
    index = (built.site / "index.html").read_text()
    rows = re.findall(r'<tr data-sweep="([^"]+)" data-chain=[^>]*>(.*?)</tr>', index)
    starred = "value, obtained under the paper protocol\">"
    corrected = [html for sweep, html in rows if sweep.startswith("corrected-")]
    paper = [html for sweep, html in rows if sweep.startswith("paper-")]
    assert corrected and paper
    assert all(starred in html and "*</td>" in html for html in corrected)
    assert not any(starred in html for html in paper)
    assert "paper* and Δ* are against the paper's values" in index


def test_index_opens_on_the_grid_of_the_users_sweep_marked_not_comparable(built: BuiltSite) -> None:
    """Issue 36: Table 1 as the paper's grid first (the user's sweep, chain / scenario rows, a column
    per learner, interval and paper value per cell), the long table below it; preset quick says once
    that it is not comparable with the paper, and no cell carries a Δ."""
    index = (built.site / "index.html").read_text()
    assert index.index('id="matrix"') < index.index('id="table1-section"')
    assert 'href="#table1-section"' in index  # the long table, one click away
    grid = index.split('id="matrix-paper-quick"')[1].split("</table>")[0]
    assert grid.count('<tr class="chain"><th colspan="6">') == len(ROWS)  # one chain per row in this data
    cells = re.findall(r'<td class="num mcell[^"]*"[^>]*>(.*?)</td>', grid)
    assert len(cells) == len(ROWS) * len(LEARNERS)
    assert all(re.search(r'<span class="ci"[^>]*>seeds ', c) and '<span class="paper">paper ' in c and "Δ" not in c for c in cells)
    assert '<p class="nc"><strong>not comparable: preset quick</strong>' in index
    assert 'title="not comparable: preset quick">not comparable: preset quick</td>' in index  # the long table's Δ
    assert "results results" not in index and "your runs in <code>" in index
    assert '<option value="paper-quick" selected>' in index.split('data-pane="sweep"')[1].split("</select>")[0]


def test_a_sweep_that_leaves_out_learners_alike_under_both_protocols_says_where_they_are(built: BuiltSite) -> None:
    """Issue 32: the corrected Table 1 runs only the learners a protocol changes; its grid says that
    PPO and PPO Shaped train identically and where their cells are, and says nothing of Random, which
    the protocols evaluate differently. Issue 45: only built-in learners: a submitted policy (the torch
    example's PPO-Lag) was not trained by either protocol, and a user's learner is handed the protocol
    when it is built, so nothing says it trains identically."""
    from types import SimpleNamespace

    from leaderboard.runs.aggregate import Group
    from leaderboard.web.table1_grid import alike_note

    learners = {"Random": "random", "PPO": "ppo", "PPO Shaped": "ppo_shaped", "PPO Lag": "ppo_lag", "CPO": "cpo", "A2C": "a2c",
                "PPO-Lag (torch example)": "submitted"}
    ran = {"paper": list(learners), "corrected": ["PPO Lag", "CPO"]}
    runs = pd.DataFrame([{"protocol": p, "preset": "paper", "learner": label, "algo": learners[label]}
                         for p, labels in ran.items() for label in labels])
    groups = [Group("paper", "paper"), Group("corrected", "paper"), Group("corrected", "quick")]
    lb = SimpleNamespace(runs=runs, groups=groups,
                         group_table=lambda g: runs.loc[(runs["protocol"] == g.protocol) & (runs["preset"] == g.preset)])
    assert alike_note(lb, Group("corrected", "paper")) == (
        "PPO and PPO Shaped train identically under protocols corrected and paper, so this sweep does not "
        "run them again: their cells are those of paper · paper")
    one = SimpleNamespace(runs=runs.loc[runs["learner"] != "A2C"].loc[lambda r: r["learner"] != "PPO Shaped"], groups=groups,
                          group_table=lb.group_table)
    assert alike_note(one, Group("corrected", "paper")) == (
        "PPO trains identically under protocols corrected and paper, so this sweep does not run it again: its cells "
        "are those of paper · paper")
    assert alike_note(lb, Group("paper", "paper")) == ""  # it ran them all
    assert alike_note(lb, Group("corrected", "quick")) == ""  # no other sweep of preset quick
    # the built site's corrected sweep ran every learner: no note
    assert 'class="note alike"' not in (built.site / "index.html").read_text()


def test_the_index_opens_on_the_newest_own_sweep_beside_the_releases() -> None:
    """Issue 36: the sweep of the user's newest run first (not the release's, not an older sweep of
    theirs), the release's sweep of the same protocol beside it; without own runs, the primary."""
    from types import SimpleNamespace

    from leaderboard.runs.aggregate import Group
    from leaderboard.runs.opening import opening_groups, primary_choice

    sweeps = {("paper", "paper"): ("paper-table1-v1", "2026-11-20T10:00:00+00:00"),
              ("corrected", "paper"): ("paper-table1-v1", "2026-11-20T11:00:00+00:00"),
              ("paper", "quick"): ("results", "2026-11-25T09:00:00+00:00"),
              ("paper", "smoke"): ("results", "2026-11-26T21:03:00+00:00")}
    runs = pd.DataFrame([{"protocol": p, "preset": s, "source": src, "finished_at": at, "started_at": at}
                         for (p, s), (src, at) in sweeps.items()])
    table = pd.DataFrame([{"kind": "learner", "n_runs": 1, "protocol": p, "preset": s, "chain": "Utility",
                           "scenario": "Switch5"} for p, s in sweeps])
    groups = [Group(p, s) for p, s in sweeps]
    lb = SimpleNamespace(runs=runs, table=table, groups=groups, primary=Group("paper", "paper"))
    assert opening_groups(lb) == (Group("paper", "smoke"), Group("paper", "paper"))
    assert primary_choice(lb, None, None) == ("paper", "smoke")  # table1.csv / .tex: the user's sweep too
    assert primary_choice(lb, "corrected", None) == ("corrected", None)  # --protocol wins
    lb.runs = runs.loc[runs["source"] != "results"]
    assert opening_groups(lb) == (Group("paper", "paper"), None)  # a fresh clone: the release, nothing beside
    assert primary_choice(lb, None, None) == (None, None)  # choose_primary's rule, as before


def test_a_submission_does_not_replace_the_users_newest_sweep() -> None:
    """Issue 45: after a smoke sweep, a 2,048-step torch example submitted at preset paper opened the
    index on "paper · paper" (its 36 runs and the release), the 630 smoke runs out of view. The
    newest *sweep* decides; a submission only when the user ran no sweep. Every section says whose
    runs it holds."""
    from types import SimpleNamespace

    from leaderboard.runs.aggregate import Group
    from leaderboard.runs.opening import display_order, opening_groups, whose_runs

    rows = [("paper", "paper", "paper-table1-v1", "ppo", "2026-11-20T10:00:00+00:00"),
            ("corrected", "paper", "corrected-table1-v1", "cpo", "2026-11-20T11:00:00+00:00"),
            ("paper", "smoke", "results", "ppo", "2026-11-26T21:03:00+00:00"),
            ("paper", "paper", "results", "submitted", "2026-11-26T22:00:00+00:00")]
    runs = pd.DataFrame([{"protocol": p, "preset": s, "source": src, "algo": algo, "finished_at": at, "started_at": at}
                         for p, s, src, algo, at in rows])
    table = pd.DataFrame([{"kind": "learner", "n_runs": 1, "protocol": p, "preset": s, "chain": "Utility",
                           "scenario": "Switch5"} for p, s, *_ in rows])
    groups = [Group("paper", "paper"), Group("corrected", "paper"), Group("paper", "smoke")]
    lb = SimpleNamespace(runs=runs, table=table, groups=groups, primary=Group("paper", "paper"))
    assert opening_groups(lb) == (Group("paper", "smoke"), Group("paper", "paper"))
    assert display_order(lb) == [Group("paper", "smoke"), Group("paper", "paper"), Group("corrected", "paper")]
    newest = Group("paper", "smoke")
    assert whose_runs(lb, Group("paper", "smoke"), newest) == "Your newest sweep"
    assert whose_runs(lb, Group("paper", "paper"), newest) == "Your runs and a release's"
    assert whose_runs(lb, Group("corrected", "paper"), newest) == "A release's runs (none of yours)"
    only_submitted = SimpleNamespace(runs=runs.loc[runs["algo"] != "ppo"].reset_index(drop=True), table=table,
                                     groups=groups, primary=Group("paper", "paper"))
    assert opening_groups(only_submitted)[0] == Group("paper", "paper")  # no sweep of theirs: the submission


def test_one_meaning_of_bold_on_every_page(built: BuiltSite) -> None:
    """Issue 36: the ranking page bolds a best value only when its interval overlaps no other
    learner's (as Table 1), shades it otherwise, and every page states the marks once."""
    ranking = (built.site / "ranking.html").read_text()
    for table in re.findall(r'<table class="aggregates".*?</table>', ranking, re.DOTALL):
        rows = [re.findall(r'<td class="num( top)?"[^>]*>(.*?)</td><td class="num ci">\[(\S+), (\S+)\]</td>', row)
                for row in re.findall(r"<tr data-learner=.*?</tr>", table)]
        for column in zip(*rows):
            for top, value, low, high in column:
                others = [(float(lo), float(hi)) for t, v, lo, hi in column if (t, v, lo, hi) != (top, value, low, high)]
                separated = all(float(low) > hi or float(high) < lo for lo, hi in others)
                assert value.startswith("<strong>") == (bool(top) and separated), (value, low, high, others)
    for page in (built.site / "index.html", built.site / "ranking.html", built.site / "runs" / "index.html"):
        text = page.read_text()
        assert text.count('id="marks"') == 1 and "overlaps no other learner" in text.split('id="marks"')[1]


def test_ranking_page_says_which_rows_each_statistic_leaves_out(built: BuiltSite) -> None:
    """Issue 32: next to each statistic (and under each figure), the rows it leaves out and why, made
    from the rows the statistics were computed over (data/ranking_rows.csv), never written by hand."""
    import html

    from leaderboard.runs.aggregate import Group
    from leaderboard.web.ranking_page import left_out

    ranking = (built.site / "ranking.html").read_text()
    rows = pd.read_csv(built.site / "data" / "ranking_rows.csv", keep_default_na=False)
    sentences = []
    for (protocol, preset), part in rows.groupby(["protocol", "preset"]):
        records = part.to_dict("records")
        for measure, shown in (("score", "score"), ("metric", "metric"), ("metric", "improvement")):
            found = re.search(rf'<p class="note left-out" id="left-out-{Group(protocol, preset).slug}-{shown}">(.*?)</p>',
                              ranking)
            if found:  # a sweep without any ranked row shows no table, hence no sentence for it
                assert html.unescape(found.group(1)) == left_out(records, measure)
                sentences.append(found.group(1))
    assert sentences and all(s.startswith(("Leaves out ", "Over ")) for s in sentences)
    captions = re.findall(r"<figcaption>(.*?)</figcaption>", ranking)
    assert any("left out" in c or "Leaves out" in c for c in captions), captions


def test_run_pages_round_for_people_and_show_the_episode(built: BuiltSite) -> None:
    """Issue 36: wall and CPU time rounded (full precision stays in data/runs.csv)."""
    record = next(r for r in built.data.ok_records if r["run_id"] in built.data.gif_runs)
    page = (built.site / "runs" / f"{record['run_id']}.html").read_text()
    shown = re.search(r"<dt>Wall time</dt><dd>([^<]*)</dd>", page).group(1)
    assert re.fullmatch(r"\d+\.\d s|\d+m\d\ds \([\d,]+ s\)", shown), shown
    assert 'href="../data/runs.csv"' in page and f'src="../gifs/{record["run_id"]}.gif"' in page


def test_run_pages_show_config_curve_and_tracking(built: BuiltSite) -> None:
    learn_run = built.data.learn_runs[0]
    page = (built.site / "runs" / f"{learn_run}.html").read_text()
    assert f'src="../runs/img/{learn_run}.svg"' in page
    assert built.data.tracked_runs[learn_run] in page
    assert "&quot;n_steps&quot;: 2048" in page  # the config, pretty-printed and escaped
    untracked = next(r["run_id"] for r in built.data.ok_records if r["seed"] == 42)
    other = (built.site / "runs" / f"{untracked}.html").read_text()
    assert "not synced" in other and "No learn-time evaluations" in other


def test_build_leaves_results_runs_untouched(built: BuiltSite) -> None:
    assert snapshot(built.results / "runs") == built.runs_before


# ---------------------------------------------------------------------------------------- cli
def test_cli_fails_without_results(tmp_path: Path) -> None:
    proc = run_build(tmp_path / "nowhere", tmp_path / "site")
    assert proc.returncode != 0 and "does not exist" in proc.stderr
    (tmp_path / "empty").mkdir()
    proc = run_build(tmp_path / "empty", tmp_path / "site")
    assert proc.returncode != 0 and "no runs" in proc.stderr
    assert not (tmp_path / "site").exists()


def test_cli_with_only_planned_runs_succeeds_and_reports_them(tmp_path: Path) -> None:
    planned = [{"run_id": "abc123", "env_id": "SwitchStandard-HumanA-v1", "scenario": "SwitchStandard", "variant": "HumanA",
                "chain": "Utility", "algo": "ppo", "learner": "PPO", "protocol": "paper", "preset": "smoke", "seed": 41}]
    write_manifest(tmp_path / "results", "smoke", planned, preset="smoke", protocol="paper")
    proc = run_build(tmp_path / "results", tmp_path / "site", "--no-reference")
    assert proc.returncode == 0, proc.stderr
    assert "1 missing" in proc.stdout
    assert "abc123" in (tmp_path / "results" / "table1.md").read_text()
    assert "abc123" in (tmp_path / "site" / "index.html").read_text()


def test_cli_refuses_to_replace_a_foreign_directory(tmp_path: Path, built: BuiltSite) -> None:
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    tables = snapshot(built.results)
    proc = run_build(built.results, foreign, "--no-reference")
    assert proc.returncode != 0 and "refusing" in proc.stderr
    assert (foreign / "notes.txt").read_text() == "keep me"
    assert snapshot(built.results) == tables  # checked before anything is written


def test_a_learning_curve_says_how_many_episodes_each_point_averages() -> None:
    """Issue 45: a run page's learn-time "metric (MC)" 0.95 at step 2,048 above a final 0.441 read as a
    bug; the 0.95 was a 5-episode estimate. The legend says so, and the legend's entries do not overlap."""
    import json

    from leaderboard.web.run_figures import draw_learn

    frame = pd.DataFrame({"step": [0, 2048], "metric": [0.95, 0.9], "exact_metric": [0.47, 0.5]})
    record = {"learner": "PPO", "scenario": "Switch5", "variant": "Human", "seed": 41, "metric": 0.441,
              "eval_episodes": 100, "config": json.dumps({"learn_eval_episodes": 5})}
    svg = draw_learn(record, frame)
    legend = re.findall(r'<text x="([\d.]+)" y="36"[^>]*>([^<]*)</text>', svg)
    assert [label for _, label in legend] == ["MC metric (5 episodes each)", "exact metric", "final evaluation (100 episodes)"]
    starts = [float(x) for x, _ in legend]
    assert all(b - a > len(label) * 5.5 for (a, (_, label)), b in zip(zip(starts, legend), starts[1:]))
    assert draw_learn(record | {"config": "not json"}, frame).count("MC metric<") == 1  # unknown: no count claimed
