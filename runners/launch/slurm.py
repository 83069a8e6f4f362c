"""Dispatch jobs to SLURM as one submitit job array (one array task per job: a run or a fleet).

Every array task calls :func:`runners.execute.jobs.execute_job_all` (named: :mod:`runners.launch.entry_points`), which records each run's result
(including failures) in Parquet; the parent polls the jobs, and records the runs whose jobs died
without a result (time limit, ``kill -9``, node failure) as failed with SLURM's view of what
happened. A fleet job that died after writing some of its runs keeps those.
Partition, time limit, CPUs, memory and array parallelism come from ``conf/launcher/slurm.yaml``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from morality_gym.baselines.device import CPU, Device
from morality_gym.baselines.specs import DEFAULT_UPDATE_ENGINE
from runners.launch.entry_points import execute_job_all
from runners.plan.fleets import Job
from runners.plan.runs import PlannedRun


def run_on_slurm(
    jobs_: list[Job],
    launcher: Mapping[str, Any],
    results_dir: Path,
    gif: bool,
    sweep_name: str,
    on_result: Callable[[PlannedRun, dict[str, Any]], None],
    on_failure: Callable[[PlannedRun, str], None],
    device: Device = CPU,
    checkpoint_every_s: float = 0.0,
    fleet_update: str = DEFAULT_UPDATE_ENGINE,
) -> None:
    """Submit ``jobs_`` as one array and poll it, reporting each run as its array task ends (a
    fleet checkpoints its training every ``checkpoint_every_s`` seconds; 0: never; its updates run
    on the ``fleet_update`` engine)."""
    jobs = _submit(jobs_, launcher, results_dir, gif, sweep_name, device, checkpoint_every_s, fleet_update)
    pending = dict(zip(range(len(jobs_)), jobs))
    poll = float(launcher.get("poll_s", 2.0))
    while pending:
        for i in list(pending):
            if pending[i].done():
                _collect(pending.pop(i), jobs_[i], on_result, on_failure)
        if pending:
            time.sleep(poll)


def _submit(jobs_: list[Job], launcher: Mapping[str, Any], results_dir: Path, gif: bool, sweep_name: str,
            device: Device, checkpoint_every_s: float = 0.0, fleet_update: str = DEFAULT_UPDATE_ENGINE) -> list[Any]:
    """One submitit array task per job, with the launcher's partition and resources."""
    import submitit  # submitit waits: importing runners.launch.slurm must not load it

    folder = Path(launcher.get("folder") or results_dir / "slurm" / sweep_name)
    folder.mkdir(parents=True, exist_ok=True)
    executor = submitit.AutoExecutor(folder=folder / "%j", cluster="slurm")
    executor.update_parameters(
        name=f"mg-{sweep_name}"[:60],
        slurm_partition=launcher["partition"],
        timeout_min=int(launcher["timeout_min"]),
        cpus_per_task=int(launcher["cpus_per_task"]),
        mem_gb=int(launcher["mem_gb"]),
        slurm_array_parallelism=int(launcher["array_parallelism"]),
        tasks_per_node=1,
        nodes=1,
    )
    return executor.map_array(
        execute_job_all,
        [j.items for j in jobs_],
        [str(results_dir)] * len(jobs_),
        [gif] * len(jobs_),
        [j.engine for j in jobs_],
        [device] * len(jobs_),
        [checkpoint_every_s] * len(jobs_),
        [fleet_update] * len(jobs_),
    )


def _collect(
    job: Any,
    planned: Job,
    on_result: Callable[[PlannedRun, dict[str, Any]], None],
    on_failure: Callable[[PlannedRun, str], None],
) -> None:
    """Report every run of a finished array task: its summaries, or, for a task that died without
    a result, a failure for each run (``on_failure`` keeps what a run wrote before the task died).
    No run is silently lost."""
    runs = {r.run_id: r for r in planned.runs}
    try:
        summaries = job.result()
    except Exception as exc:  # noqa: BLE001 - a lost job is recorded, whatever SLURM says
        lost = f"SLURM job {job.job_id} ended without a result: {type(exc).__name__}: {str(exc)[:500]}"
        for run in runs.values():
            on_failure(run, lost)
        return
    for summary in summaries:
        run = runs.pop(summary["run_id"], None)
        if run is None:
            continue
        if summary.get("status") == "busy":
            on_failure(run, f"SLURM job {job.job_id}: the run was locked by another process")
        else:
            on_result(run, summary)
    for run in runs.values():  # not reported by the task (should not happen): never silently lost
        on_failure(run, f"SLURM job {job.job_id} returned no result for this run")
