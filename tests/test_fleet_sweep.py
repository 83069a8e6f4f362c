"""Sweeps on the fleet engine (issue 14, stage 2): how the plan is cut into jobs, what a job writes,
that a resumed fleet trains only its unfinished runs, and that a killed fleet loses nothing written.

The fleet's arithmetic itself (a fleet of one equals the single learner; runs do not influence each
other) is tested in tests/test_fleet.py; here it is the sweep around it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from morality_gym.baselines.device import CPU, Device
from morality_gym.baselines.fleet import TRAINERS
from morality_gym.baselines.fleet.compiled import compiler_missing
from morality_gym.baselines.specs import (
    DEFAULT_UPDATE_ENGINE,
    FLEET_ALGORITHMS,
    fleet_trains,
    learner_spec,
    protocol_spec,
)
from morality_gym.results.recording import RunClock, RunLock, finished_status
from morality_gym.results.schema import read_runs, read_updates
from runners.compose.sweep_config import ConfigError, validate
from runners.execute.jobs import FleetTraining, execute_job
from runners.launch import entry_points
from runners.plan.estimate import dispatch_order, fleet_speedup, jobs_estimate, makespan
from runners.plan.fleets import make_jobs
from runners.plan.runs import expand_sweep
from tests.sweep_tools import run_files, wait_for_results

REPO = Path(__file__).resolve().parents[1]


def _sweep_config(tmp_path: Path, *overrides: str):
    from hydra import compose, initialize_config_dir

    from runners.compose.search_path import CONF_DIR

    given = [f"results_dir={tmp_path / 'r'}", "mlflow=false", "gif=false", *overrides]
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=given)
    return validate(cfg, given)  # the command line, as the CLI passes it: errors name its overrides


def _sweep(results: Path, *overrides: str, background: bool = False) -> subprocess.CompletedProcess | subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)
    args = [sys.executable, "-m", "runners.sweep", f"results_dir={results}", "mlflow=false", "gif=false", *overrides]
    if background:
        return subprocess.Popen(args, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                                start_new_session=True)
    return subprocess.run(args, cwd=REPO, check=False, capture_output=True, text=True, timeout=900, env=env)


# ------------------------------------------------------------------------------------------ plan -> jobs
def test_runs_group_into_fleets_by_learner_and_scenario(tmp_path: Path) -> None:
    sweep = _sweep_config(tmp_path, "algo=[random,ppo,ppo_lag]", "chain=[utility,dual_process]",
                          "scenario=[switch_standard,push_standard]", "preset=smoke", "seed=[1,2]")
    runs = expand_sweep(sweep)
    jobs = make_jobs(runs, "fleet", fleet_size=1000, workers=1)
    assert sorted(r.run_id for j in jobs for r in j.runs) == sorted(r.run_id for r in runs)  # each run exactly once
    for job in jobs:
        configs = [r.config for r in job.runs]
        if job.engine == "single":
            assert len(job.runs) == 1
            continue
        # one learner, one scenario, one budget; chains, variants and seeds may differ
        assert len({c["algo"]["name"] for c in configs}) == 1 and len({c["scenario"] for c in configs}) == 1
        assert len({c["budget"] for c in configs}) == 1
    fleets = [j for j in jobs if j.engine == "fleet"]
    assert {(j.runs[0].config["algo"]["name"], j.runs[0].config["scenario"]) for j in fleets} == {
        ("ppo", "SwitchStandard"), ("ppo", "PushStandard"), ("ppo_lag", "SwitchStandard"), ("ppo_lag", "PushStandard")}
    # both chains of a scenario share its fleet
    assert all(len({r.config["chain"]["name"] for r in j.runs}) == 2 for j in fleets)
    # Random trains nothing: never in a fleet
    assert all(j.engine == "single" for j in jobs if j.runs[0].config["algo"]["name"] == "random")
    assert all(j.engine == "single" for j in make_jobs(runs, "single"))


def test_on_accelerators_fleets_mix_the_scenarios_of_one_budget(tmp_path: Path) -> None:
    sweep = _sweep_config(tmp_path, "algo=[random,ppo]", "chain=utility", "scenario=[switch_standard,switch5,switch7]",
                          "preset=quick", "seed=[1]")
    runs = expand_sweep(sweep)
    jobs = make_jobs(runs, "fleet", fleet_size=1000, workers=1, mix_scenarios=True)
    assert sorted(r.run_id for j in jobs for r in j.runs) == sorted(r.run_id for r in runs)
    fleets = [j for j in jobs if j.engine == "fleet"]
    # one fleet per budget (a fleet learns one budget), holding every scenario of that budget
    budgets: dict[int, set[str]] = {}
    for r in runs:
        if r.config["algo"]["name"] == "ppo":
            budgets.setdefault(r.config["budget"], set()).add(r.config["scenario"])
    assert sorted(({r.config["scenario"] for r in j.runs} for j in fleets), key=sorted) == sorted(budgets.values(), key=sorted)
    assert max(len(j.runs) for j in fleets) > 12 and any(len(s) > 1 for s in budgets.values())
    assert all(len({r.config["budget"] for r in j.runs}) == 1 for j in fleets)
    unmixed = [j for j in make_jobs(runs, "fleet", fleet_size=1000, workers=1) if j.engine == "fleet"]
    assert len(unmixed) == 3 and all(len({r.config["scenario"] for r in j.runs}) == 1 for j in unmixed)


def test_fleets_are_cut_to_fleet_size_and_to_keep_workers_busy(tmp_path: Path) -> None:
    sweep = _sweep_config(tmp_path, "algo=ppo", "chain=utility", "scenario=[switch_standard]", "preset=smoke", "seed=[1,2,3]")
    runs = expand_sweep(sweep)  # 12 variants x 3 seeds
    assert len(runs) == 36
    sizes = sorted(len(j.runs) for j in make_jobs(runs, "fleet", fleet_size=10, workers=1))
    assert sizes == [9, 9, 9, 9]  # ceil(36/10) = 4 balanced fleets
    sizes = sorted(len(j.runs) for j in make_jobs(runs, "fleet", fleet_size=36, workers=3))
    assert sizes == [12, 12, 12]  # one fleet would leave two workers idle
    jobs = make_jobs(runs[:3], "fleet", fleet_size=2, workers=1)
    assert sorted((j.engine, len(j.runs)) for j in jobs) == [("fleet", 2), ("single", 1)]  # a fleet of one is a single run
    with pytest.raises(ValueError, match="engine"):
        make_jobs(runs, "batched")


def test_estimate_uses_the_measured_fleet_speedup(tmp_path: Path) -> None:
    assert fleet_speedup(8.0, 1) == 1.0 and fleet_speedup(8.0, 12) == 8.0 and fleet_speedup(8.0, 36) == 8.0
    assert 1.0 < fleet_speedup(8.0, 6) < 8.0
    sweep = _sweep_config(tmp_path, "algo=ppo_lag", "chain=utility", "scenario=[switch_standard]", "preset=quick", "seed=[1]")
    runs = expand_sweep(sweep)
    speedups = {a.spec.name: a.rates.fleet_speedup for a in sweep.algos}
    import yaml

    from runners.compose.search_path import CONF_DIR

    measured = yaml.safe_load((CONF_DIR / "algo" / "ppo_lag.yaml").read_text())["planning"]["fleet_speedup"]
    assert measured > 1 and speedups["ppo_lag"] == pytest.approx(measured)  # the paper protocol's figure
    single = jobs_estimate(make_jobs(runs, "single"), set(), 1)
    fleet = jobs_estimate(make_jobs(runs, "fleet", 36, 1, speedups), set(), 1)
    overhead = sum(r.overhead_s for r in runs)
    assert overhead > 0 and fleet == pytest.approx(overhead + (single - overhead) / measured)
    assert jobs_estimate(make_jobs(runs, "fleet", 36, 1, speedups), {r.run_id for r in runs}, 1) == 0.0


def test_several_workers_take_the_longest_jobs_first(tmp_path: Path) -> None:
    sweep = _sweep_config(tmp_path, "algo=[random,ppo,cpo]", "chain=utility", "scenario=[switch_standard,switch5]",
                          "preset=smoke", "seed=[1,2,3]")
    jobs = make_jobs(expand_sweep(sweep), "fleet", 36, 2, {a.spec.name: a.rates.fleet_speedup for a in sweep.algos})
    assert dispatch_order(jobs, 1) == jobs  # one worker: the plan's order (results arrive row by row)
    ordered = dispatch_order(jobs, 2)
    assert sorted(map(id, ordered)) == sorted(map(id, jobs))
    estimates = [j.est_seconds for j in ordered]
    assert estimates == sorted(estimates, reverse=True) and estimates != [j.est_seconds for j in jobs]
    # the estimate is the makespan of that order, never below the longest job or the even split
    est = jobs_estimate(jobs, set(), 2)
    assert est == pytest.approx(makespan(estimates, 2))
    assert est >= max(estimates) and est >= sum(estimates) / 2 - 1e-9
    assert makespan([1, 1, 1, 5], 2) == 6 and makespan(sorted([1, 1, 1, 5], reverse=True), 2) == 5


def test_only_learners_the_fleet_reproduces_are_grouped() -> None:
    assert fleet_trains("stable_baselines3.PPO")
    assert not fleet_trains("stable_baselines3.A2C")  # a user's learner runs on the single engine
    assert not fleet_trains("no_such_package.Learner")  # reported by the sweep's checks, not here


def test_the_fleet_learners_the_plan_reads_are_the_fleets_trainers() -> None:
    """The plan cuts runs into fleets from a list below the fleet (so that planning imports no
    torch); it must name exactly the classes the fleet's trainers reproduce, in their order."""
    assert list(TRAINERS) == list(FLEET_ALGORITHMS)
    assert all(trainer.algorithm == algorithm for algorithm, trainer in TRAINERS.items())
    assert all(fleet_trains(a) for a in FLEET_ALGORITHMS)


