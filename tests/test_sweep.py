"""Sweeps: validation before anything runs, planning, resume, failures, SIGKILL, MLflow, SLURM."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from morality_gym.results.manifest import read_manifests
from morality_gym.results.schema import RUN_COLUMNS, read_runs
from tests.sweep_tools import children, run_files, wait_for_results

REPO = Path(__file__).resolve().parents[1]
SMALL = ["algo=random", "chain=utility", "scenario=[switch_standard]", "preset=smoke", "seed=[41]"]


def sweep(results: Path, *args: str, timeout: float = 600, background: bool = False) -> subprocess.CompletedProcess | subprocess.Popen:
    options = [a for a in args if a.startswith("--")]  # Hydra flags must precede the overrides
    cmd = [sys.executable, "-m", "runners.sweep", *options, f"results_dir={results}", *(a for a in args if not a.startswith("--"))]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)
    if background:
        return subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, start_new_session=True)
    return subprocess.run(cmd, cwd=REPO, check=False, capture_output=True, text=True, timeout=timeout, env=env)


def planned_ids(results: Path) -> set[str]:
    """The runs a results directory's manifests plan, and those of the dry runs' plan files beside it
    (``<results>.plan*.json``: a dry run writes nothing into the results directory, issue 36)."""
    plans = [json.loads(p.read_text()) for p in sorted(results.parent.glob(f"{results.name}.plan*.json"))]
    return {r["run_id"] for m in [*read_manifests(results), *plans] for r in m["runs"]}


def plan_file(results: Path, tag: str = "") -> str:
    """The ``plan_file=`` of a dry run whose plan :func:`planned_ids` should count."""
    return f"plan_file={results.parent / f'{results.name}.plan{tag}.json'}"


def mlflow_run_ids(results: Path) -> list[str]:
    from mlflow.tracking import MlflowClient

    client = MlflowClient(f"sqlite:///{results / 'mlflow.db'}")
    exp = client.get_experiment_by_name("morality-gym")
    return [r.data.tags["run_id"] for r in client.search_runs([exp.experiment_id], max_results=5000)]


@pytest.mark.parametrize(
    "args, message",
    [
        (["scenario=[push_or_swich]"], "did you mean 'push_or_switch'"),
        (["algo=[random,cpoo]"], "unknown algo 'cpoo'"),
        (["chain=utilty"], "did you mean 'utility'"),
        (["algo=random", "variant=[Humn]"], "did you mean 'Human'"),
        (["algo=ppo", "algo.ppo.hparams.learning_rate=fast"], "hparams.learning_rate"),
        (["algo=ppo", "algo.ppo.hparams.n_stepz=3"], "n_stepz"),
        (["algo=ppo", "preset.budget=0"], "budget of 0"),
        (["algo=random", "seed=[a]"], "seed"),
        (["algo=random", "launcher.workers=0"], "launcher.workers"),
        (["algo=random", "beta=2"], "beta"),
        (["algo=random", "max_steps=many"], "max_steps"),
        (["algo=ppo", "+algo.ppo.planning.speed=3"], "unknown planning key(s) ['speed']"),
        (["algo=random", "+protocol.bogus=1"], "bogus"),  # was an UnboundLocalError (a later local import shadowed SpecError)
    ],
)
def test_bad_input_fails_before_any_run(tmp_path: Path, args: list[str], message: str) -> None:
    out = sweep(tmp_path / "r", *args)
    assert out.returncode == 2, out.stdout + out.stderr
    assert message in out.stdout + out.stderr
    assert not (tmp_path / "r" / "runs").exists()
    assert not (tmp_path / "r" / "manifests").exists()


def test_unwritable_results_dir_and_malformed_user_chain(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    out = sweep(blocker / "sub", *SMALL)
    assert out.returncode == 2 and "results_dir" in out.stderr
    conf = tmp_path / "conf" / "chain"
    conf.mkdir(parents=True)
    (conf / "mine.yaml").write_text("# @package chain.mine\nname: Mine\nnorms: [n_human_harm, n_humans_harm]\n")
    out = sweep(tmp_path / "r", f"--config-dir={tmp_path / 'conf'}", "algo=random", "chain=mine", "scenario=[switch_standard]")
    assert out.returncode == 2 and "n_humans_harm" in out.stderr and "did you mean" in out.stderr.lower()


def test_plan_narrowing_and_stable_ids(tmp_path: Path) -> None:
    results = tmp_path / "r"
    base = [*SMALL, "variant=[HumanA,HumanB]", "seed=[41,42]", "dry_run=true"]
    first = sweep(results, *base, plan_file(results))
    assert first.returncode == 0, first.stderr
    ids = planned_ids(results)
    assert len(ids) == 4 and "4 runs" in first.stderr
    assert sweep(results, *base, plan_file(results)).returncode == 0 and planned_ids(results) == ids  # stable hashes
    sweep(results, *base, "beta=0.2", "name=b02", plan_file(results, "-b02"))
    assert len(planned_ids(results)) == 8  # a different beta is a different run
    assert not results.exists()  # issue 36: dry runs write nothing there
    default = sweep(tmp_path / "d", "algo=random", "chain=utility", "dry_run=true", "preset=smoke", plan_file(tmp_path / "d"))
    scenarios = {r["scenario"] for r in json.loads((tmp_path / "d.plan.json").read_text())["runs"]}
    assert scenarios == {"Push2OrSwitch", "PushOrSwitch", "Switch2Trolley4Track", "Switch5", "Switch7", "SwitchStandard"}
    assert default.returncode == 0 and not (tmp_path / "d" / "runs").exists() or not run_files(tmp_path / "d")


@pytest.mark.slow
def test_local_sweep_end_to_end_then_resume_skips(tmp_path: Path) -> None:
    args = ["algo=[random,ppo_shaped]", "chain=utility", "scenario=[switch_standard]", "variant=[HumanA]", "seed=[41]", "preset=smoke"]
    out = sweep(tmp_path, *args)
    assert out.returncode == 0, out.stdout + out.stderr
    files = run_files(tmp_path)
    assert set(files) == planned_ids(tmp_path) and len(files) == 2
    df = read_runs(tmp_path)
    assert set(RUN_COLUMNS) <= set(df.columns) and {"mf_n_human_harm", "mf_n_animal_harm", "mf_n_robot_harm"} <= set(df.columns)
    assert (df.status == "ok").all() and df.metric.between(0, 1).all() and df.exact_metric.between(0, 1).all()
    shaped = df[df.algo == "ppo_shaped"].iloc[0]
    assert shaped.learner == "PPO Shaped" and shaped.total_steps == 2048 and shaped.protocol == "paper" and shaped.preset == "smoke"
    assert (tmp_path / shaped.model_path).is_file() and (tmp_path / shaped.gif_path).is_file()
    assert json.loads(shaped.config)["algo"]["cost_scale"] == 50.0
    learn = pq.read_table(tmp_path / "runs" / f"{shaped.run_id}.learn.parquet").to_pandas()
    assert list(learn.step) == [0, 2048]  # learn-time evaluations every preset.learn_eval_every steps
    assert sorted(mlflow_run_ids(tmp_path)) == sorted(files)
    mtimes = {k: p.stat().st_mtime_ns for k, p in files.items()}
    again = sweep(tmp_path, *args)
    assert again.returncode == 0 and "0 to run" in again.stderr
    assert {k: p.stat().st_mtime_ns for k, p in run_files(tmp_path).items()} == mtimes
    assert sorted(mlflow_run_ids(tmp_path)) == sorted(files)


@pytest.mark.slow
def test_failing_run_is_recorded_and_does_not_stop_others(tmp_path: Path) -> None:
    # SB3 rejects n_steps * n_envs == 1 when the model is built: a run-time failure after validation.
    args = ["algo=[random,ppo]", "algo.ppo.hparams.n_steps=1", "algo.ppo.n_envs=1", "chain=utility",
            "scenario=[switch_standard]", "variant=[HumanA,HumanB]", "seed=[41]", "preset=smoke", "gif=false"]
    out = sweep(tmp_path, *args)
    assert out.returncode == 1
    df = read_runs(tmp_path)
    assert len(df) == 4
    assert (df[df.algo == "random"].status == "ok").all()
    failed = df[df.algo == "ppo"]
    assert (failed.status == "failed").all() and failed.error.str.contains("n_steps").all()
    assert failed.traceback.str.contains("Traceback").all()
    assert "failed runs:" in out.stderr and all(rid in out.stderr for rid in failed.run_id)
    kept = sweep(tmp_path, *args, "retry_failed=false")
    assert kept.returncode == 1 and "0 to run" in kept.stderr


@pytest.mark.slow
def test_sigkill_of_the_sweep_then_resume_gives_exact_run_set(tmp_path: Path) -> None:
    # 12 runs (SwitchStandard's variants): the kill after 3 lands with most of them still to do
    args = ["algo=random", "chain=utility", "scenario=[switch_standard]", "seed=[41]", "preset=smoke", "launcher.workers=2"]
    proc = sweep(tmp_path, *args, background=True)
    wait_for_results(tmp_path, 3, proc, timeout=180)
    workers = children(proc.pid)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    deadline = time.monotonic() + 20
    while any(Path(f"/proc/{w}").exists() and "Z" not in Path(f"/proc/{w}/stat").read_text().split()[2] for w in workers):
        assert time.monotonic() < deadline, "workers outlived the killed sweep"
        time.sleep(0.2)
    partial = set(run_files(tmp_path))
    planned = planned_ids(tmp_path)
    assert 3 <= len(partial) < len(planned) == 12
    resumed = sweep(tmp_path, *args)
    assert resumed.returncode == 0, resumed.stderr
    assert f"{len(partial)} done" in resumed.stderr
    assert set(run_files(tmp_path)) == planned
    df = read_runs(tmp_path)
    assert len(df) == len(planned) and df.run_id.is_unique and (df.status == "ok").all()
    assert sorted(mlflow_run_ids(tmp_path)) == sorted(planned)  # mirrored once each, none lost
    assert not list((tmp_path / "runs").glob(".*.tmp"))


def _busy_worker(sweep_pid: int) -> tuple[int, str] | None:
    """A worker process of the sweep that currently holds a run lock, and that run's id."""
    for pid in children(sweep_pid):
        try:
            if b"spawn_main" not in Path(f"/proc/{pid}/cmdline").read_bytes():
                continue  # e.g. multiprocessing's resource tracker
            for fd in Path(f"/proc/{pid}/fd").iterdir():
                target = os.readlink(fd)
                if "/.locks/" in target:
                    return pid, Path(target).stem
        except OSError:
            continue
    return None


