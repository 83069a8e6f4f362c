"""The overall ranking: which learner is better across the Table 1 rows, with intervals.

Everything is per sweep setting (protocol, preset): rows of different protocols are different
experiments and are never pooled.

**Normalised score.** A run of row (chain, scenario) scores ``(metric - R) / (B - R)`` where ``R``
is the row's exact expected metric of the uniform random policy and ``B`` the best metric any
policy can reach (the oracle), both the means over the row's variants that Table 1 shows as
"Random (exact)" and "Oracle best". 0 is random, 1 is the oracle; a learner worse than random
scores below 0 (not clipped: that is information), Monte Carlo noise can put a run slightly above
1. Because the map is affine within a row, the mean score of a cell is the normalised Table 1
cell, and orderings within a row are those of the raw metric.

**Guard.** A row whose headroom ``B - R`` is below :data:`MIN_HEADROOM` (0.05) is left out of the
normalised aggregates and marked (``normalised=False`` with a note in :func:`ranking_rows`); it
stays in the raw-metric aggregates. 0.05 is the largest standard error of a share estimated from
the 100 episodes of a final evaluation (0.5 / sqrt(100)): below it, a run's distance from random
is within one standard error of evaluation noise, and dividing by the headroom would blow that
noise up twentyfold or more into scores of -10 that then dominate every mean. In the paper's
Table 1 this excludes DualProcessAgentHarm / PushOrSwitchSelfSacrifice (R = 0.949, B = 0.997).

**Which rows.** Within a (protocol, preset), every learner is aggregated over the same rows: those
in which every learner of the comparison has at least one usable run (and, for scores, a usable
reference). Otherwise a learner that skipped a hard row would rank higher for it. Rows left out
are listed with the reason.

**Aggregates** (Agarwal et al. 2021), over the rows with every row weighing the same (a run of a
row with ``n`` runs weighs ``1/(R n)``; rows have 5 to 12 variants, so pooling runs unweighted
would let the many-variant rows decide): the mean; the interquartile mean (IQM, the mean of the
middle 50 % of the weighted runs, robust to the outlying rows that a mean follows); the optimality
gap (mean shortfall ``max(0, 1 - x)`` from the oracle's score 1, or from the perfect metric 1 on
the raw scale). Intervals: stratified bootstrap with the rows as strata, runs (variants and seeds)
resampled within each row; rows never mix. The interval therefore covers seed-to-seed and
variant-to-variant variation within a row (it exists with one seed per variant, as in the
``quick`` preset) and treats the set of rows as fixed. Why runs and not whole seeds, as a Table 1
cell resamples (:mod:`leaderboard.stats.cells`): a ranking compares learners over the rows' runs,
variants included, so the variants' spread belongs in its interval, and resampling runs lets it in.
It does not cluster a row's runs by seed, so the noise a seed shares across a row's variants is
treated as independent here as it was in the cells before issue 48; whether clustering by seed
would widen these intervals has not been measured. The threshold of :func:`~leaderboard.stats.core.is_interval`
applies all the same: an aggregate over too few runs for the bootstrap's extreme resample to be
rarer than a tail (a single row of three runs: 10 distinct resamples) gets no bounds but a
``ci_note`` saying so, and the page prints its value with that note rather than a precise-looking
bracket. With Table 1's 14 rows of 15-36 runs it never applies.

**Probability of improvement** ``P(X > Y)``: per row, the Mann-Whitney ``U / (n m)`` of X's runs
against Y's (the share of run pairs in which X's metric is higher, ties counting half), averaged
over the rows. Computed on the raw metric, which gives the same U as the score within a row, so
guarded rows need not be dropped. The interval resamples X's and Y's runs independently within
each row. ``P(Y > X) = 1 - P(X > Y)`` by construction (both come from the same resamples).

**Performance profiles**: for each threshold ``tau``, the (row-weighted) share of runs scoring
above ``tau``, with pointwise bootstrap bands from the same stratified resampling.

A row with a single run of a learner contributes that run as a fixed stratum (it cannot be
resampled); it enters the statistics duplicated, which leaves every statistic here unchanged
because each depends only on the row's weighted empirical distribution.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats as sps

from leaderboard.runs.aggregate import ORACLE_BEST, RANDOM_EXACT, learner_order, row_order
from leaderboard.stats.core import (
    AGGREGATE_RESAMPLES,
    CONFIDENCE,
    DEFAULT_RESAMPLES,
    GAP_THRESHOLD,
    IQM_CUT,
    RngLike,
    StatsInputError,
    base_seed,
    bootstrap_interval,
    distinct_resamples,
    generator_for,
    is_interval,
    position_counts,
    positions,
    require_columns,
    stratum_weights,
    usable_runs,
)

#: Rows with ``Oracle best - Random exact`` below this are not normalised (see the module docstring).
MIN_HEADROOM = 0.05
#: How a row's note starts when the row has no normalised score.
NOT_NORMALISED = "not normalised: "
#: The two scales every aggregate is computed on.
SCORE, METRIC = "score", "metric"
MEASURES = (SCORE, METRIC)
#: The aggregate statistics, in display order.
STATISTICS = ("mean", "iqm", "optimality_gap")
GROUP_KEYS = ["protocol", "preset"]
ROW_KEYS = ["protocol", "preset", "chain", "scenario"]
#: Default thresholds of the performance profiles (step 0.025; scores below -1 are all "worse than random").
DEFAULT_TAUS = {SCORE: np.round(np.arange(-1.0, 1.2 + 1e-9, 0.025), 3),
                METRIC: np.round(np.arange(0.0, 1.0 + 1e-9, 0.025), 3)}


# ---------------------------------------------------------------------------------------- references
def reference_frame(table: pd.DataFrame) -> pd.DataFrame:
    """``random`` and ``best`` per (protocol, preset, chain, scenario) from a Table 1 frame.

    ``table`` is ``Leaderboard.table`` (its reference rows "Random (exact)" and "Oracle best");
    a table built without references gives an empty frame, and every row is then reported as not
    normalised.
    """
    require_columns(table, ROW_KEYS + ["learner", "mean"], "table", "pass Leaderboard.table")
    part = table.loc[table["learner"].isin([RANDOM_EXACT, ORACLE_BEST])]
    if part.empty:
        return pd.DataFrame(columns=ROW_KEYS + ["random", "best"])
    wide = part.pivot_table(index=ROW_KEYS, columns="learner", values="mean", aggfunc="first", dropna=False)
    wide = wide.reindex(columns=[RANDOM_EXACT, ORACLE_BEST]).rename(columns={RANDOM_EXACT: "random", ORACLE_BEST: "best"})
    wide.columns.name = None
    return wide.reset_index()[ROW_KEYS + ["random", "best"]]


def _as_reference_frame(references: pd.DataFrame | Mapping[Any, Any] | None) -> pd.DataFrame:
    """Normalise the accepted reference forms to columns ``[protocol, preset,] chain, scenario, random, best``.

    Accepted: a frame with ``chain, scenario, random, best`` (and optionally protocol, preset), a
    Table 1 frame (with the reference rows), or a mapping ``(chain, scenario) -> (random, best)``
    or ``-> {"random": ..., "best": ...}``.
    """
    if references is None:
        return pd.DataFrame(columns=["chain", "scenario", "random", "best"])
    if isinstance(references, pd.DataFrame):
        if {"random", "best"} <= set(references.columns):
            require_columns(references, ["chain", "scenario"], "references", "key them by chain and scenario")
            return references
        if "learner" in references.columns:
            return reference_frame(references)
        require_columns(references, ["chain", "scenario", "random", "best"], "references",
                        "pass reference_frame(Leaderboard.table) or a mapping (chain, scenario) -> (random, best)")
    rows = []
    for key, value in references.items():
        if not (isinstance(key, tuple) and len(key) == 2):
            raise StatsInputError(f"reference key {key!r} is not a (chain, scenario) pair")
        random, best = (value["random"], value["best"]) if isinstance(value, Mapping) else value
        rows.append({"chain": key[0], "scenario": key[1], "random": float(random), "best": float(best)})
    return pd.DataFrame(rows, columns=["chain", "scenario", "random", "best"])


# ---------------------------------------------------------------------------------------- rows and scores
def _learners_of(ok: pd.DataFrame, learners: Sequence[str] | None) -> dict[tuple[str, str], list[str]]:
    out = {}
    for (protocol, preset), part in ok.groupby(GROUP_KEYS, sort=True):
        present = learner_order(part["learner"].astype(str))
        out[(protocol, preset)] = present if learners is None else [name for name in learners]
    return out


def _ranking_record(reference: tuple[float, float], missing: list[str], uneven: bool,
                    min_headroom: float) -> dict[str, Any]:
    """A row's references and whether it is ranked (:func:`ranking_rows`' columns after the row's keys).

    ``reference``: (Random, best) exact metrics, NaN when unknown; ``missing``: the compared learners
    without a usable run in the row; ``uneven``: its learners' runs cover different variants."""
    random, best = reference
    headroom = best - random
    why_not = _not_normalised(headroom, uneven, min_headroom)
    notes = (["no run of " + ", ".join(missing)] if missing else []) + ([why_not] if why_not else [])
    normalised = not math.isnan(headroom) and headroom >= min_headroom and not uneven
    return {"random": random, "best": best, "headroom": headroom, "normalised": normalised,
            "normalised_note": why_not.removeprefix(NOT_NORMALISED), "missing": ", ".join(missing),
            "in_score": normalised and not missing, "in_metric": not missing, "note": "; ".join(notes)}


