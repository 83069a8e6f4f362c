"""The whole leaderboard build (``python -m leaderboard.build``) on Table 1 sized results directories.

Why: the build runs after every sweep, and the result sets users have are large: a results release
of the paper's Table 1 (1,890 runs, PPO-Lag and CPO runs with per-update diagnostics) plus their own
runs. Issue 21 set the targets: a first build under 2 minutes and a rebuild with nothing changed
under 10 s on 2 cores. The directories are :func:`write_results`: :func:`tests.stats_data.synthetic_runs`
(the paper's 14 rows with all 126 variants, five learners, learn-time curves) and
:func:`synthetic_updates`, written as real run files, so the build reads Parquet from disk as it
does after a sweep. ``python -m benchmarks.bench_leaderboard DIR [SEEDS [STRIDE]]`` writes a
directory alone, to time other builds (e.g. another commit) on the same data.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any

import numpy as np

from benchmarks import Context, Section, register, timed_command
from leaderboard.release import find_releases, load
from morality_gym.norms.chain import get_chain
from morality_gym.results.schema import MF_PREFIX, SCHEMA_VERSION, run_schema, write_learn, write_run, write_updates
from tests.stats_data import synthetic_runs

REPO = Path(__file__).resolve().parents[1]
FINISHED_AT = "2026-01-01T00:00:00+00:00"
#: Updates of a paper-preset PPO-Lag or CPO run (~500k steps in rollouts of 1,024).
UPDATES = 488


def synthetic_updates(learner: str, n_updates: int, stride: int, rng: np.random.Generator) -> list[dict[str, Any]]:
    """Per-update diagnostics as PPO-Lag or CPO write them: ``n_updates`` updates, every ``stride``-th
    kept plus the last (as a release thins them; ``stride=1`` is a results directory's full table)."""
    keep = sorted(set(range(1, n_updates + 1, stride)) | {n_updates})
    cost = np.clip(0.3 * np.exp(-np.arange(1, n_updates + 1) / 150) + rng.normal(0, 0.02, n_updates), 0, None)
    rows = []
    for update in keep:
        row: dict[str, Any] = {"update": update, "timesteps": update * 1024, "ep_cost": float(cost[update - 1]),
                               "ep_cost_episodes": 200, "kl": 0.01, "kl_mean": 0.01}
        if learner == "CPO":
            row |= {"cpo_case": int(rng.choice([1, 3, 4], p=[0.1, 0.2, 0.7])), "accept_step": int(rng.integers(0, 4)),
                    "line_search_tried": 3}
        else:
            row |= {"passes": 1 if rng.random() < 0.9 else int(rng.integers(2, 11)), "early_stopped": True,
                    "lagrange_multiplier": float(max(0.0, 0.5 * np.sin(update / 60))), "actor_lr": 3e-4,
                    "critic_lr": 3e-4}
        rows.append(row)
    return rows


def write_results(root: Path, seeds: tuple[int, ...] = (41, 42), updates: int = UPDATES, stride: int = 1) -> int:
    """A results directory of synthetic runs (all 126 variants x 5 learners x ``seeds``); returns the run count.

    PPO-Lag and CPO runs get ``updates`` per-update diagnostics (0: none), thinned to every ``stride``-th."""
    runs, learn = synthetic_runs(seeds=seeds, preset="quick")
    algo = {"CPO": "cpo", "PPO": "ppo", "PPO Lag": "ppo_lag", "PPO Shaped": "ppo_shaped", "Random": "random"}
    curves = {run_id: part for run_id, part in learn.groupby("run_id", sort=False)}
    for record in runs.to_dict("records"):
        norms = list(get_chain(record["chain"]).norm_names)
        names = run_schema(norms).names
        row: dict[str, Any] = {name: None for name in names}
        row.update({k: v for k, v in record.items() if k in names})
        row.update(schema_version=SCHEMA_VERSION, algo=algo[record["learner"]], budget=1000, total_steps=1000,
                   eval_episodes=100, metric_stderr=0.01, mean_length=5.0, truncation_rate=0.0, goal_rate=1.0,
                   wall_time_s=1.0, started_at=FINISHED_AT, finished_at=FINISHED_AT, hostname="bench",
                   git_commit="0" * 7, versions="{}", config=json.dumps({"learner": record["learner"]}))
        row.update({f"{MF_PREFIX}{n}": record.get(f"{MF_PREFIX}{n}") for n in norms})
        write_run(root, row, norms)
        part = curves.get(record["run_id"])
        if part is not None:
            write_learn(root, record["run_id"], [r | {"schema_version": SCHEMA_VERSION, "mean_length": 5.0,
                                                      "wall_time_s": 1.0} for r in part.to_dict("records")], norms)
        if updates and record["learner"] in ("CPO", "PPO Lag"):
            rng = np.random.default_rng(zlib.crc32(record["run_id"].encode()))
            write_updates(root, record["run_id"], synthetic_updates(record["learner"], updates, stride, rng))
    return len(runs)


@dataclass(frozen=True)
class Timed:
    wall: float
    cpu: float  # user + system seconds of the build process (on a loaded machine, wall says little)
    summary: str  # the build's "cache:" and "time:" lines


def timed_build(results: Path, releases: tuple[Path, ...] = (), site: Path | None = None) -> Timed:
    """Wall and CPU seconds of ``python -m leaderboard.build --results R [--site S] [--release ...]``
    (a subprocess, as a user runs it; with a site and the releases, what ``make leaderboard`` runs)."""
    command = [sys.executable, "-m", "leaderboard.build", "--results", str(results)]
    command += ["--site", str(site)] if site is not None else []
    for release in releases:
        command += ["--release", str(release)]
    run = timed_command(command, cwd=REPO)
    lines = [line for line in run.stdout.splitlines() if line.startswith(("runs:", "cache:", "time:"))]
    return Timed(run.wall, run.cpu, " / ".join(lines))


#: (label, seeds, update stride): the paper's Table 1 as a release ships it (update diagnostics thinned
#: to every 8th), and a user's own larger set (5 seeds, every update).
SETS = (
    ("Table 1, 3 seeds, updates thinned to every 8th (as a release)", (41, 42, 43), 8),
    ("5 seeds, all 488 updates (a user's own runs)", (41, 42, 43, 44, 45), 1),
)
QUICK_SETS = (("1 seed, all 488 updates", (41,), 1),)


@register("leaderboard", "Leaderboard build (python -m leaderboard.build): first build and rebuild", order=85)
def leaderboard_speed(ctx: Context) -> Section:
    rows = []
    notes = []
    for label, seeds, stride in QUICK_SETS if ctx.quick else SETS:
        with TemporaryDirectory(prefix="bench-leaderboard-") as tmp:
            results = Path(tmp) / "results"
            n = write_results(results, seeds, stride=stride)
            first = timed_build(results)  # computes the reference rows, the statistics and every figure and page
            again = timed_build(results)  # nothing changed: everything comes from <results>/cache
        rows.append([label, f"{n:,}", f"{first.wall:.1f}", f"{first.cpu:.1f}", f"{again.wall:.1f}", f"{again.cpu:.1f}"])
        notes += [f"{n:,} runs, first build: {first.summary}", f"{n:,} runs, rebuild: {again.summary}"]
    return Section(
        intro="""
`python -m leaderboard.build --results DIR` (a subprocess, as a user runs it, not pinned: both cores) on synthetic
results directories written as real run files by `benchmarks/bench_leaderboard.py` (`tests/stats_data.py`: the
paper's 14 rows with all 126 variants, 5 learners, 21 learn-time evaluations per run; PPO-Lag and CPO runs also
have per-update diagnostics of 488 updates). First build: empty output directory, so it computes the exact
reference rows, the bootstrap statistics, every figure, chart and page; rebuild: the same results again, so
statistics, figures, per-run charts and run pages come from `<out>/cache` (keyed by content; the output is
byte-identical to a fresh build's). Targets (issue 21): first build under 2 minutes, rebuild under 10 s, on 2
cores. One run each; wall-clock and CPU (user + system) seconds of the build process. The machine is shared:
other jobs ran at the same time, so wall times are inflated; CPU seconds are the steadier figure.
""",
        headers=["results", "runs", "first build wall (s)", "first build CPU (s)", "rebuild wall (s)", "rebuild CPU (s)"],
        rows=rows,
        notes=notes,
        compare=["first build wall (s)", "first build CPU (s)", "rebuild wall (s)", "rebuild CPU (s)"],
    )



# ---------------------------------------------------------------------------------------- real data
#: What a build reads of a results directory (the rest, models and the MLflow store, it never opens).
_READ_BY_THE_BUILD = (".parquet", ".gif", ".json")


def link_results(source: Path, target: Path) -> int:
    """A results directory at ``target`` with what the build reads of ``source``: its runs' files
    hard-linked (no copy of hundreds of MB; the build never writes them) and its manifests copied.
    The build's own outputs (``table1.*``, ``cache/``) are left out, so the timed build is a first
    one, and ``source`` is never written. Returns the number of run rows."""
    rows = 0
    for path in sorted((source / "runs").rglob("*")):
        if path.is_file() and path.suffix in _READ_BY_THE_BUILD and ".quarantine" not in path.parts:
            dest = target / path.relative_to(source)
            dest.parent.mkdir(parents=True, exist_ok=True)
            os.link(path, dest)
            rows += path.parent == source / "runs" and path.name.count(".") == 1
    shutil.copytree(source / "manifests", target / "manifests")
    return rows


@register("leaderboard-release", "Leaderboard build on a results release, alone and beside one's own runs", order=86)
def leaderboard_release(ctx: Context) -> Section:
    """The build users run (``make leaderboard``) on real data: a fresh clone with the shipped
    release and no runs of its own, and the release beside a results directory of one's own
    (``--results``, e.g. the quick Table 1 under both protocols). Each in a temporary directory,
    first build (nothing cached) and rebuild (nothing changed)."""
    releases = ctx.releases or tuple(find_releases())
    if not releases:
        return Section(intro="No results release to time: none under `releases/` and no `--release DIR`.", headers=[], rows=[])
    names = ", ".join(f"{load(r).label}" for r in releases)
    sets: list[tuple[str, Path | None]] = [("the release alone (a fresh clone, no runs of one's own)", None)]
    if ctx.results is not None:
        sets.append((f"the release + {ctx.results.name}/ (one's own runs)", ctx.results))
    rows, notes = [], []
    for label, own in sets:
        with TemporaryDirectory(prefix="bench-leaderboard-release-") as tmp:
            results = Path(tmp) / "results"
            results.mkdir()
            n_own = link_results(own, results) if own is not None else 0
            first = timed_build(results, releases, Path(tmp) / "site")
            again = timed_build(results, releases, Path(tmp) / "site")
        rows.append([label, f"{n_own:,}", f"{first.wall:.1f}", f"{first.cpu:.1f}", f"{again.wall:.1f}", f"{again.cpu:.1f}"])
        notes += [f"{label}, first build: {first.summary}", f"{label}, rebuild: {again.summary}"]
    return Section(
        intro=f"""
`make leaderboard` (`python -m leaderboard.build --results R --site S --release ...`, a subprocess, not pinned:
both cores) on real data: {names}. First build: an empty results directory (a fresh clone) or a results
directory of one's own runs (their run files hard-linked into a temporary directory, so nothing is cached yet)
and an empty site; rebuild: the same again, nothing changed. Targets (issue 21): first build under 2 minutes,
rebuild under 10 s, on 2 cores. One run each; wall-clock and CPU (user + system) seconds of the build process.
""",
        headers=["results", "own runs", "first build wall (s)", "first build CPU (s)", "rebuild wall (s)", "rebuild CPU (s)"],
        rows=rows,
        notes=notes,
        compare=["first build wall (s)", "first build CPU (s)", "rebuild wall (s)", "rebuild CPU (s)"],
    )


if __name__ == "__main__":
    target = Path(sys.argv[1] if len(sys.argv) > 1 else "results-bench")
    seeds = tuple(int(s) for s in sys.argv[2].split(",")) if len(sys.argv) > 2 else (41, 42)
    stride = int(sys.argv[3]) if len(sys.argv) > 3 else 1
    print(f"wrote {write_results(target, seeds, stride=stride)} runs to {target}")
