"""SIGTERM in a process that trains: checkpoint the fleet in training, then end cleanly.

SLURM sends SIGTERM when a job reaches its time limit or is preempted (and SIGKILL a grace period
later, ``KillWait``); submitit asks for SIGUSR2 shortly before the time limit; ``kill``, ``timeout``
and a stopping machine send SIGTERM too. Left to Python's default, a worker dies at once and the
fleet it trains loses everything since its last periodic checkpoint (up to ``checkpoint_every_s``,
300 s by default, of every run of the fleet).

A worker process (a local pool worker, a SLURM array task) calls :func:`install` once. Then:

* while a fleet trains with a checkpoint (:func:`stop_at_update`), the signal asks the checkpoint
  to stop (:meth:`~morality_gym.baselines.fleet.checkpoint.FleetCheckpoint.request_stop`): at the
  next update boundary the state is written and
  :class:`~morality_gym.baselines.stopped.TrainingStopped` ends the training;
* anywhere else (a single run training, a run being evaluated or written, an idle worker) the
  signal raises :class:`TrainingStopped` at once: every file is written under a temporary name and
  renamed, so what is interrupted leaves nothing behind, and the run is simply not recorded.

Either way the worker reports the runs it did not record as interrupted (not failed), and the
next sweep (or SLURM's requeue of the task) does them, the fleet resuming from its checkpoint. A
second signal while the first is handled is ignored.
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from types import FrameType
from typing import Any

from morality_gym.baselines.stopped import TrainingStopped

#: The signals that mean "stop soon": SIGTERM (time limit, preemption, kill), SIGUSR2 (submitit's
#: warning before the time limit, ``--signal=USR2@90``).
STOP_SIGNALS = (signal.SIGTERM, signal.SIGUSR2)

_state: dict[str, Any] = {"installed": False, "reason": None, "checkpoint": None}


def _handle(signum: int, _frame: FrameType | None) -> None:
    if _state["reason"] is not None:
        return  # already stopping
    reason = f"stopped by {signal.Signals(signum).name}"
    _state["reason"] = reason
    checkpoint = _state["checkpoint"]
    if checkpoint is not None:
        checkpoint.request_stop(reason)  # the fleet writes its state at the next update boundary
        return
    raise TrainingStopped(reason)


def install() -> None:
    """Handle :data:`STOP_SIGNALS` in this process as the module docstring says (main thread only)."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, _handle)
    _state["installed"] = True


def ignore() -> None:
    """Ignore :data:`STOP_SIGNALS` from now on: for a worker that has said its last word (a full
    disk reported, its runs reported stopped) and only ends. A SIGTERM the sweep sends to every
    worker as it stops would otherwise raise :class:`TrainingStopped` where nothing catches it any
    more, and print its traceback under the sweep's one line."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)


def stop_reason() -> str | None:
    """``stopped by SIGTERM`` once a stop signal arrived, else None."""
    return _state["reason"]


@contextlib.contextmanager
def stop_at_update(checkpoint: Any) -> Iterator[None]:
    """While the block runs (a fleet's ``learn``), a stop signal goes to ``checkpoint`` (None: a
    fleet without checkpoints, stopped at once like any other work)."""
    if not _state["installed"] or checkpoint is None:
        yield
        return
    if _state["reason"] is not None:  # the signal came before training started
        checkpoint.request_stop(_state["reason"])
    _state["checkpoint"] = checkpoint
    try:
        yield
    finally:
        _state["checkpoint"] = None


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Hold the stop signals back while the block runs (a message to the parent is sent whole)."""
    if not _state["installed"]:
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


__all__ = ["STOP_SIGNALS", "TrainingStopped", "install", "signals_held", "stop_at_update", "stop_reason"]