def ranking_rows(
    runs: pd.DataFrame,
    references: pd.DataFrame | Mapping[Any, Any] | None,
    *,
    learners: Sequence[str] | None = None,
    min_headroom: float = MIN_HEADROOM,
) -> pd.DataFrame:
    """One row per (protocol, preset, chain, scenario) with usable runs: its references and whether it is ranked.

    Columns: protocol, preset, chain, scenario, ``random``, ``best``, ``headroom`` (= best -
    random), ``normalised`` (references known and headroom >= ``min_headroom``), ``normalised_note``
    (why not, "" when normalised: the note's reason without "not normalised: "), ``missing``
    (learners of the comparison without a usable run here, comma-separated), ``in_score`` and
    ``in_metric`` (whether the row enters the normalised / raw aggregates), ``note`` (why not).
    ``learners``: the learners compared (default: every learner with a run in the group).
    """
    ok = usable_runs(runs)
    refs = _as_reference_frame(references)
    by_group = _learners_of(ok, learners)
    ref_keys = [k for k in ROW_KEYS if k in refs.columns]
    lookup = {tuple(r[k] for k in ref_keys): (float(r["random"]), float(r["best"])) for r in refs.to_dict("records")}
    records = []
    for (protocol, preset), part in ok.groupby(GROUP_KEYS, sort=True):
        wanted = by_group[(protocol, preset)]
        present = {pair: set(g["learner"].astype(str)) for pair, g in part.groupby(["chain", "scenario"], sort=True)}
        covers = _variants_per_learner(part)
        for chain, scenario in row_order(present):
            values = {"protocol": protocol, "preset": preset, "chain": chain, "scenario": scenario}
            reference = lookup.get(tuple(values[k] for k in ref_keys), (math.nan, math.nan))
            missing = [name for name in wanted if name not in present[(chain, scenario)]]
            uneven = len(set(covers.get((chain, scenario), {}).values())) > 1
            records.append(values | _ranking_record(reference, missing, uneven, min_headroom))
    columns = ROW_KEYS + ["random", "best", "headroom", "normalised", "normalised_note", "missing", "in_score",
                          "in_metric", "note"]
    return pd.DataFrame(records, columns=columns)


