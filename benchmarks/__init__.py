"""Speed benchmarks of MoralityGym (measurements, not tests): ``python -m benchmarks.run``.

This package holds the small framework; :mod:`benchmarks.run` holds the environment benchmarks
and the command line that writes ``BENCHMARKS.md``.

Importing the package pins numpy's and torch's thread pools to one thread. It must happen before
numpy is first imported (the BLAS/OpenMP pools read these variables once, at load time), which is
why it sits here: ``python -m benchmarks.run`` imports this ``__init__`` before ``run``. One thread
makes the numbers per-core figures that do not depend on how many cores the machine has or how
busy the others are.

Adding a section (the extension point). Write a function that takes a :class:`Context` and returns
a :class:`Section`, decorate it with :func:`register`, and put it either in ``benchmarks/run.py``
or in a module ``benchmarks/bench_<topic>.py`` (``run`` imports every such module before it
starts)::

    from benchmarks import Context, Section, best_time, register

    @register("oracle", "Oracle search", order=60)
    def oracle_speed(ctx: Context) -> Section:
        timing = best_time(lambda: ..., ctx.repeats)  # .cpu and .wall seconds
        return Section(intro="...", headers=["env id", "ms"], rows=[[f"{timing.cpu * 1e3:.1f}"]])

Sections run and appear in ``order`` (ties: registration order); ``--only KEY`` selects some.
"""

from __future__ import annotations

import os

_THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "BLIS_NUM_THREADS",
)
for _name in _THREAD_VARIABLES:
    os.environ[_name] = "1"

# The imports below come after the thread pinning on purpose (none of them loads numpy, but a
# future one might).
import gc
import resource
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

THREAD_VARIABLES = _THREAD_VARIABLES


@dataclass
class Context:
    """What every benchmark function gets: the run's size, its repeat count and progress output.

    ``quick`` runs shrink the work about tenfold (for a smoke check, not for quoting numbers).
    ``progress`` is a ``rich.progress.Progress`` (or ``None`` when progress is switched off).
    ``releases`` and ``results``: real result sets for the sections that time them (results
    releases, empty: every release under ``releases/``; a results directory of one's own, which
    lives outside the repository).
    """

    quick: bool
    repeats: int
    progress: Any = None
    releases: tuple[Path, ...] = ()
    results: Path | None = None

    def size(self, full: int, quick: int) -> int:
        """The amount of work for this run: ``full`` normally, ``quick`` with ``--quick``."""
        return quick if self.quick else full

    def task(self, description: str, total: int) -> Task:
        """A progress bar for ``total`` units of work (a no-op when progress is off)."""
        return Task(self.progress, description, total)


class Task:
    """One progress bar; ``advance()`` after each unit of work, ``done()`` at the end."""

    def __init__(self, progress: Any, description: str, total: int) -> None:
        self._progress = progress
        self._id = progress.add_task(description, total=total) if progress is not None else None

    def advance(self, amount: int = 1) -> None:
        if self._progress is not None:
            self._progress.advance(self._id, amount)

    def done(self) -> None:
        if self._progress is not None:
            self._progress.remove_task(self._id)


@dataclass
class Section:
    """One section of ``BENCHMARKS.md``: an explanation, a table and notes (e.g. targets met)."""

    intro: str
    headers: list[str]
    rows: list[list[str]]
    notes: list[str] = field(default_factory=list)
    title: str = ""  # filled in from the registry
    #: The columns a ``--baseline`` comparison sets beside an older revision's (default: all but the first).
    compare: list[str] | None = None

    def markdown(self) -> str:
        lines = [f"## {self.title}", "", self.intro.strip(), ""]
        if self.rows:
            lines.append("| " + " | ".join(self.headers) + " |")
            lines.append("|" + "|".join("---:" if i else "---" for i in range(len(self.headers))) + "|")
            lines += ["| " + " | ".join(row) + " |" for row in self.rows]
            lines.append("")
        for note in self.notes:
            lines.append(f"- {note}")
        if self.notes:
            lines.append("")
        return "\n".join(lines)


BenchmarkFn = Callable[[Context], Section]


@dataclass(frozen=True)
class Benchmark:
    """A registered benchmark: its key (for ``--only``), section title, position and function."""

    key: str
    title: str
    order: int
    index: int
    run: BenchmarkFn


REGISTRY: dict[str, Benchmark] = {}


def register(key: str, title: str, order: int = 100) -> Callable[[BenchmarkFn], BenchmarkFn]:
    """Decorator adding a benchmark function under ``key`` (unique) with its section ``title``."""

    def add(fn: BenchmarkFn) -> BenchmarkFn:
        known = REGISTRY.get(key)
        # The same function may register twice when its module runs both as ``__main__`` and as
        # ``benchmarks.run``; a different function under a taken key is a mistake.
        if known is not None and known.run.__qualname__ != fn.__qualname__:
            raise ValueError(
                f"benchmark {key!r} is already registered by {known.run.__module__}.{known.run.__qualname__}"
            )
        REGISTRY[key] = Benchmark(key, title, order, known.index if known else len(REGISTRY), fn)
        return fn

    return add


def ordered() -> list[Benchmark]:
    """The registered benchmarks in report order."""
    return sorted(REGISTRY.values(), key=lambda b: (b.order, b.index))


@dataclass(frozen=True)
class Timing:
    """The best (smallest) wall-clock and CPU seconds over the repeats of one measurement.

    Both are kept because the machines this runs on are often shared: when another process takes
    the core, wall-clock time grows but this process's CPU time does not. The CPU figure is
    therefore the steadier measure of the code's own speed; the wall-clock one is what a user
    waits. The two minima may come from different repeats.
    """

    wall: float
    cpu: float


def best_time(work: Callable[[], object], repeats: int, setup: Callable[[], object] | None = None) -> Timing:
    """Time ``work()`` ``repeats`` times (after an untimed ``setup()`` each time); keep the best.

    The minimum is the figure least disturbed by other work on the machine; the garbage
    collector is paused while measuring, as ``timeit`` does.
    """
    walls, cpus = [], []
    for _ in range(max(1, repeats)):
        if setup is not None:
            setup()
        enabled = gc.isenabled()
        gc.disable()
        try:
            wall0, cpu0 = time.perf_counter(), time.process_time()
            work()
            walls.append(time.perf_counter() - wall0)
            cpus.append(time.process_time() - cpu0)
        finally:
            if enabled:
                gc.enable()
    return Timing(min(walls), min(cpus))


def fmt_rate(per_second: float) -> str:
    """``1,234,567`` style integers for steps per second."""
    return f"{per_second:,.0f}"


__all__ = [
    "REGISTRY",
    "THREAD_VARIABLES",
    "Benchmark",
    "BenchmarkFn",
    "Context",
    "Section",
    "Task",
    "Timing",
    "best_time",
    "fmt_rate",
    "ordered",
    "register",
]


@dataclass(frozen=True)
class TimedCommand:
    """A command run as a user runs it: its wall-clock and CPU (user + system) seconds, and its output."""

    wall: float
    cpu: float  # on a loaded machine, wall says little
    stdout: str


def timed_command(command: list[str], cwd: Path, env: dict[str, str] | None = None) -> TimedCommand:
    """Run ``command`` in a subprocess (failing loudly) and time it, the CPU of its children included."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.run(command, cwd=cwd, check=True, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return TimedCommand(wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), proc.stdout)

