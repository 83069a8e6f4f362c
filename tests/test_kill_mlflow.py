"""kill -9 of a sweep that mirrors into MLflow (issue 33): after any kill and a rerun, exactly one
active MLflow run per Parquet row, and no run left ``RUNNING``; the workers die with the sweep.

Real components: the sweep as a subprocess, MLflow's SQLite store in the results directory, read
back with ``MlflowClient`` over every lifecycle stage (``ViewType.ALL``).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from morality_gym.results.schema import read_runs
from tests.sweep_tools import children, run_files, wait_for_results

REPO = Path(__file__).resolve().parents[1]
ARGS = ["algo=random", "chain=utility", "scenario=[switch_standard]", "preset=smoke", "seed=[41]", "gif=false",
        "launcher.workers=2"]


def sweep(results: Path, background: bool = False) -> subprocess.Popen | subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)
    cmd = [sys.executable, "-m", "runners.sweep", f"results_dir={results}", *ARGS]
    if background:
        return subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                                start_new_session=True)
    return subprocess.run(cmd, cwd=REPO, check=False, capture_output=True, text=True, timeout=900, env=env)


def mlflow_runs(results: Path) -> list[tuple[str, str, str]]:
    """(run id tag, status, lifecycle stage) of every MLflow run, deleted ones too."""
    from mlflow.entities import ViewType
    from mlflow.tracking import MlflowClient

    client = MlflowClient(f"sqlite:///{results / 'mlflow.db'}")
    exp = client.get_experiment_by_name("morality-gym")
    runs = client.search_runs([exp.experiment_id], run_view_type=ViewType.ALL, max_results=5000)
    return [(r.data.tags.get("run_id", ""), r.info.status, r.info.lifecycle_stage) for r in runs]


def assert_one_active_run_per_row(results: Path) -> None:
    rows = read_runs(results)
    runs = mlflow_runs(results)
    active = sorted(tag for tag, _, stage in runs if stage == "active")
    assert active == sorted(rows.run_id), (active, sorted(rows.run_id))
    assert all(status != "RUNNING" for _, status, _ in runs), runs  # an interrupted mirror is KILLED




def alive(pid: int) -> bool:
    try:
        return "Z" not in Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False


@pytest.mark.slow
@pytest.mark.parametrize("after", [1, 6])
@pytest.mark.parametrize("target", ["sweep", "process group"])
def test_kill_9_then_rerun_leaves_one_active_mlflow_run_per_row(tmp_path: Path, target: str, after: int) -> None:
    results = tmp_path / "r"
    proc = sweep(results, background=True)
    wait_for_results(results, after, proc)
    workers = children(proc.pid)
    if target == "sweep":
        os.kill(proc.pid, signal.SIGKILL)
    else:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    deadline = time.monotonic() + 20
    while any(alive(w) for w in workers):  # PR_SET_PDEATHSIG: the workers die with the sweep
        assert time.monotonic() < deadline, "workers outlived the killed sweep"
        time.sleep(0.1)
    done = len(run_files(results))
    assert after <= done < 12
    again = sweep(results)
    assert again.returncode == 0, again.stderr
    assert f"{done} done, {12 - done} to run" in again.stderr
    assert len(read_runs(results)) == 12
    assert_one_active_run_per_row(results)


@pytest.mark.slow
def test_an_interrupted_mirror_is_marked_killed_when_it_is_set_aside(tmp_path: Path) -> None:
    """The state a kill between MLflow's create_run and the marker leaves (a RUNNING run tagged with
    the run id, no marker), made with MLflow itself: the next sweep sets it aside as KILLED."""
    from mlflow.tracking import MlflowClient

    results = tmp_path / "r"
    first = sweep(results)
    assert first.returncode == 0, first.stderr
    victim = min(run_files(results))
    (results / "tracking" / f"{victim}.json").unlink()  # as if the kill came before the marker
    client = MlflowClient(f"sqlite:///{results / 'mlflow.db'}")
    exp = client.get_experiment_by_name("morality-gym")
    half = client.create_run(exp.experiment_id, tags={"run_id": victim})  # RUNNING, half-mirrored
    again = sweep(results)
    assert again.returncode == 0, again.stderr
    assert client.get_run(half.info.run_id).info.status == "KILLED"
    assert client.get_run(half.info.run_id).info.lifecycle_stage == "deleted"
    assert_one_active_run_per_row(results)
