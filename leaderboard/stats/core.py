"""What every statistic of the leaderboard shares: input checks, seeding, the bootstrap, weighted statistics.

Bootstrap. Every interval is a 95 % *percentile* bootstrap interval from
:func:`scipy.stats.bootstrap` with ``method="percentile"``. Stratification is scipy's own
behaviour for several samples: each sample passed is resampled with replacement independently of
the others, so passing one sample per stratum (a variant, a Table 1 row) is a stratified bootstrap
in which no resample ever moves an observation from one stratum to another. The percentile method
rather than scipy's default BCa because the strata here are tiny (often three seeds): BCa's
acceleration is a jackknife estimate that is unstable on three observations and undefined when a
stratum is constant, whereas percentile intervals are well defined for any data and are what
Agarwal et al. (2021) report.

Monte Carlo error. A bound is a quantile of ``n_resamples`` draws, so it moves with the seed:
between seeds its standard deviation (the Monte Carlo standard error, MCSE) is about 0.015 times
the interval's width at 2,000 resamples and shrinks as one over the square root of their number.
Every interval comes with the MCSE of its bounds (:func:`quantile_mcse`, read off the same draws:
no extra resampling), and a bound is printed to the last decimal it is stable to
(:func:`leaderboard.outputs.precision.stable_decimals`: MCSE at most a quarter of a unit of that decimal,
so two standard errors stay within half a unit). :data:`RESAMPLES` says how many resamples each
statistic draws and why.

Seeding. A build must give the same bytes twice, and a cell's interval must not change because
another cell was added to the results. So no statistic draws from a shared stream: each
bootstrap gets its own generator, derived from a base seed and a stable key naming what it
estimates (:func:`generator_for`).

Weights. Aggregates over Table 1 rows weigh every *row* equally, whatever its number of variants
(5 to 12) and runs: a run of a row with ``n`` runs weighs ``1 / (R * n)``. The weighted statistics
below take those weights on the last axis and work on any leading (bootstrap batch) axes.
"""

from __future__ import annotations

import difflib
import math
import zlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from leaderboard.runs.aggregate import Group, group_order, learner_order, prepare_runs, row_order, split_superseded

#: Coverage of every interval.
CONFIDENCE = 0.95
#: Bootstrap resamples per interval of the statistics whose bounds no page prints to three
#: decimals: the probability of improvement (two decimals on the ranking page: at 2,000
#: resamples the MCSE of its bounds in the shipped release is at most 0.0013, a quarter of a unit
#: of the second decimal is 0.0025), the performance profiles and the learning curves (bands only
#: drawn; their CSVs carry the MCSE). A caller's ``n_resamples`` replaces every count.
DEFAULT_RESAMPLES = 2000
#: Resamples of a Table 1 cell's interval and of the ranking's mean / IQM / optimality gap, whose
#: bounds are printed to three decimals where stable. Measured on the shipped release
#: (releases/paper-table1-v1, spread of each bound over 30 bootstrap seeds): at 2,000 resamples the
#: MCSE of the bounds is median 0.0004 (cells) and 0.0010 (aggregates), max 0.011 and 0.0039, so 32
#: of the 78 cell intervals and 1 of the 30 aggregate intervals were stable to three decimals. 20,000
#: resamples divide the MCSE by 3.2 (median 0.00012 for cells, 0.00031 for aggregates; max 0.0012
#: for aggregates, 0.0093 for the one cell whose lumpy bootstrap distribution puts its lower bound
#: between two atoms): 53 of 78 and 10 of 30 keep three decimals, that cell one, the rest two; for
#: about 0.5 s (cells) and 2.5 s (aggregates, with the sort-free statistic) more CPU per cold build.
#: Three stable decimals for every interval would take about 300,000 resamples (and not for that cell).
CELL_RESAMPLES = 20_000
AGGREGATE_RESAMPLES = 20_000
#: Resamples per statistic when the caller does not choose (:func:`leaderboard.stats.compute_stats`).
RESAMPLES = {"cells": CELL_RESAMPLES, "aggregates": AGGREGATE_RESAMPLES, "improvement": DEFAULT_RESAMPLES,
             "profiles": DEFAULT_RESAMPLES, "curves": DEFAULT_RESAMPLES}
