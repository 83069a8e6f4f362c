"""The generalisation track's start: ``load_split`` (first generation and cached) and ``runners.track``.

Why: issue 44 measured the first ``load_split("train")`` at about 15 minutes and every later call at
3-10 minutes (every cached file's bounds enumerated again), before the first run of
``runners.track`` and also when every run was done. Its targets: a cached split, and the track's
start with every run done, under 30 s on 2 cores; the first generation parallel, with progress.

Each step is a fresh subprocess, as a user runs it, with its own empty ``MORALITY_GYM_CACHE`` and
*not* pinned (the benchmark process is pinned to one core; a first generation uses every core the
process may use), so wall and CPU seconds are given, with the 1-minute load average before and
after each step: the machine is shared, and wall time depends on what else runs.
``python -m benchmarks.bench_splits [--code DIR] [--keep-cache DIR]`` runs the same steps alone and
prints them (``--code``: a checkout of another revision, imported through ``PYTHONPATH``; its
``runners.track`` may lack ``--chain``, whose steps are then skipped). ``make bench`` runs them in a
temporary cache, or in ``$MORALITY_GYM_BENCH_SPLITS_CACHE`` (an empty directory, kept afterwards).
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from benchmarks import Context, Section, register

REPO = Path(__file__).resolve().parents[1]
TARGET_SECONDS = 30.0
#: An empty directory to use as the steps' cache and keep afterwards (default: a temporary one).
KEEP_ENV = "MORALITY_GYM_BENCH_SPLITS_CACHE"
_LOAD = "from morality_gym.generator.splits import load_split; print(len(load_split({split!r})))"


@dataclass(frozen=True)
class Step:
    label: str
    wall: float
    cpu: float  # user + system seconds of the step's process and its children (workers)
    load: tuple[float, float]  # 1-minute load average before and after
    output: str


def _load_average() -> float:
    return float(Path("/proc/loadavg").read_text().split()[0]) if Path("/proc/loadavg").is_file() else float("nan")


def _unpinned() -> None:
    """A child may use every CPU (the benchmark process itself is pinned to one)."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, range(os.cpu_count() or 1))