def test_the_sweeps_own_process_plans_without_the_training_code() -> None:
    """The sweep's process checks, plans and waits: importing it (and the launchers, the plan) loads
    no torch; the workers import the training code by the name the launchers hand them."""
    code = ("import sys, runners.sweep, runners.launch.local_pool, runners.launch.slurm, runners.plan.fleets; "
            "print('torch' in sys.modules, 'runners.execute.jobs' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False False"
    jobs = entry_points.training()
    assert jobs.execute_job is execute_job and callable(jobs.execute_job_all)


def test_engine_is_validated(tmp_path: Path) -> None:
    from runners.compose.sweep_config import ConfigError

    with pytest.raises(ConfigError, match="engine: expected fleet or single, got 'fleat' \\(did you mean 'fleet'\\?\\)"):
        _sweep_config(tmp_path, "algo=ppo", "engine=fleat")
    with pytest.raises(ConfigError, match="fleet_size"):
        _sweep_config(tmp_path, "algo=ppo", "fleet_size=0")


def test_device_is_validated_before_anything_runs(tmp_path: Path) -> None:
    import torch

    from runners.compose.sweep_config import ConfigError

    with pytest.raises(ConfigError, match="device=cuda: only the fleet engine trains off the CPU"):
        _sweep_config(tmp_path, "algo=ppo", "engine=single", "device=cuda")
    with pytest.raises(ConfigError, match="device='tpu': not a device the fleet engine trains on; use cpu, cuda or cuda:N"):
        _sweep_config(tmp_path, "algo=ppo", "device=tpu")
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match=r"torch sees no GPU here \(torch.cuda.is_available\(\) is False\); use device=cpu"):
            _sweep_config(tmp_path, "algo=ppo", "device=cuda")
        # nothing trains here in a dry run, nor under SLURM (its nodes have the GPUs): planned, not refused
        # ... and not marked checked: the machine that trains checks it (Device.usable)
        assert _sweep_config(tmp_path, "algo=ppo", "device=cuda", "dry_run=true").device == Device("cuda")
        assert _sweep_config(tmp_path, "algo=ppo", "device=cuda", "launcher=slurm").device == Device("cuda")
        done = _sweep(tmp_path / "r", "algo=ppo", "chain=utility", "scenario=[switch_standard]", "preset=smoke", "device=cuda")
        assert done.returncode == 2 and "torch sees no GPU" in done.stderr and "Traceback" not in done.stderr
        assert not (tmp_path / "r").exists()
    assert _sweep_config(tmp_path, "algo=ppo").device == CPU
    # fleets grow with the device: 36 on the CPU, 336 on a GPU, unless fleet_size says otherwise
    assert _sweep_config(tmp_path, "algo=ppo").fleet_size == 36
    assert _sweep_config(tmp_path, "algo=ppo", "device=cuda", "dry_run=true").fleet_size == 336
    assert _sweep_config(tmp_path, "algo=ppo", "device=cuda", "dry_run=true", "fleet_size=50").fleet_size == 50