#: Half-widths, in standard deviations of the count of draws below a quantile, of the windows of
#: ordered draws :func:`quantile_mcse` reads the quantile function's slope from (the steeper wins).
MCSE_SPANS = (2.0, 4.0)
#: Bootstrap draws are made in batches of about this many resampled values (memory and cache).
BATCH_VALUES = 4_000_000
#: Base seed of every bootstrap unless the caller passes another (an int or a numpy Generator).
DEFAULT_SEED = 13  # any fixed number does; 13 is the issue that introduced these statistics
#: Optimality gap threshold (gamma): the score of the oracle, or the metric's maximum.
GAP_THRESHOLD = 1.0
#: Share of probability mass cut from each side for the interquartile mean.
IQM_CUT = 0.25

RngLike = np.random.Generator | int | None


class StatsInputError(ValueError):
    """A frame passed to a statistic lacks what it needs (raised with what is missing and the fix)."""


# ---------------------------------------------------------------------------------------- inputs
def require_columns(frame: pd.DataFrame, columns: Iterable[str], what: str, fix: str) -> None:
    """Raise :class:`StatsInputError` naming the missing columns of ``frame`` (and close matches)."""
    missing = [c for c in columns if c not in frame.columns]
    if not missing:
        return
    hints = []
    for name in missing:
        close = difflib.get_close_matches(name, [str(c) for c in frame.columns], n=1)
        if close:
            hints.append(f"{name!r} (did you mean {close[0]!r}?)")
        else:
            hints.append(repr(name))
    raise StatsInputError(f"{what} lacks column(s) {', '.join(hints)}; {fix}")


def usable_runs(runs: pd.DataFrame, what: str = "runs") -> pd.DataFrame:
    """The runs that count: ``ok`` ones, one per slot, as :func:`leaderboard.runs.aggregate.aggregate` counts them.

    Pass ``Leaderboard.runs`` (prepared, superseded runs already removed, column ``ok``). A raw
    frame from :func:`morality_gym.results.schema.read_runs` (no ``ok`` column) is prepared and de-duplicated
    here with the aggregator's own functions (without manifests, a slot keeps its newest usable
    run), so the rules for "ok" and "superseded" stay defined once.
    """
    require_columns(runs, ["chain", "scenario", "learner", "metric"], what,
                    "pass run rows as morality_gym.results.schema.read_runs or Leaderboard.runs return them")
    if "ok" not in runs.columns:
        runs, _ = split_superseded(prepare_runs(runs), {})
    return runs.loc[runs["ok"].astype(bool)].copy()


def in_table1_order(frame: pd.DataFrame, then: Sequence[str] = ()) -> pd.DataFrame:
    """``frame`` sorted as Table 1 is: sweep (protocol, preset), row (chain, scenario), learner, then ``then``.

    So that every output frame (and every CSV written from it) lists its lines in one order that
    does not depend on how the input was ordered.
    """
    frame = frame.reset_index(drop=True)  # positions, whatever index (even a duplicated one) came in
    if frame.empty:
        return frame
    groups = {(g.protocol, g.preset): i for i, g in enumerate(group_order(Group(p, s) for p, s in
                                                                             zip(frame["protocol"], frame["preset"])))}
    rows = {pair: i for i, pair in enumerate(row_order(zip(frame["chain"], frame["scenario"])))}
    learners = {name: i for i, name in enumerate(learner_order(frame["learner"].astype(str)))}
    key = pd.DataFrame({
        "_g": [groups[(p, s)] for p, s in zip(frame["protocol"], frame["preset"])],
        "_r": [rows[(c, s)] for c, s in zip(frame["chain"], frame["scenario"])],
        "_l": [learners[str(name)] for name in frame["learner"]],
    }, index=frame.index)
    ordered = pd.concat([key, frame[list(then)]], axis=1).sort_values(["_g", "_r", "_l", *then], kind="stable")
    return frame.iloc[ordered.index.to_numpy()].reset_index(drop=True)