def _not_normalised(headroom: float, uneven: bool, min_headroom: float) -> str:
    """Why a row gets no normalised score ("" when it gets one)."""
    if math.isnan(headroom):
        return "no reference values (Random exact, Oracle best)"
    if uneven:
        # The references are over the variants the row's runs cover; a learner over fewer
        # variants would be normalised by references over others, so no score is made here.
        return NOT_NORMALISED + "the learners' runs cover different variants"
    if headroom < min_headroom:
        return (f"{NOT_NORMALISED}headroom Oracle best - Random exact = {below_text(headroom, min_headroom)} "
                f"< {min_headroom:g} cutoff")
    return ""


def below_text(value: float, cutoff: float) -> str:
    """``value`` with three significant digits (at least three decimals), or more until it reads below ``cutoff``.

    The release's DualProcessAgentHarm / PushOrSwitchSelfSacrifice headroom is 0.0485; one of 0.0496
    printed as 0.050 would read "0.050 < 0.05"."""
    magnitude = math.floor(math.log10(abs(value))) if value else 0
    for decimals in range(max(3, 2 - magnitude), 10):
        text = f"{value:.{decimals}f}"
        if float(text) < cutoff:
            return text
    return repr(value)


def _variants_per_learner(runs: pd.DataFrame) -> dict[tuple[str, str], dict[str, frozenset[str]]]:
    """``{(chain, scenario): {learner: the variants of its usable runs}}`` (empty without a variant column)."""
    if "variant" not in runs.columns:
        return {}
    out: dict[tuple[str, str], dict[str, frozenset[str]]] = {}
    for (chain, scenario, learner), g in runs.groupby(["chain", "scenario", "learner"], sort=True):
        out.setdefault((chain, scenario), {})[str(learner)] = frozenset(g["variant"].astype(str))
    return out