def _frozen_mid_run(results: Path, sweep_pid: int) -> tuple[int, str]:
    """A worker of the sweep stopped (SIGSTOP) while it holds a run whose result is not written yet.

    Why freeze first: a worker holds its run's lock a moment after writing the result; a kill in
    that moment loses nothing (the run is ok, see test_fleet_sweep), so the test would see no
    failure. Frozen, the worker cannot write while the test looks."""
    deadline = time.monotonic() + 60
    while True:
        assert time.monotonic() < deadline, "no worker was caught mid-run"
        busy = _busy_worker(sweep_pid)
        if busy is not None:
            os.kill(busy[0], signal.SIGSTOP)
            if busy[1] not in run_files(results) and _busy_worker(sweep_pid) == busy:
                return busy
            os.kill(busy[0], signal.SIGCONT)
        time.sleep(0.05)


@pytest.mark.slow
def test_sigkill_of_a_worker_fails_one_run_and_resume_finishes(tmp_path: Path) -> None:
    # one run per worker, so that a killed worker takes exactly one run (a fleet's: test_fleet_sweep.py)
    args = ["algo=ppo_shaped", "chain=utility", "scenario=[switch_standard]", "seed=[41]", "preset=smoke", "launcher.workers=2",
            "gif=false", "engine=single"]
    proc = sweep(tmp_path, *args, background=True)
    wait_for_results(tmp_path, 1, proc, timeout=180)
    victim, victim_run = _frozen_mid_run(tmp_path, proc.pid)
    os.kill(victim, signal.SIGKILL)
    output, _ = proc.communicate(timeout=600)
    assert proc.returncode == 1, output  # the killed worker's run failed, the sweep carried on
    df = read_runs(tmp_path)
    assert len(df) == 12 and list(df[df.status == "failed"].run_id) == [victim_run]
    assert df[df.status == "failed"].error.iloc[0].startswith("worker process died (signal 9)")
    resumed = sweep(tmp_path, *args)
    assert resumed.returncode == 0 and "11 done, 1 to run" in resumed.stderr
    df = read_runs(tmp_path)
    assert len(df) == 12 and (df.status == "ok").all() and set(df.run_id) == planned_ids(tmp_path)
    assert sorted(mlflow_run_ids(tmp_path)) == sorted(df.run_id)  # the failed mirror was replaced, not duplicated