def test_a_fleet_job_on_a_device_it_cannot_use_fails_its_runs_instead_of_training_elsewhere(tmp_path: Path) -> None:
    """A SLURM node without the GPU the submitting host saw: every run of the job is recorded failed
    with the reason (not trained on the CPU behind the user's back)."""
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    sweep = _sweep_config(tmp_path, "algo=ppo_lag", "chain=utility", "scenario=[switch_standard]", "preset=smoke",
                          "seed=[1]", "variant=[HumanA,HumanB]")
    (job,) = make_jobs(expand_sweep(sweep), "fleet", 36, 1)
    summaries = list(execute_job(job.items, tmp_path / "r", gif=False, engine="fleet", device=Device("cuda")))
    assert [s["status"] for s in summaries] == ["failed", "failed"]
    df = read_runs(tmp_path / "r")
    assert df.error.str.contains("torch sees no GPU").all()


# ------------------------------------------------------------------------------------------ execution
def test_a_fleet_job_writes_every_run_as_the_single_engine_does(tmp_path: Path) -> None:
    sweep = _sweep_config(tmp_path, "algo=ppo_lag", "chain=utility", "scenario=[switch_standard]", "preset=smoke",
                          "seed=[1]", "variant=[HumanA,HumanB,AnimalA]")
    runs = expand_sweep(sweep)
    results = tmp_path / "r"
    (job,) = make_jobs(runs, "fleet", 36, 1)
    assert job.engine == "fleet" and len(job.runs) == 3
    summaries = list(execute_job(job.items, results, gif=False, engine="fleet"))
    assert [s["status"] for s in summaries] == ["ok"] * 3, summaries
    df = read_runs(results)
    assert sorted(df.run_id) == sorted(r.run_id for r in runs)
    assert set(df.engine) == {"fleet:3"}
    assert (df.total_steps > 0).all() and df.metric.notna().all()
    # compute: each run's CPU time is its share of the fleet plus its own evaluation; one thread per
    # worker, so never more than its wall time (a little slack for the clocks' resolution)
    assert (df.cpu_time_s > 0).all() and (df.cpu_time_s <= df.wall_time_s * 1.05 + 0.05).all(), df[["cpu_time_s", "wall_time_s"]]
    for r in runs:
        assert any((results / "runs" / r.run_id).glob("model*"))  # the saved model, per run
        assert len(read_updates(results, r.run_id)) > 0  # PPO-Lag's per-update diagnostics, per run
        assert (results / "runs" / f"{r.run_id}.learn.parquet").is_file()


