"""Leaderboard statistics (:mod:`leaderboard.stats`): how long the intervals, rankings, curves and
their figures take on a Table 1 sized results frame.

The leaderboard is rebuilt after every sweep on 1,000 to 4,000 runs, so the statistics must take
seconds. The frame is :func:`tests.stats_data.synthetic_runs` (the paper's 14 rows with all 126
variants, 5 learners, 21 learn-time evaluations per run); the work is :func:`compute_stats` with
each statistic's default number of bootstrap resamples, then every figure of one (protocol, preset).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import TYPE_CHECKING

import pandas as pd

from benchmarks import Context, Section, best_time, register
from leaderboard.runs.aggregate import row_order
from leaderboard.stats import RESAMPLES, compute_stats
from leaderboard.stats import plots as F
from tests.stats_data import reference_frame, synthetic_runs

if TYPE_CHECKING:
    from leaderboard.stats import LeaderboardStats


def _collect(runs: pd.DataFrame, learn: pd.DataFrame, into: list[LeaderboardStats]) -> Callable[[], None]:
    return lambda: into.append(compute_stats(runs, reference_frame(), learn))


def _figures(stats: LeaderboardStats, out: Path) -> int:
    """Every figure of the first (protocol, preset): ranking figures, both grids, both per-row figures for each row."""
    group = stats.aggregates[["protocol", "preset"]].iloc[0]

    def only(frame: pd.DataFrame) -> pd.DataFrame:
        return frame.loc[(frame["protocol"] == group["protocol"]) & (frame["preset"] == group["preset"])]

    made = [
        F.performance_profile_figure(only(stats.profiles).loc[lambda f: f["measure"] == "score"], out / "profile.png"),
        F.aggregate_figure(only(stats.aggregates).loc[lambda f: f["measure"] == "score"], out / "aggregates.png"),
        F.improvement_figure(only(stats.improvement), out / "improvement.png"),
        F.learning_curves_figure(only(stats.curves), out / "curves.png"),
        F.return_cost_figure(only(stats.points), out / "return_cost.png"),
    ]
    for i, row in enumerate(row_order(zip(stats.points["chain"], stats.points["scenario"]))):
        made.append(F.learning_curves_figure(only(stats.curves), out / f"curves_{i}.png", rows=[row]))
        made.append(F.return_cost_figure(only(stats.points), out / f"return_cost_{i}.png", rows=[row]))
    return sum(path is not None for path in made)


@register("stats", "Leaderboard statistics: intervals, ranking, curves and their figures", order=80)
def stats_speed(ctx: Context) -> Section:
    settings = [((41,), ("paper",)), ((41, 42, 43), ("paper",)), ((41, 42, 43), ("paper", "corrected"))]
    if ctx.quick:
        settings = settings[:1]
    repeats = min(ctx.repeats, 3)
    task = ctx.task("leaderboard statistics", len(settings) + 1)
    rows = []
    last: LeaderboardStats | None = None
    for seeds, protocols in settings:
        runs, learn = synthetic_runs(seeds=seeds, protocols=protocols)
        holder: list[LeaderboardStats] = []
        timing = best_time(_collect(runs, learn, holder), repeats)
        last = holder[-1]
        parts = ", ".join(f"{k} {v:.2f}" for k, v in sorted(last.seconds.items(), key=lambda kv: -kv[1])[:3])
        rows.append([f"{len(runs):,}", f"{len(seeds)} x {len(protocols)}", f"{len(learn):,}", f"{timing.cpu:.2f}",
                     f"{timing.wall:.2f}", parts])
        task.advance()
    with TemporaryDirectory() as tmp:
        counted: list[int] = []
        figures = best_time(lambda: counted.append(_figures(last, Path(tmp))), 1)
    task.done()
    return Section(
        intro=f"""
`leaderboard.stats.compute_stats` on synthetic Table 1 frames (`tests/stats_data.py`: the paper's 14 rows with all
their variants, 5 learners, 21 learn-time evaluations per run), each statistic's own bootstrap resamples per
interval ({", ".join(f"{k} {v:,}" for k, v in RESAMPLES.items())}): 70 cell intervals per (protocol, preset), mean / IQM / optimality gap on two scales, 20 ordered pairs of
probability of improvement, performance profiles on 89 + 41 thresholds, pooled learning curves of 70 cells, return-cost
points and violation rates. Best of {repeats}; CPU and wall-clock seconds; the three slowest parts of the best run.
""",
        headers=["runs", "seeds x protocols", "learn-time rows", "CPU s", "wall-clock s", "slowest parts (s)"],
        rows=rows,
        notes=[(f"Figures of one (protocol, preset) from the largest frame ({counted[-1]} PNGs: 3 ranking figures, "
                f"2 fourteen-panel grids, a learning-curve and a return-cost figure per row): "
                f"{figures.cpu:.1f} s CPU, {figures.wall:.1f} s wall-clock.")],
    )
