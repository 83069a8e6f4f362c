"""The exception that ends a training early on request, apart from the modules that train.

Apart (and free of torch) because the processes that ask for the stop (:mod:`runners.execute.stopping`,
the sweep's workers) must be able to catch it without loading torch, and the fleet's checkpoint
(:mod:`morality_gym.baselines.fleet.checkpoint`) raises it.
"""

from __future__ import annotations


class TrainingStopped(BaseException):
    """Training ended early on request (a SIGTERM), its state written: not an error of the runs.

    A ``BaseException``, as ``KeyboardInterrupt`` is, so that the ``except Exception`` that records
    a failed training as failed runs lets it through: the runs are not failed, they resume from
    the checkpoint when the sweep is run again (or SLURM requeues the job)."""


__all__ = ["TrainingStopped"]
