"""``python -m leaderboard.engines``: the same plan's results from two engines, cell by cell and run by run.

The single side is the leaderboard tests' synthetic results directory; the fleet side is a copy in
which every trained run is re-written as a fleet run (``engine`` ``fleet:12``, a quarter of the wall
time) and a known set of runs got another metric, so every count the report prints is known.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from leaderboard.engines import load_results, paired_runs, report, wilcoxon_p
from morality_gym.norms.metric import bind_chain
from morality_gym.results.schema import write_run
from tests.leaderboard_data import REPO, make_results

#: The cell whose runs differ between the engines, and by how much per seed.
CHANGED = ("Utility", "Switch5", "PPO")
SHIFT = {41: 0.0, 42: 0.02, 43: -0.01}


@pytest.fixture(scope="module")
def sides(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, list[dict]]:
    base = tmp_path_factory.mktemp("engines")
    synthetic = make_results(base / "single")
    fleet = base / "fleet"
    shutil.copytree(base / "single", fleet)
    for record in synthetic.ok_records:
        row = dict(record)
        if row["learner"] != "Random":
            row["engine"] = "fleet:12"
            row["wall_time_s"] = record["wall_time_s"] / 4
            row["cpu_time_s"] = record["cpu_time_s"] / 4
        if (row["chain"], row["scenario"], row["learner"]) == CHANGED:
            shift = SHIFT[int(row["seed"])]
            row["metric"] = record["metric"] + shift
            for norm in row["relevant_norms"]:  # a run's metric is its functions' weighted mean: shift them alike
                row[f"mf_{norm}"] = record[f"mf_{norm}"] + shift
        write_run(fleet, row, bind_chain(row["chain"], row["env_id"]).chain.norm_names)
    return base / "single", fleet, synthetic.ok_records


def test_runs_pair_by_run_id_and_the_counts_are_the_known_ones(sides: tuple[Path, Path, list[dict]]) -> None:
    single, fleet, _records = sides
    s, f = load_results(single), load_results(fleet)
    pairs = paired_runs(s.runs, f.runs)
    changed = pairs.loc[(pairs["chain"] == CHANGED[0]) & (pairs["scenario"] == CHANGED[1]) & (pairs["learner"] == CHANGED[2])]
    assert len(changed) > 0
    assert (changed["diff"].abs() > 1e-9).sum() == (changed["seed"] != 41).sum()
    others = pairs.drop(changed.index)
    assert (others["diff"] == 0).all()
    text = report(s, f)
    line = next(row for row in text.splitlines() if row.startswith(f"| {CHANGED[0]} | {CHANGED[1]} | {CHANGED[2]} |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    identical = int((changed["seed"] == 41).sum())
    assert cells[6] == f"{identical}/{len(changed)}"
    expected_p = float(stats.wilcoxon(changed.loc[changed["diff"] != 0, "diff"].to_numpy()).pvalue)
    assert cells[7] == f"{expected_p:.2f}"
    mean_shift = float(np.mean([SHIFT[int(seed)] for seed in changed["seed"]]))
    assert float(cells[5]) == pytest.approx(mean_shift, abs=1e-3)


def test_per_learner_summary_and_compute(sides: tuple[Path, Path, list[dict]]) -> None:
    single, fleet, _records = sides
    text = report(load_results(single), load_results(fleet), ["paper"])
    summary = text.split("Per learner", 1)[1]
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.strip("|").split("|")]
            for line in summary.splitlines() if line.startswith("| ") and not line.startswith("| learner")}
    assert rows["PPO"][8] != rows["PPO"][7]  # fleet compute is a quarter of the single one
    assert rows["PPO"][9] == "4.0x"
    assert rows["Random"][9] == "1.0x"  # Random is trained alone by both engines
    assert rows["CPO"][5].split("/")[0] == rows["CPO"][5].split("/")[1]  # every CPO run identical
    assert "fleets of 12-12 runs" in text


def test_wilcoxon_edge_cases() -> None:
    assert wilcoxon_p(np.zeros(5)) == 1.0
    assert np.isnan(wilcoxon_p(np.array([0.0, 0.1])))
    assert 0 < wilcoxon_p(np.array([0.1, 0.2, -0.05, 0.3, 0.15])) <= 1


def test_cli_writes_the_report_and_refuses_a_bad_directory(sides: tuple[Path, Path, list[dict]], tmp_path: Path) -> None:
    single, fleet, _ = sides
    out = tmp_path / "engines.md"
    done = subprocess.run([sys.executable, "-m", "leaderboard.engines", str(single), str(fleet), "--out", str(out)],
                          check=False, cwd=REPO, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert out.read_text().startswith("# Table 1 by engine")
    bad = subprocess.run([sys.executable, "-m", "leaderboard.engines", str(single), str(tmp_path / "nope")],
                         check=False, cwd=REPO, capture_output=True, text=True)
    assert bad.returncode == 2
    assert "not a results directory" in bad.stderr and "Traceback" not in bad.stderr


def test_compute_compares_the_same_runs_when_one_side_is_unfinished(sides: tuple[Path, Path, list[dict]], tmp_path: Path) -> None:
    single, fleet, records = sides
    partial = tmp_path / "partial"
    shutil.copytree(single, partial)
    ppo = sorted(r["run_id"] for r in records if r["learner"] == "PPO")
    for run_id in ppo[: len(ppo) // 2]:  # half the single engine's PPO runs not finished yet
        for path in (partial / "runs").glob(f"{run_id}*"):
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    text = report(load_results(partial), load_results(fleet), ["paper"])
    summary = text.split("Per learner", 1)[1]
    row = next(line for line in summary.splitlines() if line.startswith("| PPO |"))
    assert row.strip("|").split("|")[9].strip() == "4.0x"  # not 2.0x: the fleet's extra runs are left out


def test_a_release_against_a_rerun_of_some_rows_with_names(sides: tuple[Path, Path, list[dict]], tmp_path: Path) -> None:
    """A newer engine reruns a few rows of a shipped Table 1: the release is one side, the rows the
    other; only the rows both have are compared, the others are counted in one line."""
    from leaderboard.release import create

    single, _fleet, records = sides
    release = create(single, "engines-test", root=tmp_path / "releases", tables=False)
    rerun = tmp_path / "rerun"
    kept = [r for r in records if (r["chain"], r["scenario"]) == CHANGED[:2]]
    for record in kept:
        row = dict(record)
        if (row["chain"], row["scenario"], row["learner"]) == CHANGED:
            shift = SHIFT[int(row["seed"])]
            row["metric"] = record["metric"] + shift
            for norm in row["relevant_norms"]:  # a run's metric is its functions' weighted mean: shift them alike
                row[f"mf_{norm}"] = record[f"mf_{norm}"] + shift
        # a rerun on a busy machine: ten times the wall time, half the CPU time
        row["wall_time_s"], row["cpu_time_s"] = record["wall_time_s"] * 10, record["cpu_time_s"] / 2
        write_run(rerun, row, bind_chain(row["chain"], row["env_id"]).chain.norm_names)
    out = tmp_path / "engines.md"
    done = subprocess.run([sys.executable, "-m", "leaderboard.engines", str(release), str(rerun), "--names", "release", "main",
                           "--protocol", "paper", "--out", str(out)], check=False, cwd=REPO, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    text = out.read_text()
    assert text.startswith(f"# Table 1 by engine: {release} (release) and {rerun} (main)")
    assert "| release mean ± seed sd | main mean ± seed sd | main − release |" in text
    cell_rows = [line for line in text.split("Per learner", 1)[0].splitlines()
                 if line.startswith("| ") and not line.startswith("| chain")]
    assert cell_rows and all(line.startswith(f"| {CHANGED[0]} | {CHANGED[1]} |") for line in cell_rows)
    n_rows = len({(r["chain"], r["scenario"]) for r in records if r["protocol"] == "paper"})
    assert f"Rows left out, one side has none of their cells: {n_rows - 1} only in release." in text
    changed = next(line for line in cell_rows if line.startswith(f"| {CHANGED[0]} | {CHANGED[1]} | {CHANGED[2]} |"))
    mean_shift = float(np.mean([SHIFT[int(r["seed"])] for r in kept if r["learner"] == CHANGED[2]]))
    assert float(changed.strip("|").split("|")[5]) == pytest.approx(mean_shift, abs=1e-3)
    summary = text.split("Per learner", 1)[1]
    ppo = next(line for line in summary.splitlines() if line.startswith("| PPO |"))
    assert ppo.strip("|").split("|")[9].strip() == "2.0x"  # compute is CPU time, not the busy wall time


def test_a_damaged_release_is_one_line(sides: tuple[Path, Path, list[dict]], tmp_path: Path) -> None:
    from leaderboard.release import create

    single, _, _ = sides
    release = create(single, "engines-damaged", root=tmp_path / "releases", tables=False)
    runs = release / "runs.parquet"
    runs.write_bytes(runs.read_bytes()[:-40])
    bad = subprocess.run([sys.executable, "-m", "leaderboard.engines", str(release), str(single)],
                         check=False, cwd=REPO, capture_output=True, text=True)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr, bad.stderr
    assert "engines-damaged" in bad.stderr and "checksum" in bad.stderr.lower(), bad.stderr