def run_scores(
    runs: pd.DataFrame,
    references: pd.DataFrame | Mapping[Any, Any] | None,
    *,
    min_headroom: float = MIN_HEADROOM,
) -> pd.DataFrame:
    """The usable runs with their normalised ``score`` (NaN in rows that are not normalised).

    Columns: protocol, preset, chain, scenario, variant, learner, seed, run_id, metric, score.
    """
    ok = usable_runs(runs)
    rows = ranking_rows(ok, references, min_headroom=min_headroom)
    columns = ROW_KEYS + ["variant", "learner", "seed", "run_id", "metric"]
    for column in ("variant", "seed", "run_id"):
        if column not in ok.columns:
            ok[column] = None
    if ok.empty:  # no usable run: an empty frame's key columns carry no dtype to merge on
        return pd.DataFrame(columns=columns + ["score"])
    merged = ok[columns].merge(rows[ROW_KEYS + ["random", "best", "normalised"]], on=ROW_KEYS, how="left")
    score = (merged["metric"] - merged["random"]) / (merged["best"] - merged["random"])
    merged["score"] = score.where(merged["normalised"].astype(bool), np.nan).astype(float)
    return merged[columns + ["score"]]


def _values(runs: pd.DataFrame, references: Any, measure: str, min_headroom: float,
            learners: Sequence[str] | None) -> tuple[pd.DataFrame, dict[tuple[str, str], list[str]],
                                                     dict[tuple[str, str], list[tuple[str, str]]], dict[tuple, np.ndarray]]:
    """Shared preparation: per group its learners and ranked rows, and the run values per (group, row, learner)."""
    if measure not in MEASURES:
        raise StatsInputError(f"measure must be one of {MEASURES}, got {measure!r}")
    scores = run_scores(runs, references, min_headroom=min_headroom)
    rows = ranking_rows(runs, references, learners=learners, min_headroom=min_headroom)
    flag = "in_score" if measure == SCORE else "in_metric"
    ranked: dict[tuple[str, str], list[tuple[str, str]]] = {}
    for r in rows.loc[rows[flag].astype(bool)].to_dict("records"):
        ranked.setdefault((r["protocol"], r["preset"]), []).append((r["chain"], r["scenario"]))
    value = SCORE if measure == SCORE else METRIC
    cells = {}
    for key, part in scores.groupby(ROW_KEYS + ["learner"], sort=True):
        cells[tuple(key)] = part[value].to_numpy(dtype=float)
    return rows, _learners_of(usable_runs(runs), learners), ranked, cells


def _stratum(values: np.ndarray) -> np.ndarray:
    """A row's runs as a bootstrap stratum; a single run is duplicated (see the module docstring)."""
    return np.repeat(values, 2) if len(values) == 1 else values