# ---------------------------------------------------------------------------------------- seeding
def base_seed(rng: RngLike) -> int:
    """The integer every per-estimate generator of one call is derived from.

    ``None`` means :data:`DEFAULT_SEED` (reproducible by default); an ``int`` is used as is; a
    ``numpy.random.Generator`` gives one draw (so a caller's generator decides, once per call).
    """
    if rng is None:
        return DEFAULT_SEED
    if isinstance(rng, np.random.Generator):
        return int(rng.integers(0, 2**63 - 1))
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) and int(rng) >= 0:
        return int(rng)
    raise StatsInputError(f"rng must be a numpy Generator, a non-negative int or None, got {rng!r}")


def generator_for(seed: int, *key: Any) -> np.random.Generator:
    """A generator for one estimate: seeded by ``seed`` and a CRC-32 of the key's text.

    The key names the estimate (e.g. ``("cell", protocol, preset, chain, scenario, learner)``),
    so its interval depends only on its own data and the seed, never on the order of a loop or on
    which other results exist.
    """
    text = "\x1f".join(str(part) for part in key)
    return np.random.default_rng([seed, zlib.crc32(text.encode("utf-8"))])


# ---------------------------------------------------------------------------------------- bootstrap
@dataclass(frozen=True)
class BootstrapInterval:
    """A percentile interval and the Monte Carlo standard error of each bound."""

    low: np.ndarray
    high: np.ndarray
    low_mcse: np.ndarray
    high_mcse: np.ndarray