def run_step(label: str, command: list[str], env: dict[str, str], cwd: Path) -> Step:
    """Run ``command`` (failing loudly) and time it, its children's CPU included."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load0, start = _load_average(), time.perf_counter()
    proc = subprocess.run(command, check=False, cwd=cwd, env=env, capture_output=True, text=True, preexec_fn=_unpinned)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"{label}: {' '.join(command)} failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return Step(label, wall, cpu, (load0, _load_average()), proc.stdout + proc.stderr)


class Steps(list[Step]):
    """The steps so far; ``shown`` prints each as it finishes (a full run takes many minutes)."""

    def __init__(self, shown: bool = False) -> None:
        super().__init__()
        self.shown = shown

    def append(self, step: Step) -> None:
        super().append(step)
        if self.shown:
            print(" | ".join(_row(step)), flush=True)


def measure(cache: Path, code: Path = REPO, quick: bool = False, chain: str | None = "Utility",
            shown: bool = False) -> list[Step]:
    """The steps, in order, on an empty ``cache`` (``quick``: the ``test`` split only, no track)."""
    env = {**os.environ, "MORALITY_GYM_CACHE": str(cache), "PYTHONPATH": str(code), "OMP_NUM_THREADS": "1"}
    python = sys.executable
    steps = Steps(shown)
    splits = ["test"] if quick else ["train", "test"]
    for split in splits:
        steps.append(run_step(f'load_split("{split}"), first (generates)', [python, "-c", _LOAD.format(split=split)], env, code))
        steps.append(run_step(f'load_split("{split}"), cached', [python, "-c", _LOAD.format(split=split)], env, code))
    if quick:
        return steps
    track = [python, "-m", "runners.track", "--learners", "random", "--out", str(cache / "track-results")]
    steps.append(run_step("runners.track --learners random, first (computes the sets' exact values)", track, env, code))
    steps.append(run_step("runners.track --learners random, every run done", track, env, code))
    has_chain = "--chain" in subprocess.run([python, "-m", "runners.track", "--help"], check=False, cwd=code, env=env,
                                            capture_output=True, text=True).stdout
    if chain is not None and has_chain:
        chained = [*track, "--chain", chain]
        steps.append(run_step(f"runners.track --chain {chain} --learners random, first (the chain's pool values)",
                              chained, env, code))
        steps.append(run_step(f"runners.track --chain {chain} --learners random, every run done", chained, env, code))
    return steps


def _row(step: Step) -> list[str]:
    return [step.label, f"{step.wall:.1f}", f"{step.cpu:.1f}", f"{step.load[0]:.2f} / {step.load[1]:.2f}"]


@register("splits", "Generalisation track start: load_split (first and cached) and runners.track with every run done",
          order=88)
def splits_speed(ctx: Context) -> Section:
    keep = os.environ.get(KEEP_ENV)
    if keep:  # the populated cache is worth keeping (the exact values took minutes)
        Path(keep).mkdir(parents=True, exist_ok=True)
        if any(Path(keep).iterdir()):
            raise SystemExit(f"{KEEP_ENV}={keep}: not empty; the first steps must start from an empty cache")
        steps = measure(Path(keep), quick=ctx.quick)
    else:
        with tempfile.TemporaryDirectory(prefix="bench-splits-") as tmp:
            steps = measure(Path(tmp), quick=ctx.quick)
    cpus = os.cpu_count()  # what the unpinned steps may use (this process itself is pinned to one)
    cached = [s for s in steps if s.label.endswith(("cached", "every run done"))]
    worst = max(cached, key=lambda s: s.wall)
    notes = [f"Target (issue 44): a cached split and the track's start with every run done under {TARGET_SECONDS:.0f} s "
             f"on 2 cores. Slowest of them: {worst.label}, {worst.wall:.1f} s wall at load average "
             f"{worst.load[0]:.1f} / {worst.load[1]:.1f} ({worst.cpu:.1f} s CPU): "
             + ("**met**" if worst.wall <= TARGET_SECONDS else "**NOT met** in wall time on this machine's load")
             + (f"; its CPU time is under {TARGET_SECONDS:.0f} s" if worst.cpu <= TARGET_SECONDS else "") + "."]
    progress = [line for s in steps for line in s.output.splitlines() if line.startswith("generating split")]
    if progress:
        notes.append(f"Progress lines of the first generation (stderr), e.g. `{progress[0]}` ... `{progress[-1]}`.")
    return Section(
        intro=f"""
Each step is a fresh subprocess (`python -c "load_split(...)"`, `python -m runners.track ...`) with its own empty
`MORALITY_GYM_CACHE`, run in this order, not pinned (it may use all {cpus} CPUs: a first generation attempts the
seeds over one worker process per CPU). "First" generates the split (checking it against its manifest) or computes
the exact values; "cached" and "every run done" are what a user waits for every later time. Wall-clock and CPU
(user + system, workers included) seconds, one run each, with the 1-minute load average before / after the step:
the machine is shared, so wall time depends on the other jobs; CPU seconds are the steadier figure.
""",
        headers=["step", "wall (s)", "CPU (s)", "load average before / after"],
        rows=[_row(s) for s in steps],
        notes=notes,
        compare=["wall (s)", "CPU (s)"],
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_splits", description=__doc__.split("\n\n")[0])
    parser.add_argument("--code", type=Path, default=REPO, help="the checkout to time (default: this one)")
    parser.add_argument("--keep-cache", type=Path, help="use (and keep) this empty cache directory")
    parser.add_argument("--quick", action="store_true", help="the test split only")
    args = parser.parse_args(argv)
    if args.keep_cache is not None:
        args.keep_cache.mkdir(parents=True, exist_ok=True)
        measure(args.keep_cache, args.code, args.quick, shown=True)
    else:
        with tempfile.TemporaryDirectory(prefix="bench-splits-") as tmp:
            measure(Path(tmp), args.code, args.quick, shown=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
