"""``python -m benchmarks.project_table1``: measured per-learner cost, priced over the full plan.

The measured side is the leaderboard tests' synthetic results directory (quick preset, three
Table 1 rows, five learners), whose wall times are known, so every rate the tool prints can be
recomputed here; the projection is checked against the plan the sweep itself makes.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.project_table1 import job_seconds, measured_rates, scenario_factors, table1_jobs
from runners.plan.estimate import makespan
from tests.leaderboard_data import REPO, make_results


@pytest.fixture(scope="module")
def measured(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict]]:
    base = tmp_path_factory.mktemp("projection")
    synthetic = make_results(base / "r")
    return base / "r", synthetic.ok_records


def test_makespan_takes_jobs_in_order_on_the_first_free_worker() -> None:
    assert makespan([5, 1, 1, 1], 2) == 5  # the three short jobs share the second worker
    assert makespan([1, 1, 1, 5], 2) == 6  # plan order matters: the long job starts last (5 if it went first)
    assert makespan([3, 3, 3], 1) == 9
    assert makespan([], 4) == 0


def test_rates_are_the_runs_core_seconds_per_step(measured: tuple[Path, list[dict]]) -> None:
    """Core-seconds are the runs' CPU time (runners.results_schema.compute_seconds), not their wall time."""
    results, records = measured
    rates = measured_rates(results, "paper", "quick", "single")
    ppo = [r for r in records if r["algo"] == "ppo" and r["protocol"] == "paper"]
    assert rates["ppo"].runs == len(ppo)
    assert rates["ppo"].seconds_per_step == pytest.approx(sum(r["cpu_time_s"] for r in ppo) / sum(r["budget"] for r in ppo))
    randoms = [r for r in records if r["algo"] == "random" and r["protocol"] == "paper"]
    per = max(r["budget"] for r in randoms) > 0 and sum(r["budget"] for r in randoms) or len(randoms)  # real sweeps: budget 0
    assert rates["random"].seconds_per_step == pytest.approx(sum(r["cpu_time_s"] for r in randoms) / per)
    assert measured_rates(results, "paper", "quick", "fleet").keys() == {"random"}  # no trained run was a fleet's


def test_projection_prices_every_planned_run(measured: tuple[Path, list[dict]], tmp_path: Path) -> None:
    results, _ = measured
    rates = measured_rates(results, "paper", "quick", "single")
    jobs, _sweep = table1_jobs("quick", "paper", "fleet", 2, tmp_path / "scratch")
    assert sum(len(j.runs) for j in jobs) == 630  # the quick Table 1: 126 pairs x 5 learners, one seed
    priced = [job_seconds(j, rates) for j in jobs]
    assert all(ok for _, ok in priced)
    expected = sum(rates[r.config["algo"]["name"]].seconds_per_step * max(int(r.config["budget"]), 1)
                   for j in jobs for r in j.runs)
    assert sum(p for p, _ in priced) == pytest.approx(expected)
    del rates["cpo"]  # an unmeasured learner keeps the planner's estimate and is said to
    assert not all(ok for _, ok in (job_seconds(j, rates) for j in jobs))


