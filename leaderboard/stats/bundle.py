"""Every statistic of the leaderboard in one call, for the build (``compute_stats``)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import pandas as pd

from leaderboard.stats.cells import SEED, bold_cells, cell_intervals
from leaderboard.stats.core import CONFIDENCE, RESAMPLES, RngLike, base_seed
from leaderboard.stats.curves import CURVE_COLUMNS, pooled_learning_curves
from leaderboard.stats.ranking import (
    MEASURES,
    MIN_HEADROOM,
    aggregate_intervals,
    performance_profiles,
    probability_of_improvement,
    ranking_rows,
)
from leaderboard.stats.tradeoffs import return_cost_points, violation_rates


@dataclass
class LeaderboardStats:
    """The tidy frames the pages, CSV downloads and figures are made from (columns: see each function)."""

    cells: pd.DataFrame  # cell_intervals + bold_cells: one row per Table 1 learner cell
    rows: pd.DataFrame  # ranking_rows: which rows are ranked, their references, why not
    aggregates: pd.DataFrame  # aggregate_intervals: mean / IQM / optimality gap per learner, both measures
    improvement: pd.DataFrame  # probability_of_improvement: every ordered pair of learners
    profiles: pd.DataFrame  # performance_profiles for both measures (column "measure")
    curves: pd.DataFrame  # pooled_learning_curves (empty without learn-time evaluations)
    points: pd.DataFrame  # return_cost_points: one per run
    violations: pd.DataFrame  # violation_rates per row, learner and relevant norm
    seconds: dict[str, float] = field(default_factory=dict)  # time per part (for the build summary)
    resamples: dict[str, int] = field(default_factory=dict)  # bootstrap resamples per part (resample_counts)


def resample_counts(n_resamples: int | None = None) -> dict[str, int]:
    """Bootstrap resamples per statistic: :data:`~leaderboard.stats.core.RESAMPLES`, or ``n_resamples`` for every one."""
    return dict(RESAMPLES) if n_resamples is None else dict.fromkeys(RESAMPLES, int(n_resamples))


def compute_stats(
    runs: pd.DataFrame,
    references: Any = None,
    learn: pd.DataFrame | None = None,
    *,
    rng: RngLike = None,
    n_resamples: int | None = None,
    confidence: float = CONFIDENCE,
    min_headroom: float = MIN_HEADROOM,
    curve_column: str = "exact_metric",
    resampling: str = SEED,
) -> LeaderboardStats:
    """All statistics of the runs of a results directory.

    ``runs``: ``Leaderboard.runs``; ``references``: ``Leaderboard.table`` (its reference rows), a
    frame from :func:`~leaderboard.stats.ranking.reference_frame`, a mapping ``(chain, scenario)
    -> (random, best)``, or ``None`` (no normalised ranking: every row says "no reference values");
    ``learn``: :func:`morality_gym.results.schema.read_learn` of the results directory, or ``None``.
    ``rng``: a seed or generator; each estimate derives its own generator from it, so the result
    is the same on every call with the same seed. ``n_resamples``: bootstrap resamples of every
    interval; ``None``: each statistic's own count, :data:`~leaderboard.stats.core.RESAMPLES`.
    ``resampling``: what the cells' and the aggregates' bootstraps draw, whole seeds (``"seed"``, the
    default) or each variant's seeds on their own (``"variant"``, the rule before issue 48), see
    :mod:`leaderboard.stats.cells`.
    """
    seed = base_seed(rng)
    counts = resample_counts(n_resamples)

    def options(part: str) -> dict[str, Any]:
        return {"rng": seed, "n_resamples": counts[part], "confidence": confidence}
    seconds: dict[str, float] = {}

    def timed(name: str, work: Callable[[], pd.DataFrame]) -> pd.DataFrame:
        start = time.perf_counter()
        result = work()
        seconds[name] = time.perf_counter() - start
        return result

    profiles = [timed(f"profiles ({m})", lambda m=m: performance_profiles(runs, references, measure=m, min_headroom=min_headroom,
                                                                            **options("profiles"))) for m in MEASURES]
    return LeaderboardStats(
        cells=timed("cells", lambda: bold_cells(cell_intervals(runs, resampling=resampling, **options("cells")))),
        rows=timed("rows", lambda: ranking_rows(runs, references, min_headroom=min_headroom)),
        aggregates=timed("aggregates", lambda: aggregate_intervals(runs, references, min_headroom=min_headroom,
                                                                   **options("aggregates"))),
        improvement=timed("improvement", lambda: probability_of_improvement(runs, **options("improvement"))),
        profiles=pd.concat(profiles, ignore_index=True),
        curves=timed("curves", lambda: pooled_learning_curves(runs, learn, column=curve_column, **options("curves")))
        if learn is not None and len(learn) else pd.DataFrame(columns=CURVE_COLUMNS),
        points=timed("points", lambda: return_cost_points(runs)),
        violations=timed("violations", lambda: violation_rates(runs)),
        seconds=seconds,
        resamples=counts,
    )