def bootstrap_interval(
    samples: Sequence[np.ndarray],
    statistic: Callable[..., np.ndarray],
    rng: np.random.Generator,
    n_resamples: int = DEFAULT_RESAMPLES,
    confidence: float = CONFIDENCE,
    axis: int = -1,
) -> BootstrapInterval:
    """A two-sided percentile interval, each sample resampled on its own, with each bound's MCSE.

    ``statistic(*samples, axis=-1)`` must be vectorised (scipy passes a batch of resamples at
    once); it may return a vector (one interval per entry). Every sample needs two or more
    observations: a single observation cannot be resampled and the caller decides what that means.
    """
    arrays = tuple(np.asarray(s, dtype=float) for s in samples)
    batch = max(1000, BATCH_VALUES // max(1, sum(a.size for a in arrays)))
    result = stats.bootstrap(arrays, statistic, n_resamples=n_resamples, batch=batch, vectorized=True, axis=axis,
                             confidence_level=confidence, method="percentile", rng=rng)
    low, high = result.confidence_interval
    alpha = (1 - confidence) / 2
    low_mcse, high_mcse = quantile_mcse(result.bootstrap_distribution, [alpha, 1 - alpha])
    return BootstrapInterval(np.asarray(low, dtype=float), np.asarray(high, dtype=float), low_mcse, high_mcse)


def percentile_bootstrap(
    samples: Sequence[np.ndarray],
    statistic: Callable[..., np.ndarray],
    rng: np.random.Generator,
    n_resamples: int = DEFAULT_RESAMPLES,
    confidence: float = CONFIDENCE,
    axis: int = -1,
) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` of :func:`bootstrap_interval`."""
    interval = bootstrap_interval(samples, statistic, rng, n_resamples, confidence, axis)
    return interval.low, interval.high


def quantile_mcse(draws: np.ndarray, levels: Sequence[float]) -> np.ndarray:
    """Monte Carlo standard error of the ``levels`` quantiles of ``draws`` (last axis), shape ``(len(levels), ...)``.

    Read off the ordered draws themselves: of ``B`` draws, the number below the true ``q``
    quantile is binomial with standard deviation ``s = sqrt(B q (1 - q))``, so the estimated
    quantile moves by ``s`` times the slope of the quantile function, in draws. The slope is that of
    the ordered draws over ``k * s`` draws on each side of the quantile, the steeper of
    ``k`` in :data:`MCSE_SPANS`: distribution-free, and a gap between atoms of a lumpy bootstrap
    distribution (a cell whose runs take few distinct values) shows in the wider window even when
    the draws of this seed put the quantile a little away from it. On the shipped release it is
    within about 15 % of the spread of the bounds over bootstrap seeds (median ratio about 1).
    """
    ordered = np.sort(np.asarray(draws, dtype=float), axis=-1)
    b = ordered.shape[-1]
    out = []
    for q in levels:
        spread = math.sqrt(b * q * (1 - q))
        at = (b - 1) * q
        slopes = [np.zeros(ordered.shape[:-1])]
        for span in MCSE_SPANS:
            lo, hi = max(0.0, at - span * spread), min(b - 1.0, at + span * spread)
            if hi > lo:
                slopes.append((_ordered_at(ordered, hi) - _ordered_at(ordered, lo)) / (hi - lo))
        out.append(np.max(slopes, axis=0) * spread)
    return np.stack(out)


def _ordered_at(ordered: np.ndarray, position: float) -> np.ndarray:
    """The sorted draws at a fractional position (linear interpolation), along the last axis."""
    below = math.floor(position)
    above = min(below + 1, ordered.shape[-1] - 1)
    share = position - below
    return ordered[..., below] * (1 - share) + ordered[..., above] * share


def distinct_resamples(sizes: Sequence[int]) -> int:
    """How many different resamples a bootstrap of strata of these sizes can draw (as multisets).

    A stratum of ``n`` units resampled with replacement has ``C(2n - 1, n)`` distinct resamples:
    10 for three seeds, 35 for four; strata multiply."""
    return math.prod(math.comb(2 * n - 1, n) for n in sizes)


def extreme_resample_share(sizes: Sequence[int]) -> float:
    """The probability that a resample repeats, in every stratum, one and the same unit (``prod n ** -n``).

    It is the share of the bootstrap distribution sitting on its most extreme atom (every stratum's
    lowest unit drawn every time, or its highest)."""
    return math.prod(float(n) ** -n for n in sizes)


def is_interval(sizes: Sequence[int], confidence: float = CONFIDENCE) -> bool:
    """Whether a percentile bootstrap over strata of ``sizes`` units gives an interval at all.

    Not when the most extreme atom alone holds more than a tail, ``(1 - confidence) / 2``: then the
    bounds are, for every data and every bootstrap seed, the lowest and the highest value a unit can
    give, i.e. the range of the data, printed as if it were a 95 % interval. With one stratum of three
    seeds (10 distinct resamples) the atom holds 1/27 = 3.7 % > 2.5 %: a seed-level "interval" of a
    three-seed cell is exactly the range of its three per-seed means. From four seeds (35 distinct
    resamples, 0.4 % on the atom) the bounds are quantiles inside the range, though coarse ones."""
    return bool(sizes) and extreme_resample_share(sizes) < (1 - confidence) / 2


def fewest_units_for_interval(confidence: float = CONFIDENCE) -> int:
    """The fewest units (seeds) of a single stratum whose bootstrap is an interval (:func:`is_interval`): 4 at 95 %."""
    return next(n for n in range(2, 100) if is_interval([n], confidence))


def cluster_statistic(sums: np.ndarray, counts: np.ndarray) -> Callable[..., np.ndarray]:
    """The pooled mean of resampled *clusters*, as a statistic of their resampled ids.

    A cluster (a seed, with all its runs) contributes its sum and its count of runs; a resample is a
    draw of cluster ids with replacement and its mean is ``sum(sums[ids]) / sum(counts[ids])``: the
    Table 1 mean of the runs of the drawn seeds. Pass ``np.arange(len(sums))`` as the sample."""
    k = len(sums)

    def statistic(ids: np.ndarray, axis: int = -1) -> np.ndarray:
        drawn = position_counts(np.moveaxis(ids, axis, -1), k)
        return (drawn @ sums) / (drawn @ counts)

    return statistic


# ---------------------------------------------------------------------------------------- weighted statistics
def stratum_weights(sizes: Sequence[int]) -> np.ndarray:
    """Per-observation weights making every stratum weigh the same: ``1 / (len(sizes) * n)``."""
    if not sizes or min(sizes) < 1:
        raise StatsInputError(f"every stratum needs at least one observation, got sizes {list(sizes)}")
    return np.concatenate([np.full(n, 1.0 / (len(sizes) * n)) for n in sizes])


def weighted_mean(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``sum(w * x) / sum(w)`` along the last axis."""
    return np.sum(x * w, axis=-1) / np.sum(w)


def weighted_iqm(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Interquartile mean of the weighted sample along the last axis: the mean of its middle 50 %.

    Observations are sorted; each contributes the part of its weight that lies between 25 % and
    75 % of the total weight, and the result is the weighted mean of those parts. An observation
    straddling a quartile counts with the fraction inside, which is the usual definition of the
    IQM when the sample size is not a multiple of four (with 9 equal weights the two boundary
    values count 3/4 each). With equal weights and a size divisible by four it is exactly
    ``scipy.stats.trim_mean(x, 0.25)`` (tested), which is Agarwal et al.'s IQM.
    """
    order = np.argsort(x, axis=-1)  # ties may come in any order: tied values contribute the same
    xs = np.take_along_axis(x, order, axis=-1)
    ws = np.take_along_axis(np.broadcast_to(w, x.shape), order, axis=-1)
    upper = np.cumsum(ws, axis=-1)
    lower = upper - ws
    total = upper[..., -1:]
    inside = np.clip(np.minimum(upper, (1 - IQM_CUT) * total) - np.maximum(lower, IQM_CUT * total), 0.0, None)
    return np.sum(xs * inside, axis=-1) / np.sum(inside, axis=-1)


def weighted_optimality_gap(x: np.ndarray, w: np.ndarray, gamma: float = GAP_THRESHOLD) -> np.ndarray:
    """Weighted mean of ``max(0, gamma - x)``: how far, on average, scores fall short of ``gamma``.

    Agarwal et al.'s optimality gap: scores above ``gamma`` earn nothing extra, so a learner
    cannot buy back a failed row with a super-oracle Monte Carlo fluke on another.
    """
    return weighted_mean(np.maximum(0.0, gamma - x), w)


def positions(sample: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Each observation's index among the sorted distinct ``values`` (as floats, for scipy's bootstrap).

    Statistics that depend only on order, ties and thresholds (the probability of improvement, the
    performance profiles) lose nothing when runs are replaced by these positions, and counting
    positions in a resample is one ``bincount`` instead of comparing every resampled run with
    every other value or threshold.
    """
    return np.searchsorted(values, sample).astype(float)


def position_counts(pos: np.ndarray, k: int) -> np.ndarray:
    """How often each position ``0..k-1`` occurs along the last axis of ``pos``; shape ``pos.shape[:-1] + (k,)``."""
    lead = pos.shape[:-1]
    size = int(np.prod(lead, dtype=np.int64))
    offsets = (np.arange(size, dtype=np.int64) * k).reshape(lead + (1,))
    counts = np.bincount((pos.astype(np.int64) + offsets).ravel(), minlength=size * k)
    return counts.reshape(lead + (k,)).astype(float)