def _aggregate_strata(values: Sequence[np.ndarray]):
    """Bootstrap strata and statistic for the row-weighted mean, IQM and optimality gap (in that order).

    Each run is replaced by its rank among all runs of all rows (ties in any order), so a resample
    is a count per rank and the runs are sorted once, not once per resample: the weighted IQM
    (:func:`~leaderboard.stats.core.weighted_iqm`) then needs one cumulative sum of the resample's
    weights in rank order. The same numbers as :func:`~leaderboard.stats.core.weighted_mean`,
    ``weighted_iqm`` and ``weighted_optimality_gap`` of the resampled runs (tested), and what makes
    :data:`~leaderboard.stats.core.AGGREGATE_RESAMPLES` affordable: the release's aggregates at
    20,000 resamples take 3.3 s of CPU, 6.9 s with a sort per resample.
    """
    pooled = np.concatenate([np.asarray(v, dtype=float) for v in values])
    order = np.argsort(pooled, kind="stable")
    rank = np.empty(len(pooled), dtype=float)
    rank[order] = np.arange(len(pooled))
    sizes = [len(v) for v in values]
    weight = stratum_weights(sizes)[order]
    x = pooled[order]
    shortfall = np.maximum(0.0, GAP_THRESHOLD - x)
    strata = np.split(rank, np.cumsum(sizes)[:-1])

    def statistic(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
        w = position_counts(np.concatenate(samples, axis=-1), len(x)) * weight
        upper = np.cumsum(w, axis=-1)
        total = upper[..., -1]
        inside = np.clip(np.minimum(upper, (1 - IQM_CUT) * total[..., None])
                         - np.maximum(upper - w, IQM_CUT * total[..., None]), 0.0, None)
        return np.stack([w @ x / total, inside @ x / np.sum(inside, axis=-1), w @ shortfall / total])

    return strata, statistic


# ---------------------------------------------------------------------------------------- aggregates
def aggregate_intervals(
    runs: pd.DataFrame,
    references: pd.DataFrame | Mapping[Any, Any] | None,
    *,
    measures: Iterable[str] = MEASURES,
    learners: Sequence[str] | None = None,
    rng: RngLike = None,
    n_resamples: int = AGGREGATE_RESAMPLES,
    confidence: float = CONFIDENCE,
    min_headroom: float = MIN_HEADROOM,
) -> pd.DataFrame:
    """Mean, IQM and optimality gap per (protocol, preset, measure, learner) with 95 % intervals.

    Columns: protocol, preset, measure (``score`` | ``metric``), learner, statistic (``mean`` |
    ``iqm`` | ``optimality_gap``), value, ci_low, ci_high, ci_low_mcse, ci_high_mcse (Monte Carlo
    standard error of each bound), ci_note (why there are no bounds: too few runs, module docstring;
    "" when there are), n_rows, n_runs. A group without any ranked row for a measure has
    no lines for it (see :func:`ranking_rows` for why).
    """
    seed = base_seed(rng)
    out = []
    for measure in measures:
        _, group_learners, ranked, cells = _values(runs, references, measure, min_headroom, learners)
        for group, pairs in ranked.items():
            for learner in group_learners[group]:
                raw = [cells[(*group, chain, scenario, learner)] for chain, scenario in pairs]
                strata, statistic = _aggregate_strata([_stratum(v) for v in raw])
                point = statistic(*strata)
                sizes = [len(v) for v in raw]
                nan = np.full(len(STATISTICS), math.nan)
                low = high = low_mcse = high_mcse = nan
                note = ""
                if is_interval(sizes, confidence):
                    interval = bootstrap_interval(strata, statistic, generator_for(seed, "aggregate", measure, *group, learner),
                                                  n_resamples, confidence)
                    low, high, low_mcse, high_mcse = interval.low, interval.high, interval.low_mcse, interval.high_mcse
                else:  # the bounds would be the extremes of the runs, not an interval (leaderboard.stats.core.is_interval)
                    note = f"{distinct_resamples(sizes)} distinct resamples of {sum(sizes)} runs: too few for an interval"
                for i, name in enumerate(STATISTICS):
                    out.append({"protocol": group[0], "preset": group[1], "measure": measure, "learner": learner,
                                "statistic": name, "value": float(point[i]), "ci_low": float(low[i]),
                                "ci_high": float(high[i]), "ci_low_mcse": float(low_mcse[i]),
                                "ci_high_mcse": float(high_mcse[i]), "ci_note": note,
                                "n_rows": len(pairs), "n_runs": int(sum(sizes))})
    columns = ["protocol", "preset", "measure", "learner", "statistic", "value", "ci_low", "ci_high", "ci_low_mcse",
               "ci_high_mcse", "ci_note", "n_rows", "n_runs"]
    return pd.DataFrame(out, columns=columns)


# ---------------------------------------------------------------------------------------- probability of improvement
def row_improvement(x: np.ndarray, y: np.ndarray) -> float:
    """``U / (n m)`` of Mann-Whitney for one row: the share of (x, y) run pairs with x > y, ties counting half."""
    return float(sps.mannwhitneyu(x, y, method="asymptotic").statistic / (len(x) * len(y)))


def _improvement_strata(xs: Sequence[np.ndarray], ys: Sequence[np.ndarray]):
    """Bootstrap strata and statistic for the mean over rows of ``U / (n m)``.

    Each row's runs are replaced by their positions among the row's distinct values (X's and Y's
    together; :func:`~leaderboard.stats.core.positions`), the strata alternating X's and Y's
    positions row by row. For a resample with ``cx[a]`` copies of value ``a`` among X's runs and
    ``cy[a]`` among Y's, ``U = sum_a cx[a] * (#Y below a + cy[a] / 2)``, linear in the number of
    distinct values. The same number as :func:`row_improvement` (tested against scipy's
    ``mannwhitneyu`` on resamples), which ranks every resample and is ten times slower.
    """
    strata, sizes = [], []
    for x, y in zip(xs, ys):
        u = np.unique(np.concatenate([x, y]))
        strata += [positions(x, u), positions(y, u)]
        sizes.append((len(u), len(x) * len(y)))

    def statistic(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
        total = 0.0
        for (k, pairs), px, py in zip(sizes, samples[0::2], samples[1::2]):
            cx, cy = position_counts(px, k), position_counts(py, k)
            below = np.cumsum(cy, axis=-1) - cy
            total = total + np.sum(cx * (below + 0.5 * cy), axis=-1) / pairs
        return np.asarray(total / len(sizes))

    return strata, statistic


def probability_of_improvement(
    runs: pd.DataFrame,
    *,
    learners: Sequence[str] | None = None,
    rng: RngLike = None,
    n_resamples: int = DEFAULT_RESAMPLES,
    confidence: float = CONFIDENCE,
) -> pd.DataFrame:
    """``P(X > Y)`` for every ordered pair of distinct learners of each (protocol, preset).

    Columns: protocol, preset, learner_x, learner_y, probability, ci_low, ci_high, ci_low_mcse, ci_high_mcse,
    n_rows. Rows
    are those of the raw-metric ranking (every learner has a run there). Each unordered pair is
    bootstrapped once; the reverse pair is ``1 - p`` with the bounds mirrored.
    """
    seed = base_seed(rng)
    _, group_learners, ranked, cells = _values(runs, None, METRIC, MIN_HEADROOM, learners)
    out = []
    for group, pairs in ranked.items():
        names = group_learners[group]
        for i, x_name in enumerate(names):
            for y_name in names[i + 1:]:
                xs = [_stratum(cells[(*group, chain, scenario, x_name)]) for chain, scenario in pairs]
                ys = [_stratum(cells[(*group, chain, scenario, y_name)]) for chain, scenario in pairs]
                point = float(np.mean([row_improvement(x, y) for x, y in zip(xs, ys)]))
                strata, statistic = _improvement_strata(xs, ys)
                interval = bootstrap_interval(strata, statistic, generator_for(seed, "improvement", *group, x_name, y_name),
                                              n_resamples, confidence)
                low, high = float(interval.low), float(interval.high)
                low_mcse, high_mcse = float(interval.low_mcse), float(interval.high_mcse)
                base = {"protocol": group[0], "preset": group[1], "n_rows": len(pairs)}
                out.append(base | {"learner_x": x_name, "learner_y": y_name, "probability": point,
                                   "ci_low": low, "ci_high": high, "ci_low_mcse": low_mcse, "ci_high_mcse": high_mcse})
                out.append(base | {"learner_x": y_name, "learner_y": x_name, "probability": 1.0 - point,
                                   "ci_low": 1.0 - high, "ci_high": 1.0 - low, "ci_low_mcse": high_mcse,
                                   "ci_high_mcse": low_mcse})
    columns = ["protocol", "preset", "learner_x", "learner_y", "probability", "ci_low", "ci_high", "ci_low_mcse",
               "ci_high_mcse", "n_rows"]
    frame = pd.DataFrame(out, columns=columns)
    if frame.empty:
        return frame
    order = {g: {name: i for i, name in enumerate(n)} for g, n in group_learners.items()}
    key = [(p, s, order[(p, s)][x], order[(p, s)][y]) for p, s, x, y in
           zip(frame["protocol"], frame["preset"], frame["learner_x"], frame["learner_y"])]
    return frame.iloc[sorted(range(len(frame)), key=key.__getitem__)].reset_index(drop=True)


# ---------------------------------------------------------------------------------------- performance profiles
def _profile_strata(values: Sequence[np.ndarray], taus: np.ndarray):
    """Bootstrap strata and statistic for the row-weighted share of runs above each tau, shape ``(len(taus), ...)``.

    Runs are replaced by their positions among their row's distinct values; a resample's count
    above ``tau`` is then its number of positions beyond the last distinct value <= ``tau``, read
    off a cumulative count, instead of comparing every resampled run with every threshold (which
    needs gigabytes for 2,000 resamples of 378 runs and 89 thresholds).
    """
    strata, rows = [], []
    for v in values:
        u = np.unique(v)
        strata.append(positions(v, u))
        rows.append((len(u), len(v), np.searchsorted(u, taus, side="right")))

    def statistic(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
        share = 0.0
        for (k, n, at_or_below), pos in zip(rows, samples):
            counts = position_counts(pos, k)
            cumulative = np.concatenate([np.zeros(counts.shape[:-1] + (1,)), np.cumsum(counts, axis=-1)], axis=-1)
            share = share + (n - cumulative[..., at_or_below]) / n
        return np.moveaxis(np.asarray(share / len(rows)), -1, 0)

    return strata, statistic


def performance_profiles(
    runs: pd.DataFrame,
    references: pd.DataFrame | Mapping[Any, Any] | None,
    *,
    measure: str = SCORE,
    taus: Sequence[float] | None = None,
    learners: Sequence[str] | None = None,
    rng: RngLike = None,
    n_resamples: int = DEFAULT_RESAMPLES,
    confidence: float = CONFIDENCE,
    min_headroom: float = MIN_HEADROOM,
) -> pd.DataFrame:
    """Share of runs above each threshold ``tau`` per (protocol, preset, learner), with pointwise bands.

    Columns: protocol, preset, measure, learner, tau, share, ci_low, ci_high, ci_low_mcse, ci_high_mcse,
    n_rows. The share
    weighs rows equally (a row's runs share its weight), like the aggregates.
    """
    grid = np.asarray(DEFAULT_TAUS[measure] if taus is None else taus, dtype=float)
    seed = base_seed(rng)
    _, group_learners, ranked, cells = _values(runs, references, measure, min_headroom, learners)
    out = []
    for group, pairs in ranked.items():
        for learner in group_learners[group]:
            strata, statistic = _profile_strata([_stratum(cells[(*group, chain, scenario, learner)])
                                                 for chain, scenario in pairs], grid)
            point = statistic(*strata)
            interval = bootstrap_interval(strata, statistic, generator_for(seed, "profile", measure, *group, learner),
                                          n_resamples, confidence)
            for j, tau in enumerate(grid):
                out.append({"protocol": group[0], "preset": group[1], "measure": measure, "learner": learner,
                            "tau": float(tau), "share": float(point[j]), "ci_low": float(interval.low[j]),
                            "ci_high": float(interval.high[j]), "ci_low_mcse": float(interval.low_mcse[j]),
                            "ci_high_mcse": float(interval.high_mcse[j]), "n_rows": len(pairs)})
    return pd.DataFrame(out, columns=["protocol", "preset", "measure", "learner", "tau", "share", "ci_low", "ci_high",
                                      "ci_low_mcse", "ci_high_mcse", "n_rows"])