def test_cli(measured: tuple[Path, list[dict]], tmp_path: Path) -> None:
    results, _ = measured
    out = tmp_path / "projection.md"
    done = subprocess.run([sys.executable, "-m", "benchmarks.project_table1", str(results), "--preset", "quick",
                           "--engine", "single", "--workers", "2", "8", "--out", str(out)],
                          cwd=REPO, capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stderr
    text = out.read_text()
    assert "| 2 | 630 |" in text and "| 8 | 630 |" in text and "| none |" in text
    bad = subprocess.run([sys.executable, "-m", "benchmarks.project_table1", str(tmp_path)], cwd=REPO,
                         capture_output=True, text=True, timeout=120, check=False)
    assert bad.returncode == 2 and "not a results directory" in bad.stderr


def test_scenario_factors_weight_the_rates_by_the_reference_sweep(measured: tuple[Path, list[dict]], tmp_path: Path) -> None:
    results, records = measured
    rates = measured_rates(results, "paper", "quick", "single")
    factors = scenario_factors(results, "paper", "single", rates)
    ppo = [r for r in records if r["algo"] == "ppo" and r["protocol"] == "paper"]
    per_step = {sc: sum(r["cpu_time_s"] for r in ppo if r["scenario"] == sc) / sum(r["budget"] for r in ppo if r["scenario"] == sc)
                for sc in {r["scenario"] for r in ppo}}
    overall = sum(r["cpu_time_s"] for r in ppo) / sum(r["budget"] for r in ppo)
    for scenario, value in per_step.items():  # the reference is the measured sweep itself: relative to its mean
        assert factors[("ppo", scenario)] == pytest.approx(value / overall)
    jobs, _sweep = table1_jobs("quick", "paper", "fleet", 1, tmp_path / "scratch")
    weighted = sum(job_seconds(j, rates, factors)[0] for j in jobs)
    expected = sum(rates[r.config["algo"]["name"]].seconds_per_step * max(int(r.config["budget"]), 1)
                   * factors.get((r.config["algo"]["name"], r.config["scenario"]), 1.0) for j in jobs for r in j.runs)
    assert weighted == pytest.approx(expected)
    assert any(abs(f - 1.0) > 1e-6 for f in factors.values())  # the weighting is not a no-op here


def test_cpu_time_only_prices_from_the_runs_that_recorded_it(measured: tuple[Path, list[dict]],
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """Runs written before cpu_time_s existed count their wall time (marked 'wall'); --cpu-time-only leaves them out."""
    import benchmarks.project_table1 as tool

    results, records = measured
    real = tool.finished_runs
    older = sorted(r["run_id"] for r in records if r["algo"] == "ppo" and r["protocol"] == "paper")[:3]

    def with_older_runs(*args: object) -> object:
        frame = real(*args).copy()
        frame.loc[frame["run_id"].isin(older), "cpu_time_s"] = float("nan")
        return frame

    monkeypatch.setattr(tool, "finished_runs", with_older_runs)
    mixed = measured_rates(results, "paper", "quick", "single")
    ppo = [r for r in records if r["algo"] == "ppo" and r["protocol"] == "paper"]
    assert (mixed["ppo"].runs, mixed["ppo"].cpu_runs) == (len(ppo), len(ppo) - 3)
    cpu = measured_rates(results, "paper", "quick", "single", cpu_only=True)
    newer = [r for r in ppo if r["run_id"] not in older]
    assert (cpu["ppo"].runs, cpu["ppo"].cpu_runs) == (len(newer), len(newer))
    assert cpu["ppo"].seconds_per_step == pytest.approx(sum(r["cpu_time_s"] for r in newer) / sum(r["budget"] for r in newer))
    assert f"CPU {len(ppo) - 3}, wall 3" in "\n".join(tool._measured_table(results, "quick", "paper", "single", mixed))



def test_against_the_planner_sets_each_learners_core_time_beside_the_plans_price_of_the_same_runs(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 32 asks for a sweep's time per learner against the planner: the same runs, priced by the plan.
    Finished runs are the plan's own (ids and all), each at twice its planned price, plus one run the
    plan does not have."""
    import pandas as pd

    import benchmarks.project_table1 as tool

    jobs, _sweep = table1_jobs("quick", "paper", "fleet", 2, tmp_path / "scratch")
    priced = tool.planned_core_seconds(jobs)
    assert len(priced) == 630 and all(v > 0 for v in priced.values())
    fleets = [j for j in jobs if j.engine == "fleet"]
    assert fleets and all(priced[r.run_id] == pytest.approx(j.est_seconds / len(j.runs)) for j in fleets for r in j.runs)
    cpo = [r for j in jobs for r in j.runs if r.config["algo"]["name"] == "cpo"][:20]
    frame = pd.DataFrame({"run_id": [r.run_id for r in cpo] + ["not-planned"], "algo": "cpo",
                          "cpu_time_s": [2 * priced[r.run_id] for r in cpo] + [1e6], "wall_time_s": 1.0})
    monkeypatch.setattr(tool, "finished_runs", lambda *args: frame)
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
            for line in tool._against_plan_table(tmp_path, "quick", "paper", "fleet", jobs, 2)
            if line.startswith("| ") and not line.startswith("| learner")}
    assert rows["CPO"][0] == "20" and rows["CPO"][3:] == ["2.00", "1"]  # the unplanned run is counted apart, not priced