def test_the_pool_reports_a_fleets_training_steps_while_it_trains(tmp_path: Path) -> None:
    """A local worker sends the fleet's steps to the parent as it trains (at most once a second,
    and at the end), and the job's end; the sweep shows them as a bar per fleet."""
    from runners.launch.local_pool import JobProgress, WorkerPool

    sweep = _sweep_config(tmp_path, "algo=ppo_lag", "chain=utility", "scenario=[switch_standard]", "preset=smoke",
                          "seed=[1]", "variant=[HumanA,HumanB]")
    (job,) = make_jobs(expand_sweep(sweep), "fleet", 36, 1)

    class Record(JobProgress):
        def __init__(self) -> None:
            self.updates: list[tuple[int, int]] = []
            self.ended: list[int] = []

        def update(self, job_: object, steps: int, total: int) -> None:
            assert job_ is job
            self.updates.append((steps, total))

        def end(self, job_: object) -> None:
            self.ended.append(id(job_))

    record, results = Record(), []
    WorkerPool(1, tmp_path / "r", gif=False).run([job], lambda run, summary: results.append(summary["status"]),
                                                  lambda run, error: results.append(error), record)
    assert results == ["ok", "ok"]
    assert record.updates and record.updates[-1][0] == record.updates[-1][1] > 0
    assert [s for s, _ in record.updates] == sorted(s for s, _ in record.updates)
    assert record.ended == [id(job)]


