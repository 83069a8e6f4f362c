"""Intervals for the Table 1 cells, and the rule that decides which cell is bold.

A Table 1 cell is one (protocol, preset, chain, scenario, learner); its number is the mean of the
final evaluation's metric over every run of the cell, all variants and seeds alike (evaluation
spec 7.2, :func:`leaderboard.runs.aggregate.learner_cells`).

**Interval.** A 95 % percentile bootstrap over *seeds as clusters* (``resampling="seed"``, the
default): a resample draws the cell's seeds with replacement, each drawn seed bringing all its runs
(one per variant), and the statistic is the cell mean computed exactly as Table 1 computes it (the
sum of the drawn runs' metrics over their number). Why whole seeds: the seed, not the variant, is
what a rerun would draw anew, and a seed's runs on the variants of a scenario share that seed's
randomness (docs/concepts.md#what-a-seed-drives: Random's evaluation stream; a learner's initial
network, its action sampling and its minibatch order, identical across the variants of a scenario
because their spaces are), so they move together. The shipped releases show it: the per-seed cell
means spread 6-7 times as much as independent variants would make them for Random and 1.4-2.7 times
for the learners (docs/concepts.md, checked there). Resampling each variant's seeds independently
(the old rule, ``resampling="variant"``: seeds resampled within each variant, the variants as strata)
treats those runs as independent draws and averages their shared noise away: on the shipped
releases it counted three Random cells as "moved" by a redrawn evaluation stream alone, and whole
seeds count none. Either way the variants are never
mixed: a cell always contains every variant of its scenario, so resampling runs across variants would
swap a hard variant for an easy one and report the spread between variants as uncertainty.

**Three seeds are not an interval.** A bootstrap over ``k`` seeds can draw ``C(2k - 1, k)`` distinct
resamples, 10 for three seeds, and the most extreme of them (one seed drawn three times) alone holds
``1/27`` = 3.7 % of the draws, more than the 2.5 % tail: the 95 % bounds are then, for any data and
any bootstrap seed, the lowest and the highest per-seed mean (:func:`~leaderboard.stats.core.is_interval`
states the threshold). Such a cell keeps those two numbers as ``ci_low``/``ci_high`` (exact, Monte
Carlo error 0) but says what they are: ``ci_kind`` "seed range" and ``seed_means``, the per-seed
means in seed order, which every output prints instead of a precise-looking bracket. From four
seeds (35 distinct resamples) the bounds are bootstrap quantiles again (``ci_kind`` "bootstrap").

**One seed.** When there is a single seed (or, under ``resampling="variant"``, a variant has a single
run) there is nothing to resample: the interval would be computed as if that run were exact, i.e. too
narrow, in the extreme (every variant one seed, as in the ``quick`` and ``smoke`` presets) of width
zero, which reads as certainty. Such a cell gets NaN bounds and ``ci_note`` "1 seed" (or names the
variants with one seed), never a zero-width interval.

**Bold.** A cell is bold when it has the highest mean of its row *and* its interval overlaps the
interval of no other learner of the row (so in particular not the runner-up's). When any learner
of the row has no interval, when the best mean is tied, or when the intervals overlap, nothing is
bold, and :func:`bold_cells` says why on the best cell. Non-overlap of two 95 % intervals is a
conservative test (it implies a difference at roughly the 0.5 % level for equal widths), so bold
means "clearly better", and the absence of bold means "not shown to be better", not "equal". With
three seeds the "intervals" are the per-seed ranges and non-overlap means every seed of the best
learner above every seed of the other: if the six per-seed means were exchangeable that happens by
chance with probability 1/20, so there bold means "better on every seed", a weaker statement.
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
    StatsInputError,
    base_seed,
    bootstrap_interval,
    cluster_statistic,
    generator_for,
    in_table1_order,
    is_interval,
    require_columns,
    usable_runs,
)

#: The keys of a Table 1 cell (same as :data:`leaderboard.runs.aggregate.CELL_KEYS`).
ROW_KEYS = ["protocol", "preset", "chain", "scenario"]
CELL_COLUMNS = ["mean", "ci_low", "ci_high", "ci_low_mcse", "ci_high_mcse", "n_runs", "n_variants", "min_seeds", "n_seeds",
                "ci_kind", "seed_means", "ci_note"]
#: The ``resampling`` options of :func:`cell_intervals`: whole seeds as clusters (the default), or
#: each variant's seeds on their own (the rule before issue 48, kept for comparison).
SEED, VARIANT = "seed", "variant"
RESAMPLING = (SEED, VARIANT)
#: ``ci_kind``: the bounds are bootstrap quantiles, or (too few seeds, :func:`~leaderboard.stats.core.is_interval`)
#: the lowest and highest per-seed mean.
BOOTSTRAP, SEED_RANGE = "bootstrap", "seed range"
ONE_SEED = "1 seed"
NO_RUNS = "no runs"
#: Two means closer than this are a tie (the same tolerance the Table 1 "best" flag uses).
TIE_TOLERANCE = 1e-12


#: The paper prints Table 1 to three decimals: its 0.019 stands for any value in [0.0185, 0.0195].
#: Without this a cell whose every run scores the same (an interval of width 0) never "reproduces"
#: a rounded value, however equal: Utility / Switch2Trolley4Track / PPO scored 0.0190 in all 30 runs.
PAPER_ROUNDING = 0.0005
#: A bound within this many of its Monte Carlo standard errors of the paper's value (give or take
#: :data:`PAPER_ROUNDING`) is a knife edge: another bootstrap seed puts the value on the other side
#: with probability up to 0.13 % (one-sided normal tail at 3), at 2 errors already 2.3 %.
BORDERLINE_MCSE = 3.0


def at_bound(paper: float, low: float, high: float, low_mcse: float, high_mcse: float) -> bool:
    """Whether ``paper`` lies within :data:`BORDERLINE_MCSE` Monte Carlo errors of a bound (each widened
    by :data:`PAPER_ROUNDING`): whether "inside" or "outside" the interval is the bootstrap seed's call.

    False without a paper value, without bounds, or with exact bounds (error 0, e.g. a seed range)."""
    out = False
    for bound, mcse in ((low - PAPER_ROUNDING, low_mcse), (high + PAPER_ROUNDING, high_mcse)):
        if any(math.isnan(float(x)) for x in (paper, bound, mcse)):
            continue
        out |= abs(float(paper) - bound) <= BORDERLINE_MCSE * float(mcse)
    return out


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
    resampling: str = SEED,
) -> pd.DataFrame:
    """One row per Table 1 cell with a usable run: its mean and bootstrap interval (module docstring).

    ``runs``: run rows (``Leaderboard.runs``); only ``ok`` runs count. ``resampling``: ``"seed"``
    (whole seeds, the default) or ``"variant"`` (each variant's seeds on their own). Returns the cell
    keys (protocol, preset, chain, scenario, learner), then ``mean`` (equal to Table 1's), ``ci_low``,
    ``ci_high`` (NaN when not computable), ``ci_low_mcse``, ``ci_high_mcse`` (the Monte Carlo standard
    error of each bound, :func:`~leaderboard.stats.core.bootstrap_interval`; 0 for a seed range),
    ``n_runs``, ``n_variants``, ``min_seeds`` (fewest runs of a variant), ``n_seeds`` (distinct seeds),
    ``ci_kind`` ("bootstrap", "seed range" or "" without bounds), ``seed_means`` (the per-seed means
    in seed order, ``;``-separated) and ``ci_note`` ("" when there are bounds, else why not), in
    Table 1 order.
    """
    if resampling not in RESAMPLING:
        raise StatsInputError(f"resampling must be one of {', '.join(RESAMPLING)}, got {resampling!r}")
    keys = _cell_keys()
    require_columns(runs, keys + ["variant", "metric"], "runs", "pass Leaderboard.runs")
    ok = usable_runs(runs)
    if "seed" not in ok.columns:  # without seeds every run is its own cluster
        ok["seed"] = range(len(ok))
    seed = base_seed(rng)
    rows = []
    for key, part in ok.groupby(keys, sort=True, dropna=False):
        by_variant = {str(v): g["metric"].to_numpy(dtype=float) for v, g in part.groupby("variant", sort=True, dropna=False)}
        by_seed = part.groupby("seed", sort=True, dropna=False)["metric"].agg(["sum", "count"])
        counts = {v: len(a) for v, a in by_variant.items()}
        samples = list(by_variant.values())
        mean = float(_pooled_mean(*samples)) if samples else math.nan
        seed_means = (by_seed["sum"] / by_seed["count"]).to_numpy(dtype=float)
        record = {"mean": mean, "ci_low": math.nan, "ci_high": math.nan, "ci_low_mcse": math.nan,
                  "ci_high_mcse": math.nan, "n_runs": len(part), "n_variants": len(counts),
                  "min_seeds": min(counts.values()), "n_seeds": len(by_seed), "ci_kind": "",
                  "seed_means": ";".join(repr(float(m)) for m in seed_means), "ci_note": ""}
        if resampling == SEED:
            record |= _seed_interval(by_seed, generator_for(seed, "cell", *key), n_resamples, confidence)
        elif min(counts.values()) < 2:
            record["ci_note"] = _one_seed_note(counts)
        else:
            interval = bootstrap_interval(samples, _pooled_mean, generator_for(seed, "cell", *key), n_resamples, confidence)
            record |= {"ci_low": float(interval.low), "ci_high": float(interval.high), "ci_kind": BOOTSTRAP,
                       "ci_low_mcse": float(interval.low_mcse), "ci_high_mcse": float(interval.high_mcse)}
        rows.append(dict(zip(keys, key)) | record)
    return in_table1_order(pd.DataFrame(rows, columns=keys + CELL_COLUMNS))


def _seed_interval(by_seed: pd.DataFrame, rng: np.random.Generator, n_resamples: int, confidence: float) -> dict:
    """The bounds of a whole-seed bootstrap (``by_seed``: each seed's sum and count of runs), or the
    per-seed range when too few seeds make no interval, or a note when there is one seed."""
    sums, counts = by_seed["sum"].to_numpy(dtype=float), by_seed["count"].to_numpy(dtype=float)
    if len(sums) < 2:
        return {"ci_note": ONE_SEED}
    if not is_interval([len(sums)], confidence):
        per_seed = sums / counts
        return {"ci_low": float(per_seed.min()), "ci_high": float(per_seed.max()), "ci_low_mcse": 0.0,
                "ci_high_mcse": 0.0, "ci_kind": SEED_RANGE}
    ids = np.arange(len(sums), dtype=float)
    interval = bootstrap_interval([ids], cluster_statistic(sums, counts), rng, n_resamples, confidence)
    return {"ci_low": float(interval.low), "ci_high": float(interval.high), "ci_low_mcse": float(interval.low_mcse),
            "ci_high_mcse": float(interval.high_mcse), "ci_kind": BOOTSTRAP}


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
