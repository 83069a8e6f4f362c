"""Interval estimates and overall rankings for the leaderboard (issue 13), as pure functions of frames.

Inputs are the frames the leaderboard already has: the run rows (``Leaderboard.runs``, columns of
:data:`morality_gym.results.schema.RUN_FIELDS` plus ``mf_<norm>``), the Table 1 frame for the reference values
(``Leaderboard.table``) and the learn-time evaluations (:func:`morality_gym.results.schema.read_learn`).
Outputs are tidy DataFrames (one observation per row), ready for CSV, templates and figures.

* :mod:`~leaderboard.stats.cells`: 95 % intervals of the Table 1 cells and the bold rule;
* :mod:`~leaderboard.stats.ranking`: normalised scores, mean / IQM / optimality gap with
  intervals, probability of improvement, performance profiles;
* :mod:`~leaderboard.stats.curves`: learning curves pooled per cell;
* :mod:`~leaderboard.stats.tradeoffs`: return versus cost, per-norm violation rates;
* :mod:`~leaderboard.stats.plots`: the figures of all of the above;
* :mod:`~leaderboard.stats.core`: the bootstrap, seeding and weighted statistics they share;
* :func:`compute_stats`: everything at once.

Each module's docstring defines its statistics and says why they are defined that way.
"""

from leaderboard.stats.bundle import LeaderboardStats, compute_stats, resample_counts
from leaderboard.stats.cells import bold_cells, cell_intervals, intervals_overlap
from leaderboard.stats.core import CONFIDENCE, DEFAULT_RESAMPLES, DEFAULT_SEED, RESAMPLES, StatsInputError
from leaderboard.stats.curves import pooled_learning_curves
from leaderboard.stats.ranking import (
    MIN_HEADROOM,
    aggregate_intervals,
    performance_profiles,
    probability_of_improvement,
    ranking_rows,
    reference_frame,
    run_scores,
)
from leaderboard.stats.tradeoffs import return_cost_points, violation_rates

__all__ = [
    "CONFIDENCE",
    "DEFAULT_RESAMPLES",
    "DEFAULT_SEED",
    "MIN_HEADROOM",
    "RESAMPLES",
    "LeaderboardStats",
    "StatsInputError",
    "aggregate_intervals",
    "bold_cells",
    "cell_intervals",
    "compute_stats",
    "intervals_overlap",
    "performance_profiles",
    "pooled_learning_curves",
    "probability_of_improvement",
    "ranking_rows",
    "reference_frame",
    "resample_counts",
    "return_cost_points",
    "run_scores",
    "violation_rates",
]