@pytest.mark.slurm
@pytest.mark.slow
def test_sweep_through_real_slurm_with_a_failing_run(slurm_cluster, tmp_path: Path) -> None:
    args = ["launcher=slurm", f"launcher.partition={slurm_cluster.partition}", "launcher.timeout_min=10",
            "launcher.cpus_per_task=1", "launcher.mem_gb=2", "launcher.array_parallelism=2", "launcher.poll_s=0.5",
            "algo=[random,ppo]", "algo.ppo.hparams.n_steps=1", "algo.ppo.n_envs=1",
            "chain=utility", "scenario=[switch_standard]", "variant=[HumanA,HumanB]", "seed=[41]", "preset=smoke",
            "engine=single"]  # one array task per run (the fleet engine on SLURM: the next test)
    out = sweep(tmp_path, *args, timeout=600)
    assert out.returncode == 1, out.stdout + out.stderr
    df = read_runs(tmp_path)
    assert set(df.run_id) == planned_ids(tmp_path) and len(df) == 4
    assert (df[df.algo == "random"].status == "ok").all()
    assert (df[df.algo == "ppo"].status == "failed").all()
    assert len(list((tmp_path / "slurm").rglob("*_log.out"))) >= 4  # submitit logs of the array tasks
    assert sorted(mlflow_run_ids(tmp_path)) == sorted(df.run_id)
    again = sweep(tmp_path, *[a for a in args if not a.startswith("algo")], "algo=[random]")
    assert again.returncode == 0 and "0 to run" in again.stderr


