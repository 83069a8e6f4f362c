"""Dispatch runs to SLURM as one submitit job array (one array task per run).

Every array task calls :func:`runners.execute.execute`, which records its own result (including
failures) in Parquet; the parent polls the jobs, and records the runs whose jobs died without a
result (time limit, ``kill -9``, node failure) as failed with SLURM's view of what happened.
Partition, time limit, CPUs, memory and array parallelism come from ``conf/launcher/slurm.yaml``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from runners.plan import PlannedRun
from runners.slurm_controller import SlurmUnavailable, check_controller  # noqa: F401 - re-exported for callers


def run_on_slurm(
    runs: list[PlannedRun],
    launcher: Mapping[str, Any],
    results_dir: Path,
    gif: bool,
    sweep_name: str,
    on_result: Callable[[PlannedRun, dict[str, Any]], None],
    on_failure: Callable[[PlannedRun, str], None],
) -> None:
    import submitit

    from runners.execute import execute

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
    jobs = executor.map_array(
        execute,
        [r.config for r in runs],
        [r.run_id for r in runs],
        [str(results_dir)] * len(runs),
        [gif] * len(runs),
    )
    pending = dict(zip(range(len(runs)), jobs))
    poll = float(launcher.get("poll_s", 2.0))
    while pending:
        for i in list(pending):
            job = pending[i]
            if not job.done():
                continue
            del pending[i]
            run = runs[i]
            try:
                summary = job.result()
            except Exception as exc:  # noqa: BLE001 - a lost job is recorded, whatever SLURM says
                on_failure(run, f"SLURM job {job.job_id} ended without a result: {type(exc).__name__}: {str(exc)[:500]}")
                continue
            if summary.get("status") == "busy":
                on_failure(run, f"SLURM job {job.job_id}: the run was locked by another process")
            else:
                on_result(run, summary)
        if pending:
            time.sleep(poll)
