"""The figures of the statistics the site shows: ranking figures per sweep, and per Table 1 row the
pooled learning curves and the return-versus-cost scatter.

Drawn with :mod:`leaderboard.stats.plots` (deterministic bytes) under ``<out>/figures/<sweep>/stats/``,
next to Figure 2; the site copies them. Each sweep (protocol, preset) is drawn separately: the
statistics functions refuse to pool sweeps, and so does this module.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from leaderboard.runs.aggregate import Group, Leaderboard, safe_name
from leaderboard.stats import plots as sf

Progress = Callable[[Iterable[Any], str, int], Iterable[Any]]


@dataclass
class StatFigures:
    """Where each statistics figure was written."""

    ranking: dict[Group, list[tuple[str, Path]]] = field(default_factory=dict)  # (kind, path) per sweep
    curves: dict[tuple[Group, str, str], Path] = field(default_factory=dict)
    curves_notes: dict[tuple[Group, str, str], str] = field(default_factory=dict)
    tradeoffs: dict[tuple[Group, str, str], Path] = field(default_factory=dict)

    @property
    def count(self) -> int:
        return sum(len(v) for v in self.ranking.values()) + len(self.curves) + len(self.tradeoffs)


#: Columns matplotlib needs as floats (a frame built from records with a missing value can hold objects).
NUMERIC = ("tau", "share", "value", "ci_low", "ci_high", "probability", "step", "mean", "mean_cost", "mean_return")


def _of(frame: pd.DataFrame, group: Group) -> pd.DataFrame:
    """The rows of one sweep, numeric columns as floats (None -> NaN)."""
    if frame.empty:
        return frame
    part = frame.loc[(frame["protocol"] == group.protocol) & (frame["preset"] == group.preset)]
    numeric = {c: pd.to_numeric(part[c], errors="coerce").astype(float) for c in NUMERIC if c in part.columns}
    return part.assign(**numeric)


def _measure(frame: pd.DataFrame, measure: str) -> pd.DataFrame:
    return frame.loc[frame["measure"] == measure] if not frame.empty else frame


#: The ranking figures of a sweep: (kind, caption) in page order.
RANKING_FIGURES = (
    ("profile-score", ("Performance profiles of the normalised score: share of runs (rows weighted equally) whose "
                      "score exceeds τ, with 95% pointwise bootstrap bands. A curve above another is better everywhere.")),
    ("profile-metric", "Performance profiles of the raw morality metric."),
    ("aggregates-score", "Mean, IQM and optimality gap of the normalised score with their 95% intervals."),
    ("improvement", "P(X > Y) for each pair of learners with its 95% interval; 0.5 = no difference."),
)


def write_stat_figures(lb: Leaderboard, stats: Any, out_dir: Path, colours: dict[str, str],
                       progress: Progress | None = None) -> StatFigures:
    """Every statistics figure of every sweep; a figure with nothing to draw is simply absent."""
    found = StatFigures()
    jobs: list[tuple[str, Group, tuple[str, str] | None]] = []
    for group in lb.groups:
        jobs += [("ranking", group, None)]
        jobs += [("row", group, pair) for pair in lb.pairs(group)]
    iterator: Iterable[Any] = progress(jobs, "statistics figures", len(jobs)) if progress and jobs else jobs
    for kind, group, pair in iterator:
        folder = out_dir / group.slug / "stats"
        if kind == "ranking":
            drawn = []
            profiles, aggregates = _of(stats.profiles, group), _of(stats.aggregates, group)
            plans: list[tuple[str, Callable[..., Path | None], pd.DataFrame, str]] = [
                ("profile-score", sf.performance_profile_figure, _measure(profiles, "score"),
                 "Performance profiles (normalised score)"),
                ("profile-metric", sf.performance_profile_figure, _measure(profiles, "metric"),
                 "Performance profiles (morality metric)"),
                ("aggregates-score", sf.aggregate_figure, _measure(aggregates, "score"), "Aggregate normalised score"),
                ("improvement", sf.improvement_figure, _of(stats.improvement, group), ""),
            ]
            for name, draw, frame, title in plans:
                path = draw(frame, folder / f"{name}.png", title, colours)
                if path is not None:
                    drawn.append((name, path))
            found.ranking[group] = drawn
            continue
        chain, scenario = pair  # type: ignore[misc]
        key = (group, chain, scenario)
        stem = f"{safe_name(chain)}_{safe_name(scenario)}"
        curves = _of(stats.curves, group)
        if not curves.empty:
            part = curves.loc[(curves["chain"] == chain) & (curves["scenario"] == scenario)]
            path = sf.learning_curves_figure(part, folder / f"curves_{stem}.png", rows=[pair], colours=colours, ncols=1,
                                             title=f"Learning curves · {scenario} · {chain}")
            if path is not None:
                found.curves[key] = path
                if (part["aligned"] == "interpolated").any():
                    found.curves_notes[key] = ("runs evaluated at different steps are interpolated onto a common grid "
                                               "over the steps every run covers")
        points = _of(stats.points, group)
        if not points.empty:
            part = points.loc[(points["chain"] == chain) & (points["scenario"] == scenario)]
            path = sf.return_cost_figure(part, folder / f"return_cost_{stem}.png", rows=[pair], colours=colours, ncols=1,
                                         title=f"Return versus cost · {scenario} · {chain}")
            if path is not None:
                found.tradeoffs[key] = path
    return found
