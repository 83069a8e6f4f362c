"""What a worker runs, named by its module path instead of imported: the training code.

Why by name: :mod:`runners.execute.jobs` imports the fleet engine, i.e. torch (about 1.5 s here),
which a worker process and a SLURM task need and the sweep's own process, which only checks,
plans, launches and waits, does not: a ``--help`` or a mistyped override is answered without it.
So the launchers hand a worker these light functions, and the worker imports the training code
when it first calls one. The name is an edge of the import graph like any other
(tests/test_layers.py reads module paths written as strings).
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any

#: The module a worker imports to execute its jobs.
TRAINING = "runners.execute.jobs"


def training() -> ModuleType:
    """:mod:`runners.execute.jobs`, imported on the first call (in a worker process or a SLURM task)."""
    return importlib.import_module(TRAINING)


def execute_job_all(*args: Any, **kwargs: Any) -> list[dict[str, Any]]:
    """:func:`runners.execute.jobs.execute_job_all` in the SLURM task (submitit pickles this light
    function by reference; the task imports the training code when it calls it)."""
    result: list[dict[str, Any]] = training().execute_job_all(*args, **kwargs)
    return result
