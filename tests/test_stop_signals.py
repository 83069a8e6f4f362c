"""SIGTERM (a SLURM time limit or preemption, ``timeout``, a stopping machine) stops a sweep cleanly.

Issue 33: a fleet in training writes its checkpoint at the next update boundary and the sweep ends
with one line (exit 143, no traceback, no run recorded as failed); the same sweep run again
resumes the fleet at exactly the step where it stopped. Sent to the sweep's own process (it tells
its workers) and to its whole process group (what ``timeout`` and SLURM do), and, with the real
single-node SLURM cluster, to a sweep's array task with ``scancel --signal=TERM``.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from morality_gym.results.schema import read_runs
from tests.sweep_tools import run_files, wait_for_results

REPO = Path(__file__).resolve().parents[1]
BUDGET = 16384  # 16 updates of 1,024 steps: the signal lands after the first ones, long before training ends
FLEET = ["algo=ppo_lag", "chain=utility", "scenario=[switch_standard]", "preset=smoke", "seed=[1]",
         "variant=[HumanA,HumanB,AnimalA]", f"preset.budget={BUDGET}", "preset.learn_eval_every=30000",
         "checkpoint_every_s=0.000001", "mlflow=false", "gif=false"]
WAIT_S = 300  # upper bound on any wait: a hang fails the test instead of blocking it


def sweep_args(results: Path, *overrides: str) -> list[str]:
    return [sys.executable, "-m", "runners.sweep", f"results_dir={results}", *overrides]


def clean_env() -> dict[str, str]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)
    env.pop("MORALITY_GYM_DEBUG", None)
    return env


def start(results: Path, *overrides: str) -> subprocess.Popen:
    """A sweep in its own session (its own process group), output captured."""
    return subprocess.Popen(sweep_args(results, *overrides), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=clean_env(), start_new_session=True)


def finish(results: Path, *overrides: str) -> subprocess.CompletedProcess:
    return subprocess.run(sweep_args(results, *overrides), cwd=REPO, check=False, capture_output=True, text=True,
                          timeout=900, env=clean_env())


def wait_for_checkpoint(results: Path, proc: subprocess.Popen | None = None) -> Path:
    """The fleet's checkpoint file, once training has written it (training is then under way)."""
    deadline = time.monotonic() + WAIT_S
    while True:
        found = list((results / "checkpoints").glob("fleet-*.pt"))
        if found:
            return found[0]
        assert proc is None or proc.poll() is None, proc.stdout.read() if proc and proc.stdout else ""
        assert time.monotonic() < deadline, "no checkpoint was written"
        time.sleep(0.02)


def stopped_step(output: str) -> int:
    """Where the fleet said it stopped (``... stopped at 3,072 of 32,768 steps, checkpoint ...``)."""
    match = re.search(r"fleet of 3 runs stopped at ([\d,]+) of ([\d,]+) steps", output)
    assert match is not None, output
    assert int(match.group(2).replace(",", "")) == BUDGET
    return int(match.group(1).replace(",", ""))


def resumed_step(output: str) -> int:
    match = re.search(r"fleet of 3 runs resumed at ([\d,]+) of ([\d,]+) steps", output)
    assert match is not None, output
    return int(match.group(1).replace(",", ""))


def assert_nothing_failed_and_nothing_left(results: Path) -> None:
    """No run file (none failed, none half-written), no temporary file, the checkpoint whole."""
    assert not run_files(results)
    assert not [p for p in results.rglob("*") if p.name.endswith(".tmp")]
    assert len(list((results / "checkpoints").glob("fleet-*.pt"))) == 1


@pytest.mark.slow
@pytest.mark.parametrize("target", ["sweep", "process group"])
def test_sigterm_checkpoints_the_fleet_and_the_rerun_resumes_it(tmp_path: Path, target: str) -> None:
    results = tmp_path / "r"
    proc = start(results, *FLEET, "launcher.workers=1")
    wait_for_checkpoint(results, proc)
    if target == "sweep":
        os.kill(proc.pid, signal.SIGTERM)  # the sweep tells its workers
    else:
        os.killpg(proc.pid, signal.SIGTERM)  # every process at once, as timeout(1) and SLURM do
    output = proc.communicate(timeout=WAIT_S)[0]
    assert proc.returncode == 143, output
    assert "Traceback" not in output, output
    lines = [line for line in output.splitlines() if "run(s) interrupted" in line]
    expected = ("stopped by SIGTERM: 3 run(s) interrupted, none recorded as failed; fleets in training wrote their "
                "checkpoints; run the same command again to resume")
    assert lines == [expected], output
    step = stopped_step(output)
    assert 0 < step < BUDGET
    assert_nothing_failed_and_nothing_left(results)

    again = finish(results, *FLEET, "launcher.workers=1")
    assert again.returncode == 0, again.stderr
    assert resumed_step(again.stderr) == step  # nothing trained before the stop is trained again
    runs = read_runs(results)
    assert len(runs) == 3 and (runs.status == "ok").all() and (runs.total_steps == BUDGET).all()
    assert not list((results / "checkpoints").glob("fleet-*"))  # removed once the runs were recorded