def test_a_resumed_fleet_trains_only_its_unfinished_runs(tmp_path: Path) -> None:
    sweep = _sweep_config(tmp_path, "algo=ppo", "chain=utility", "scenario=[switch_standard]", "preset=smoke",
                          "seed=[1]", "variant=[HumanA,HumanB,AnimalA,AnimalB]")
    runs = expand_sweep(sweep)
    results = tmp_path / "r"
    # run 0 finished earlier (single engine); run 1 is held by another live process
    first = list(execute_job([(runs[0].run_id, runs[0].config)], results, gif=False))
    assert first[0]["status"] == "ok"
    before = (results / "runs" / f"{runs[0].run_id}.parquet").stat().st_mtime_ns
    holder = RunLock(results, runs[1].run_id)
    assert holder.acquire()
    try:
        summaries = {s["run_id"]: s for s in execute_job([(r.run_id, r.config) for r in runs], results, gif=False, engine="fleet")}
    finally:
        holder.release()
    assert summaries[runs[0].run_id].get("skipped") is True
    assert summaries[runs[1].run_id]["status"] == "busy" and finished_status(results, runs[1].run_id) is None
    assert summaries[runs[2].run_id]["status"] == summaries[runs[3].run_id]["status"] == "ok"
    assert (results / "runs" / f"{runs[0].run_id}.parquet").stat().st_mtime_ns == before  # not trained again
    df = read_runs(results)
    engines = dict(zip(df.run_id, df.engine))
    assert engines[runs[0].run_id] == "single" and engines[runs[2].run_id] == engines[runs[3].run_id] == "fleet:2"


@pytest.mark.slow
def test_a_killed_fleet_sweep_resumes_with_nothing_lost_or_twice(tmp_path: Path) -> None:
    """Kill -9 a fleet sweep once some runs are written; the resumed sweep plans only the rest,
    and the directory ends with every run exactly once, all trained by fleets."""
    results = tmp_path / "r"
    args = ["algo=ppo", "chain=utility", "scenario=[switch_standard]", "preset=smoke", "seed=[1,2]", "launcher.workers=1",
            "fleet_size=6"]
    first = _sweep(results, *args, background=True)
    wait_for_results(results, 2, first)
    os.killpg(first.pid, signal.SIGKILL)
    first.wait(timeout=30)
    written = set(run_files(results))
    assert 2 <= len(written) < 24
    second = _sweep(results, *args)
    assert second.returncode == 0, second.stderr
    assert f"({len(written)} done, {24 - len(written)} to run)" in second.stderr
    df = read_runs(results)
    assert len(df) == 24 and df.run_id.is_unique and (df.status == "ok").all()
    assert set(df.engine) <= {f"fleet:{k}" for k in range(2, 7)} | {"single"}
    assert written <= set(df.run_id)


def test_the_recorded_commit_is_the_one_the_worker_loaded(monkeypatch: pytest.MonkeyPatch) -> None:
    """A sweep runs for hours: a commit made while a worker trains must not be recorded for runs of
    the code it loaded before (git_commit is asked once per process, at the worker's start)."""

    from morality_gym.results import recording as execute

    execute.git_commit.cache_clear()
    first = execute.git_commit()
    assert len(first) == 40 or first == "unknown"

    def later_commit(*args: object, **kwargs: object) -> subprocess.CompletedProcess[str]:
        raise AssertionError("git asked again: a later HEAD would be recorded")

    monkeypatch.setattr(execute.subprocess, "run", later_commit)
    assert execute.git_commit() == first


