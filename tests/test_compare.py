"""``python -m leaderboard.compare``: before / after / paper per Table 1 cell, and the update diagnostics.

Runs on the synthetic results directory of the leaderboard tests (written through the real Parquet
contract). The "before" side is a ``table1_all.csv``-shaped file built here from the after side's
own cells with known shifts, so every verdict the report prints is known in advance.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from leaderboard.compare import load_side, report
from morality_gym.results.schema import write_updates
from tests.leaderboard_data import REPO, make_results


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("compare") / "results"
    synthetic = make_results(root)
    ppo_lag = [r["run_id"] for r in synthetic.ok_records if r["learner"] == "PPO Lag" and r["protocol"] == "paper"]
    cpo = [r["run_id"] for r in synthetic.ok_records if r["learner"] == "CPO" and r["protocol"] == "paper"]
    # Two PPO-Lag runs: 3 of 4 updates one pass; final multipliers 0.5 and 0.7.
    for run_id, final in zip(ppo_lag[:2], (0.5, 0.7)):
        write_updates(root, run_id, [
            {"update": u, "timesteps": 2048 * u, "passes": 1 if u < 4 else 3, "lagrange_multiplier": final * u / 4,
             "ep_cost": 0.1} for u in range(1, 5)])
    # One CPO run: cases 0, 0, 1, 1; the case-1 updates accept no step, the case-0 ones at step 1 and 3.
    write_updates(root, cpo[0], [
        {"update": u, "timesteps": 2048 * u, "cpo_case": case, "accept_step": step, "ep_cost": 0.2}
        for u, (case, step) in enumerate([(0, 1), (0, 3), (1, 0), (1, 0)], start=1)])
    return root


def _before_csv(after_cells: pd.DataFrame, path: Path) -> Path:
    """PPO Lag twice as far from the paper as now (so every complete row moves closer); CPO unchanged."""
    before = after_cells.copy()
    lag = before["learner"] == "PPO Lag"
    before.loc[lag, "mean"] = before.loc[lag, "paper"] + 2 * (before.loc[lag, "mean"] - before.loc[lag, "paper"])
    before.assign(kind="learner").to_csv(path, index=False)
    return path


def _rows(text: str, section: str) -> dict[tuple[str, str], list[str]]:
    body = text.split(f"## Protocol `{section}`", 1)[1].split("## Protocol", 1)[0]
    out = {}
    for line in body.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("| ") and cells[0] not in ("chain",):
            out[(cells[0], cells[1])] = cells[2:]
    return out


def test_verdicts_summary_and_incomplete_cells(results: Path, tmp_path: Path) -> None:
    after = load_side(results)
    before = load_side(_before_csv(after.cells, tmp_path / "table1_all.csv"))
    text = report(after, before, ["PPO Lag", "CPO"], ["paper"])
    rows = _rows(text, "paper")
    cells = after.cells.set_index(["protocol", "chain", "scenario", "learner"])
    complete_lag = 0
    for (chain, scenario), values in rows.items():
        _lag_before, lag_after, lag_paper, lag_verdict, cpo_before, cpo_after, _, cpo_verdict = values
        lag = cells.loc[("paper", chain, scenario, "PPO Lag")]
        assert lag_after.startswith(f"{lag['mean']:.3f}")
        assert lag_paper == f"{lag['paper']:.3f}"
        if bool(lag["complete"]):
            complete_lag += 1
            # moved from twice the distance to the distance: closer, unless both round to one distance
            expected = "closer" if abs(lag["mean"] - lag["paper"]) >= 5e-4 else "same"
            assert lag_verdict == expected
        else:  # incomplete: shown with counts, never judged
            assert "⚠" in lag_after and lag_verdict == ""
        if bool(cells.loc[("paper", chain, scenario, "CPO")]["complete"]):
            assert cpo_verdict == "same" and cpo_before == cpo_after
    assert complete_lag >= 2
    summary = re.search(r"\*\*PPO Lag\*\* \((\d+) rows complete on both sides\): (\d+) closer", text)
    assert summary and int(summary.group(1)) == complete_lag
    # The synthetic Switch5 row has a failed PPO Lag run and a missing CPO run: both incomplete.
    assert "⚠" in rows[("Utility", "Switch5")][1] and "⚠" in rows[("Utility", "Switch5")][5]


def test_update_diagnostics(results: Path) -> None:
    text = report(load_side(results), None, protocols=["paper"])
    lag = next(line for line in text.splitlines() if line.startswith("- **PPO Lag**"))
    assert "8 updates in 2 runs" in lag and "75.0% of updates ran one pass" in lag and "max 3" in lag
    assert "final multiplier mean 0.600 (range 0.500-0.700)" in lag
    cpo = next(line for line in text.splitlines() if line.startswith("- **CPO**"))
    assert "cases {0: 2, 1: 2}" in cpo and "50.0% of updates accepted a step" in cpo
    assert "case 0: 100.0%, case 1: 0.0%" in cpo and "at backtracking step 2.00" in cpo
    assert "- **PPO**:" not in text  # learners without update files get no line


def test_cli_errors_and_output_file(results: Path, tmp_path: Path) -> None:
    def cli(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "leaderboard.compare", *args], cwd=REPO, check=False, capture_output=True,
                              text=True, timeout=300)

    bad = cli(str(tmp_path / "nope"))
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "neither a results directory" in bad.stderr
    wrong = cli(str(results), "--learner", "PPOLag")
    assert wrong.returncode == 2 and "did not" not in wrong.stderr and "PPO Lag" in wrong.stderr
    not_table = tmp_path / "x.csv"
    not_table.write_text("a,b\n1,2\n")
    assert "missing columns" in cli(str(results), "--before", str(not_table)).stderr
    out = tmp_path / "cmp.md"
    before = _before_csv(load_side(results).cells, tmp_path / "before.csv")
    done = cli(str(results), "--before", str(before), "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert out.read_text().startswith("# Table 1:") and "## Protocol `corrected`" in out.read_text()