@pytest.mark.slow
def test_sigterm_between_single_runs_records_no_failure(tmp_path: Path) -> None:
    """Runs without a fleet stop at once: what was written stays, nothing is recorded as failed."""
    results = tmp_path / "r"
    args = ["algo=random", "chain=utility", "scenario=[switch_standard]", "preset=smoke", "seed=[41]", "mlflow=false",
            "gif=false", "launcher.workers=1"]
    proc = start(results, *args)
    wait_for_results(results, 2, proc)
    os.killpg(proc.pid, signal.SIGTERM)
    output = proc.communicate(timeout=WAIT_S)[0]
    assert proc.returncode == 143 and "Traceback" not in output, output
    assert sum("run(s) interrupted, none recorded as failed" in line for line in output.splitlines()) == 1, output
    written = read_runs(results)
    assert 2 <= len(written) < 12 and (written.status == "ok").all()
    assert not [p for p in results.rglob("*") if p.name.endswith(".tmp")]
    again = finish(results, *args)
    assert again.returncode == 0, again.stderr
    assert f"{len(written)} done, {12 - len(written)} to run" in again.stderr
    assert len(read_runs(results)) == 12


# ---------------------------------------------------------------------------------------- SLURM
def _array_job(name_prefix: str) -> str | None:
    """The id of the running job array task of the sweep named ``name_prefix`` (None until it runs)."""
    out = subprocess.run(["squeue", "-h", "-t", "RUNNING", "-o", "%i %j"], capture_output=True, text=True, timeout=30,
                         check=False).stdout
    for line in out.splitlines():
        job_id, _, name = line.partition(" ")
        if name.startswith(name_prefix):
            return job_id
    return None


@pytest.mark.slurm
@pytest.mark.slow
def test_scancel_term_checkpoints_a_slurm_fleet_and_the_rerun_resumes_it(slurm_cluster, tmp_path: Path) -> None:
    """``scancel --signal=TERM`` (what SLURM sends at a time limit or on preemption) reaches the
    array task; its fleet writes the checkpoint and the task reports its runs interrupted (none
    failed); the sweep ends with one line saying so, and the next sweep resumes the fleet."""
    results = tmp_path / "r"
    args = [*FLEET, "launcher=slurm", "launcher.poll_s=0.5", f"launcher.partition={slurm_cluster.partition}",
            "launcher.timeout_min=10", "name=sigterm"]
    proc = start(results, *args)
    wait_for_checkpoint(results, proc)
    job_id = _array_job("mg-sigterm")
    assert job_id is not None, "the sweep's array task is not running"
    sent = subprocess.run(["scancel", "--signal=TERM", job_id], capture_output=True, text=True, timeout=30, check=False)
    assert sent.returncode == 0, sent.stderr
    output = proc.communicate(timeout=WAIT_S)[0]
    assert proc.returncode == 1, output  # 3 runs missing: not done, not failed
    assert "Traceback" not in output, output
    assert "0 ok, 0 failed, 3 missing (of 3)" in output, output
    lines = [line for line in output.splitlines() if "run(s) interrupted" in line]
    assert len(lines) == 1 and lines[0].startswith("SLURM task(s) stopped by a signal (time limit or preemption): 3 run(s)"), output
    assert_nothing_failed_and_nothing_left(results)

    again = finish(results, *args)
    assert again.returncode == 0, again.stderr
    assert "1 fleet(s) resume their training from a checkpoint" in " ".join(again.stderr.split()), again.stderr
    logs = "".join(p.read_text(errors="replace") for p in (results / "slurm" / "sigterm").rglob("*.err"))
    assert 0 < resumed_step(logs) < BUDGET  # the second task's log: trained on from the checkpoint
    runs = read_runs(results)
    assert len(runs) == 3 and (runs.status == "ok").all() and (runs.total_steps == BUDGET).all()