def test_a_run_written_before_its_worker_died_counts_as_written(tmp_path: Path) -> None:
    # A worker killed between writing a run's result and reporting it: the result on disk stands;
    # the sweep neither overwrites it with a failure nor counts the run as failed.
    from rich.console import Console
    from rich.progress import Progress

    from runners.sweep import _Outcomes

    sweep = _sweep_config(tmp_path, "algo=random", "chain=utility", "scenario=[switch_standard]", "preset=smoke",
                          "seed=[1]", "variant=[HumanA,HumanB]")
    written, unwritten = expand_sweep(sweep)
    results = tmp_path / "r"
    assert [s["status"] for s in execute_job([(written.run_id, written.config)], results, gif=False)] == ["ok"]
    console = Console(file=open(os.devnull, "w"))  # noqa: SIM115 - closed with the test's process
    with Progress(console=console) as progress:
        outcomes = _Outcomes(sweep, None, progress, console, 2)
        outcomes.fail(written, "worker process died (signal 9) while running this configuration")
        outcomes.fail(unwritten, "worker process died (signal 9) while running this configuration")
    assert list(outcomes.failures) == [unwritten.run_id]
    df = read_runs(results).set_index("run_id")
    assert df.loc[written.run_id, "status"] == "ok" and df.loc[written.run_id, "metric"] is not None
    assert df.loc[unwritten.run_id, "status"] == "failed"
    assert df.loc[unwritten.run_id, "error"].startswith("worker process died (signal 9)")


# ------------------------------------------------------------------------------------------ fleet_update
def test_fleet_update_is_checked_with_close_matches(tmp_path: Path) -> None:
    """``fleet_update`` defaults to the engine every release was trained with; a misspelt engine,
    or an engine where no fleet trains, is refused in one line naming the setting."""
    assert _sweep_config(tmp_path, "algo=ppo").fleet_update == DEFAULT_UPDATE_ENGINE == "eager"
    assert _sweep_config(tmp_path, "algo=ppo", "fleet_update=compiled").fleet_update == "compiled"
    with pytest.raises(ConfigError, match=r"^fleet_update: expected eager or compiled, got 'compild' \(did you mean 'compiled'\?\)$"):
        _sweep_config(tmp_path, "algo=ppo", "fleet_update=compild")
    with pytest.raises(ConfigError, match=r"^fleet_update=compiled: only the fleet engine has update engines; use engine=fleet"):
        _sweep_config(tmp_path, "algo=ppo", "engine=single", "fleet_update=compiled")
    done = _sweep(tmp_path / "r", "algo=ppo", "fleet_update=eagr", "dry_run=true")
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert "fleet_update: expected eager or compiled, got 'eagr' (did you mean 'eager'?)" in done.stderr


def test_the_update_engine_keys_a_fleet_checkpoint_only_when_compiled(tmp_path: Path) -> None:
    """A compiled fleet's checkpoint is never resumed by an eager fleet (nor the other way round);
    an eager fleet's key is the one every checkpoint written before the setting has, so those resume."""
    sweep = _sweep_config(tmp_path, "algo=ppo", "chain=utility", "scenario=[switch_standard]", "preset=smoke",
                          "seed=[1]", "variant=[HumanA,HumanB]")
    runs = [(r.run_id, r.config) for r in expand_sweep(sweep)]
    spec, protocol = learner_spec("ppo"), protocol_spec("paper")
    eager = FleetTraining(runs, RunClock.start()).checkpoint(tmp_path / "r", spec, protocol, CPU, 60.0)
    compiled = FleetTraining(runs, RunClock.start()).checkpoint(tmp_path / "r", spec, protocol, CPU, 60.0, "compiled")
    assert eager is not None and compiled is not None
    assert set(eager.key) == {"runs", "learner", "protocol", "device", "fleet_size", "code"}
    assert compiled.key == {**eager.key, "update": "compiled"}


def test_a_sweep_with_fleet_update_compiled_trains_its_fleets_compiled(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The setting reaches the worker's fleets: they compile their update steps (kernels written to
    the compile cache, which an eager fleet never touches) and every run is recorded as usual."""
    if compiler_missing():
        pytest.skip(str(compiler_missing()))
    cache = tmp_path / "kernels"
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(cache))
    done = _sweep(tmp_path / "r", "algo=ppo", "chain=utility", "scenario=[switch_standard]", "variant=[HumanA]",
                  "seed=[1,2]", "preset=smoke", "fleet_update=compiled")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "update engine compiled" in done.stderr, done.stderr  # the plan, as the sweep prints it
    df = read_runs(tmp_path / "r")
    assert set(df.status) == {"ok"} and set(df.engine) == {"fleet:2"}, df[["status", "engine", "error"]]
    assert cache.is_dir() and any(p.is_file() for p in cache.rglob("*")), "the fleet trained without compiling"
