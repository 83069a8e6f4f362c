"""Intervals for the Table 1 cells, and the rule that decides which cell is bold.

A Table 1 cell is one (protocol, preset, chain, scenario, learner); its number is the mean of the
final evaluation's metric over every run of the cell, all variants and seeds alike (evaluation
spec 7.2, :func:`leaderboard.runs.aggregate.learner_cells`).

**Interval.** A 95 % stratified percentile bootstrap over seeds: within each variant, the
variant's runs (one per seed) are resampled with replacement, independently of the other
variants, and the statistic is the cell mean computed exactly as Table 1 computes it (the sum
over variants of their resampled sums divided by the number of runs). Why stratify by variant:
a cell always contains every variant of its scenario, so the variants are fixed, not sampled; the
only randomness a rerun would change is the seeds. Resampling runs across variants would swap a
hard variant for an easy one and report the spread between variants as uncertainty.

**One seed.** When a variant has a single run there is nothing to resample: the interval would
be computed as if that run were exact, i.e. too narrow, in the extreme (every variant one seed, as
in the ``quick`` and ``smoke`` presets) of width zero, which reads as certainty. Such a cell gets
NaN bounds and ``ci_note`` "1 seed" (or names the variants with one seed), never a zero-width
interval.

**Bold.** A cell is bold when it has the highest mean of its row *and* its interval overlaps the
interval of no other learner of the row (so in particular not the runner-up's). When any learner
of the row has no interval, when the best mean is tied, or when the intervals overlap, nothing is
bold, and :func:`bold_cells` says why on the best cell. Non-overlap of two 95 % intervals is a
conservative test (it implies a difference at roughly the 0.5 % level for equal widths), so bold
means "clearly better", and the absence of bold means "not shown to be better", not "equal".
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from leaderboard.runs.aggregate import CELL_KEYS
from leaderboard.stats.core import (
    CELL_RESAMPLES,
    CONFIDENCE,
    RngLike,
    base_seed,
    bootstrap_interval,
    generator_for,
    in_table1_order,
    require_columns,
    usable_runs,
)

#: The keys of a Table 1 cell (same as :data:`leaderboard.runs.aggregate.CELL_KEYS`).
ROW_KEYS = ["protocol", "preset", "chain", "scenario"]
CELL_COLUMNS = ["mean", "ci_low", "ci_high", "ci_low_mcse", "ci_high_mcse", "n_runs", "n_variants", "min_seeds", "ci_note"]
ONE_SEED = "1 seed"
NO_RUNS = "no runs"
#: Two means closer than this are a tie (the same tolerance the Table 1 "best" flag uses).
TIE_TOLERANCE = 1e-12


def _cell_keys() -> list[str]:
    return list(CELL_KEYS)


def _pooled_mean(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
    """Mean over all observations of all samples (the Table 1 cell mean), vectorised."""
    total = sum(np.sum(s, axis=axis) for s in samples)
    count = sum(s.shape[axis] for s in samples)
    return total / count


def _one_seed_note(counts: dict[str, int]) -> str:
    short = sorted(v for v, n in counts.items() if n < 2)
    if len(short) == len(counts):
        return ONE_SEED
    named = ", ".join(short[:3]) + (f" and {len(short) - 3} more" if len(short) > 3 else "")
    return f"{ONE_SEED} in {named}"


def cell_intervals(
    runs: pd.DataFrame,
    *,
    rng: RngLike = None,
    n_resamples: int = CELL_RESAMPLES,
    confidence: float = CONFIDENCE,
) -> pd.DataFrame:
    """One row per Table 1 cell with a usable run: its mean and stratified bootstrap interval.

    ``runs``: run rows (``Leaderboard.runs``); only ``ok`` runs count. Returns the cell keys
    (protocol, preset, chain, scenario, learner), then ``mean`` (equal to Table 1's), ``ci_low``,
    ``ci_high`` (NaN when not computable), ``ci_low_mcse``, ``ci_high_mcse`` (the Monte Carlo standard error of each
    bound, :func:`~leaderboard.stats.core.bootstrap_interval`), ``n_runs``, ``n_variants``, ``min_seeds`` (fewest runs
    of a variant) and ``ci_note`` ("" when the interval exists, else why not), in Table 1 order.
    """
    keys = _cell_keys()
    require_columns(runs, keys + ["variant", "metric"], "runs", "pass Leaderboard.runs")
    ok = usable_runs(runs)
    seed = base_seed(rng)
    rows = []
    for key, part in ok.groupby(keys, sort=True, dropna=False):
        by_variant = {str(v): g["metric"].to_numpy(dtype=float) for v, g in part.groupby("variant", sort=True, dropna=False)}
        counts = {v: len(a) for v, a in by_variant.items()}
        samples = list(by_variant.values())
        mean = float(_pooled_mean(*samples)) if samples else math.nan
        low = high = low_mcse = high_mcse = math.nan
        note = ""
        if not samples:
            note = NO_RUNS
        elif min(counts.values()) < 2:
            note = _one_seed_note(counts)
        else:
            interval = bootstrap_interval(samples, _pooled_mean, generator_for(seed, "cell", *key), n_resamples, confidence)
            low, high = float(interval.low), float(interval.high)
            low_mcse, high_mcse = float(interval.low_mcse), float(interval.high_mcse)
        rows.append(dict(zip(keys, key)) | {"mean": mean, "ci_low": low, "ci_high": high, "ci_low_mcse": low_mcse,
                                             "ci_high_mcse": high_mcse, "n_runs": len(part), "n_variants": len(counts), "min_seeds": min(counts.values()),
                                             "ci_note": note})
    return in_table1_order(pd.DataFrame(rows, columns=keys + CELL_COLUMNS))


def intervals_overlap(a_low: float, a_high: float, b_low: float, b_high: float) -> bool | None:
    """Whether two closed intervals share a point; ``None`` when either is unknown (a NaN bound).

    Touching intervals overlap: a bold must not hinge on the last digit of a bootstrap quantile.
    """
    bounds = (a_low, a_high, b_low, b_high)
    if any(pd.isna(b) for b in bounds):
        return None
    return not (float(a_low) > float(b_high) or float(b_low) > float(a_high))


def bold_cells(cells: pd.DataFrame) -> pd.DataFrame:
    """``cells`` (from :func:`cell_intervals`) with ``best``, ``bold`` and ``bold_note`` columns.

    ``best``: the highest mean of the row (ties: all of them), as Table 1 marks it today.
    ``bold``: best, no tie, and the interval overlaps no other learner's interval of the row.
    ``bold_note`` on the best cell(s): "" when bold, else why not (an overlap with a named learner,
    a learner without an interval and why, a tie, or no other learner to compare with).
    """
    keys = _cell_keys()
    require_columns(cells, keys + ["mean", "ci_low", "ci_high", "ci_note"], "cells", "pass cell_intervals(...)")
    out = cells.copy()
    out["best"] = False
    out["bold"] = False
    out["bold_note"] = ""
    for _, part in out.groupby(ROW_KEYS, sort=False, dropna=False):
        good = part.loc[part["mean"].notna()]
        if good.empty:
            continue
        top = float(good["mean"].max())
        best = good.loc[good["mean"] >= top - TIE_TOLERANCE]
        out.loc[best.index, "best"] = True
        others = good.drop(index=best.index)
        if len(best) > 1:
            out.loc[best.index, "bold_note"] = "tie: " + ", ".join(best["learner"].astype(str))
            continue
        if others.empty:
            out.loc[best.index, "bold_note"] = "no other learner to compare with"
            continue
        cell = best.iloc[0]
        reasons = []
        if math.isnan(cell["ci_low"]):
            reasons.append(f"no interval ({cell['ci_note']})")
        else:
            for other in others.sort_values("mean", ascending=False, kind="stable").itertuples():
                overlap = intervals_overlap(cell["ci_low"], cell["ci_high"], other.ci_low, other.ci_high)
                if overlap is None:
                    reasons.append(f"{other.learner} has no interval ({other.ci_note})")
                elif overlap:
                    reasons.append(f"overlaps {other.learner}")
        out.loc[best.index, "bold"] = not reasons
        out.loc[best.index, "bold_note"] = "; ".join(reasons)
    return out
