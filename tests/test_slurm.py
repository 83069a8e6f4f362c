"""End-to-end checks of the project's single-node SLURM cluster with submitit, as the sweeps use it.

Needs root and the Debian packages (see runners/slurm/README.md); the ``slurm_cluster`` fixture
(tests/slurm_cluster.py) starts the cluster if it is not already running, or skips.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Sequence

import cloudpickle
import pytest
import submitit
from submitit.core.utils import FailedJobError, UncompletedJobError

pytestmark = pytest.mark.slurm

# The job functions below travel to the jobs by value, so the jobs need not import this test
# module (which would depend on the directory pytest was started from).
cloudpickle.register_pickle_by_value(sys.modules[__name__])

WAIT_S = 120  # upper bound on any wait for jobs: a hang fails the test instead of blocking CI


def square_job(x: int) -> dict:
    return {
        "value": x * x,
        "array_job": os.environ.get("SLURM_ARRAY_JOB_ID"),
        "array_task": os.environ.get("SLURM_ARRAY_TASK_ID"),
        "python": sys.executable,
    }


def raising_job(message: str) -> None:
    raise ValueError(message)


def hard_exit_job() -> None:
    os._exit(7)  # no result pickle, no traceback: only SLURM (sacct) can tell submitit it failed


def make_executor(folder, partition: str) -> submitit.AutoExecutor:
    executor = submitit.AutoExecutor(folder=folder / "%j", cluster="slurm", slurm_python=sys.executable)
    # timeout_min >= 5: submitit asks for USR2 signal_delay_s (120 s) before the limit and SLURM may
    # send it up to ~60 s early, so a shorter limit can kill even short jobs.
    executor.update_parameters(slurm_partition=partition, cpus_per_task=1, timeout_min=5, slurm_array_parallelism=2)
    return executor


def wait_done(jobs: Sequence[submitit.Job], timeout: float = WAIT_S) -> None:
    """Wait until every job is finished (result written or SLURM says it ended), at most `timeout` s."""
    deadline = time.monotonic() + timeout
    pending = list(jobs)
    while pending:
        # force_check: ask sacct every quarter second instead of submitit's backing-off schedule.
        pending = [job for job in pending if not job.done(force_check=True)]
        if pending and time.monotonic() > deadline:
            for job in pending:
                job.cancel(check=False)
            states = {job.job_id: job.state for job in pending}
            pytest.fail(f"jobs not finished after {timeout:.0f} s (states: {states}); cancelled them")
        if pending:
            time.sleep(0.25)


def sacct_states(job_id: str) -> dict[str, str]:
    out = subprocess.run(
        ["sacct", "-n", "-P", "-X", "-j", job_id, "-o", "JobID,State"],
        capture_output=True,
        text=True,
        timeout=30,
        check=True,
    ).stdout
    return dict(line.split("|", 1) for line in out.splitlines() if "|" in line)


@pytest.fixture(scope="module")
def array_jobs(slurm_cluster, tmp_path_factory) -> list[submitit.Job]:
    """One job array of 4 tasks, at most 2 at a time (shared by the result and sacct tests)."""
    executor = make_executor(tmp_path_factory.mktemp("submitit_array"), slurm_cluster.partition)
    jobs = executor.map_array(square_job, [1, 2, 3, 4])
    wait_done(jobs)
    return jobs


def test_srun_hostname(slurm_cluster):
    proc = subprocess.run(
        ["srun", "-N1", "-n1", "-p", slurm_cluster.partition, "hostname"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == socket.gethostname()


def test_node_resources(slurm_cluster):
    assert slurm_cluster.partition == "debug"
    assert slurm_cluster.cpus == len(os.sched_getaffinity(0))  # what nproc counts
    assert 0 < slurm_cluster.memory_mb < os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") // 2**20


def test_job_array_results(array_jobs):
    results = [job.result() for job in array_jobs]
    assert [r["value"] for r in results] == [1, 4, 9, 16]
    # One array, not four separate jobs, and each task ran with the venv's Python.
    array_ids = {job.job_id.split("_")[0] for job in array_jobs}
    assert len(array_ids) == 1
    assert {r["array_job"] for r in results} == array_ids
    assert sorted(r["array_task"] for r in results) == ["0", "1", "2", "3"]
    assert {r["python"] for r in results} == {sys.executable}


def test_raising_job_surfaces_original_error(slurm_cluster, tmp_path):
    job = make_executor(tmp_path, slurm_cluster.partition).submit(raising_job, "boom from inside the job 4711")
    wait_done([job])
    with pytest.raises(FailedJobError) as info:
        job.result()
    assert "ValueError: boom from inside the job 4711" in str(info.value)


def test_hard_killed_job_fails_instead_of_hanging(slurm_cluster, tmp_path):
    # Without accounting, sacct cannot report this job and submitit would wait for it forever.
    job = make_executor(tmp_path, slurm_cluster.partition).submit(hard_exit_job)
    wait_done([job])
    # after done(), result() waits up to submitit's _results_timeout_s (15 s, for slow shared file
    # systems) for a result file that this job never writes; a local disk needs no such grace
    job._results_timeout_s = 1
    with pytest.raises(UncompletedJobError) as info:
        job.result()  # waits at most the second above for a result file, then raises
    assert "has not produced any output" in str(info.value)
    assert job.state == "FAILED"


def test_sacct_lists_array_tasks_completed(array_jobs):
    array_id = array_jobs[0].job_id.split("_")[0]
    expected = {job.job_id: "COMPLETED" for job in array_jobs}
    # Records reach slurmdbd a couple of seconds after the jobs end: retry for a while.
    deadline = time.monotonic() + 30
    while (states := sacct_states(array_id)) != expected and time.monotonic() < deadline:
        time.sleep(0.5)
    assert states == expected