@pytest.mark.slurm
@pytest.mark.slow
def test_fleet_sweep_through_real_slurm(slurm_cluster, tmp_path: Path) -> None:
    """The fleet engine on SLURM: one array task trains a fleet and writes each of its runs."""
    args = ["launcher=slurm", f"launcher.partition={slurm_cluster.partition}", "launcher.timeout_min=10",
            "launcher.cpus_per_task=1", "launcher.mem_gb=2", "launcher.array_parallelism=2", "launcher.poll_s=0.5",
            "algo=[random,ppo_lag]", "chain=utility", "scenario=[switch_standard]", "variant=[HumanA,HumanB,AnimalA]",
            "seed=[41]", "preset=smoke", "engine=fleet"]
    out = sweep(tmp_path, *args, timeout=600)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "3 of 6 runs to do train in 1 fleet(s)" in out.stderr
    df = read_runs(tmp_path)
    assert set(df.run_id) == planned_ids(tmp_path) and len(df) == 6 and (df.status == "ok").all()
    assert sorted(df[df.algo == "ppo_lag"].engine) == ["fleet:3"] * 3
    assert sorted(df[df.algo == "random"].engine) == ["single"] * 3
    assert len(list((tmp_path / "slurm").rglob("*_log.out"))) == 4  # 3 Random tasks + 1 fleet task
    assert sorted(mlflow_run_ids(tmp_path)) == sorted(df.run_id)
