"""What every writer of a run's result uses, the sweep's workers and the leaderboard's submissions alike.

A run's row records when it ran and with what (:func:`utc_now`, :func:`git_commit`,
:func:`versions`, :class:`RunClock`); a run is written by one process at a time (:class:`RunLock`,
a per-run ``flock`` the kernel releases even on ``kill -9``); and a run counts as done when its
result file can be read (:func:`finished_status`; an unreadable one is moved aside by
:mod:`morality_gym.results.quarantine`, so the run is done again).
"""

from __future__ import annotations

import fcntl
import json
import platform
import subprocess
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import lru_cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from morality_gym.results.quarantine import read_table_or_quarantine
from morality_gym.results.schema import run_path, runs_dir


def utc_now() -> str:
    """The time now, UTC, to the second (ISO 8601): the rows' ``started_at`` / ``finished_at``."""
    return datetime.now(UTC).isoformat(timespec="seconds")


@lru_cache(maxsize=1)
def git_commit() -> str:
    """The commit of the checkout this code runs from, or "unknown" (an installed package: its
    version is recorded with the others). A package installed into a virtual environment that
    happens to sit inside some git work tree must not report that tree's commit, so the answer
    counts only if the work tree's ``morality_gym/results/recording.py`` is this very file.

    Asked once per process (workers ask at start, when they import the code): a sweep runs for
    hours, and a commit made meanwhile must not be recorded for runs of the code loaded before it
    (a worker started at one commit recorded the checkout's later HEAD)."""
    here = Path(__file__).resolve()
    try:
        out = subprocess.run(["git", "rev-parse", "--show-toplevel", "HEAD"], cwd=here.parent,
                             capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    lines = out.stdout.split()
    if out.returncode != 0 or len(lines) != 2 or (Path(lines[0]) / "morality_gym" / "results" / "recording.py").resolve() != here:
        return "unknown"
    return lines[1]


@lru_cache(maxsize=1)
def versions() -> str:
    out = {"python": platform.python_version()}
    for pkg in ("morality-gym", "numpy", "torch", "gymnasium", "stable-baselines3", "sb3-contrib", "pyarrow", "mlflow"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "not installed"
    return json.dumps(out, sort_keys=True)


class RunLock:
    """An exclusive, non-blocking lock per run id (None if another live process holds it)."""

    def __init__(self, results_dir: Path, run_id: str) -> None:
        directory = runs_dir(results_dir) / ".locks"
        directory.mkdir(parents=True, exist_ok=True)
        self.path = directory / f"{run_id}.lock"
        self.fh: Any = None

    def acquire(self) -> bool:
        self.fh = open(self.path, "a+")  # noqa: SIM115 - held open while the lock is held; closed by release()
        try:
            fcntl.flock(self.fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            self.fh.close()
            self.fh = None
            return False

    def release(self) -> None:
        if self.fh is not None:
            fcntl.flock(self.fh, fcntl.LOCK_UN)
            self.fh.close()
            self.fh = None


def finished_status(results_dir: Path, run_id: str) -> str | None:
    """``ok`` / ``failed`` if the run has a readable result file, else None (an unreadable one is
    moved aside by :mod:`morality_gym.results.quarantine`, so the run is done again)."""
    table = read_table_or_quarantine(results_dir, run_path(results_dir, run_id), columns=["status"])
    return None if table is None else str(table.column("status")[0].as_py())


@dataclass(frozen=True)
class RunClock:
    """When a run started, by the wall clock and by this process's CPU clock.

    Why both: a run's ``wall_time_s`` is what a user waited, but on a shared or oversubscribed
    machine (a niced sweep beside other work, more workers than cores) it overstates the compute
    the run needed; ``cpu_time_s`` (CPU seconds of the worker process, every thread counted) is the
    compute, whatever else the machine did. Budgets and the planner's rates are about compute."""

    started: str
    wall0: float
    cpu0: float

    @classmethod
    def start(cls) -> RunClock:
        return cls(utc_now(), time.perf_counter(), time.process_time())

    def elapsed(self) -> tuple[float, float]:
        """(wall seconds, CPU seconds) since the start."""
        return time.perf_counter() - self.wall0, time.process_time() - self.cpu0

    @classmethod
    def already_spent(cls, started: str, wall: float, cpu: float) -> RunClock:
        """A clock that reads (``wall``, ``cpu``) now: a fleet's run starts from its share of the
        fleet's training, so that summing over the fleet's runs still gives what the fleet spent."""
        return cls(started, time.perf_counter() - wall, time.process_time() - cpu)
