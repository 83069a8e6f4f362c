"""Learning curves pooled per Table 1 cell, from the learn-time evaluations (``runs/<id>.learn.parquet``).

**Value.** By default the learn-time ``exact_metric``: the exact expected metric of the policy
at that step, which the learn-time Monte Carlo ``metric`` estimates from only 10 episodes (pass
``column="metric"`` for that, or ``mean_return`` / ``mean_cost``).

**Alignment.** Runs of one cell usually evaluate at the same steps; then those steps are the grid
and nothing is interpolated (``aligned="shared"``). When they differ (budgets or rollout sizes
that differ slightly between runs), the grid is ``n`` evenly spaced steps over the range every run
covers, from the latest first evaluation to the earliest last one, with ``n`` the fewest
evaluations any run has in that range, and each run's curve is linearly interpolated onto it
(``aligned="interpolated"``). A curve is never extrapolated beyond a run's own first and last
evaluation, so the pooled curve ends where the shortest run ends.

**Pooling.** At each grid step: the mean over the cell's runs (variants and seeds alike, as a Table
1 cell is a mean over both) and a 95 % percentile bootstrap interval resampling whole runs (every
resample takes a run's entire curve, so the band is consistent along the steps). This is the
resampling of the ranking restricted to one row, so it exists with one seed per variant; it is
wider than the cell interval of :mod:`leaderboard.stats.cells`, which keeps the variants fixed.
A cell with a single curve gets NaN bounds.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from leaderboard.runs.aggregate import CELL_KEYS
from leaderboard.stats.core import (
    CONFIDENCE,
    DEFAULT_RESAMPLES,
    RngLike,
    base_seed,
    bootstrap_interval,
    generator_for,
    in_table1_order,
    require_columns,
    usable_runs,
)

CURVE_COLUMNS = ["protocol", "preset", "chain", "scenario", "learner", "measure", "step", "mean", "ci_low", "ci_high",
                 "ci_low_mcse", "ci_high_mcse", "n_runs", "n_cell_runs", "aligned"]
SHARED, INTERPOLATED = "shared", "interpolated"


def _mean_over_runs(y: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.mean(y, axis=axis)


def common_grid(curves: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, str]:
    """The step grid of a cell's runs (see the module docstring) and how it was obtained.

    ``curves``: per run, its sorted unique steps and values. An empty grid means the runs share
    no range of steps at all.
    """
    first = curves[0][0]
    if all(len(s) == len(first) and np.array_equal(s, first) for s, _ in curves):
        return first.astype(float), SHARED
    start = max(float(s[0]) for s, _ in curves)
    end = min(float(s[-1]) for s, _ in curves)
    if end < start:
        return np.array([], dtype=float), INTERPOLATED
    n = min(int(np.count_nonzero((s >= start) & (s <= end))) for s, _ in curves)
    if end == start or n < 2:
        return np.array([start]), INTERPOLATED
    return np.round(np.linspace(start, end, n)), INTERPOLATED


def pooled_learning_curves(
    runs: pd.DataFrame,
    learn: pd.DataFrame,
    *,
    column: str = "exact_metric",
    rng: RngLike = None,
    n_resamples: int = DEFAULT_RESAMPLES,
    confidence: float = CONFIDENCE,
) -> pd.DataFrame:
    """Mean curve and 95 % band per (protocol, preset, chain, scenario, learner) and grid step.

    ``runs``: run rows (only ``ok`` runs count); ``learn``: learn-time evaluations (as
    :func:`morality_gym.results.schema.read_learn` returns them), joined to the runs by ``run_id``. Columns:
    the cell keys, ``measure`` (= ``column``), ``step``, ``mean``, ``ci_low``, ``ci_high``,
    ``ci_low_mcse``, ``ci_high_mcse`` (Monte Carlo standard error of each bound), ``n_runs`` (curves pooled), ``n_cell_runs`` (usable runs of the cell, with or without a
    curve), ``aligned`` (``shared`` | ``interpolated``). Evaluations whose value is missing are
    ignored; a run evaluated twice at a step counts with the mean of both.
    """
    keys = list(CELL_KEYS)
    require_columns(learn, ["run_id", "step", column], "learn", "pass morality_gym.results.schema.read_learn(results_dir)")
    ok = usable_runs(runs)
    require_columns(ok, keys + ["run_id"], "runs", "pass Leaderboard.runs")
    cell_sizes = ok.groupby(keys, sort=True).size()
    evaluations = learn[["run_id", "step", column]].copy()
    evaluations["step"] = pd.to_numeric(evaluations["step"], errors="coerce")
    evaluations[column] = pd.to_numeric(evaluations[column], errors="coerce")
    evaluations = evaluations.dropna(subset=["step", column])
    evaluations = evaluations.groupby(["run_id", "step"], as_index=False, sort=True)[column].mean()
    joined = ok[keys + ["run_id"]].merge(evaluations, on="run_id", how="inner")
    seed = base_seed(rng)
    out = []
    for key, part in joined.groupby(keys, sort=True):
        curves = [(g["step"].to_numpy(dtype=float), g[column].to_numpy(dtype=float))
                  for _, g in part.groupby("run_id", sort=True)]
        grid, aligned = common_grid(curves)
        if grid.size == 0:
            continue
        y = np.vstack([np.interp(grid, steps, values) for steps, values in curves])
        mean = _mean_over_runs(y, axis=0)
        if len(curves) >= 2:
            interval = bootstrap_interval([y], _mean_over_runs, generator_for(seed, "curve", column, *key),
                                          n_resamples, confidence, axis=0)
            low, high, low_mcse, high_mcse = interval.low, interval.high, interval.low_mcse, interval.high_mcse
        else:
            low = high = low_mcse = high_mcse = np.full(grid.shape, math.nan)
        base = dict(zip(keys, key)) | {"measure": column, "n_runs": len(curves), "n_cell_runs": int(cell_sizes[key]),
                                       "aligned": aligned}
        out += [base | {"step": int(step), "mean": float(m), "ci_low": float(lo), "ci_high": float(hi),
                        "ci_low_mcse": float(e_lo), "ci_high_mcse": float(e_hi)}
                for step, m, lo, hi, e_lo, e_hi in zip(grid, mean, *map(np.atleast_1d, (low, high, low_mcse, high_mcse)))]
    return in_table1_order(pd.DataFrame(out, columns=CURVE_COLUMNS), then=["step"])
