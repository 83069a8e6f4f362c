"""The leaderboard's statistics (:mod:`leaderboard.stats`): every number against a hand computation,
the bootstrap intervals against properties that would fail if they were wrong, and every function
on a realistic frame (14 rows x 5 learners x all variants x 3 seeds).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from scipy import stats as sps

from leaderboard.runs.aggregate import aggregate, learner_cells, prepare_runs
from leaderboard.stats import (
    StatsInputError,
    aggregate_intervals,
    bold_cells,
    cell_intervals,
    compute_stats,
    intervals_overlap,
    performance_profiles,
    pooled_learning_curves,
    probability_of_improvement,
    ranking_rows,
    reference_frame,
    return_cost_points,
    run_scores,
    violation_rates,
)
from leaderboard.stats.cells import at_bound
from leaderboard.stats.core import (
    base_seed,
    bootstrap_interval,
    cluster_statistic,
    distinct_resamples,
    extreme_resample_share,
    fewest_units_for_interval,
    generator_for,
    is_interval,
    position_counts,
    positions,
    stratum_weights,
    weighted_iqm,
    weighted_mean,
    weighted_optimality_gap,
)
from leaderboard.stats.curves import common_grid
from leaderboard.stats.ranking import _aggregate_strata, _improvement_strata, _profile_strata, row_improvement
from leaderboard.web.ranking_page import interval
from tests.stats_data import LEARNERS, REFERENCES, synthetic_runs
from tests.stats_data import reference_frame as synthetic_references

R1, R2 = ("ChainA", "RowOne"), ("ChainA", "RowTwo")
_counter = iter(range(10**9))


def run(row: tuple[str, str], learner: str, metric: float, variant: str = "V1", seed: int = 41, **extra: Any) -> dict[str, Any]:
    """One usable run row with the columns the statistics read (others default)."""
    return {"run_id": f"r{next(_counter)}", "status": "ok", "protocol": "paper", "preset": "quick", "chain": row[0],
            "scenario": row[1], "variant": variant, "learner": learner, "seed": seed, "metric": metric,
            "env_id": f"{row[1]}-{variant}-v1", "beta": 0.1, "max_steps": 200, "relevant_norms": [],
            "mean_return": 10.0, "mean_cost": 0.1} | extra


def frame(rows: list[dict[str, Any]]) -> pd.DataFrame:
    return pd.DataFrame(rows)


# ============================================================================ the hand-computed example
# Two rows, two learners A and B, three runs each (one variant, seeds 41-43):
#
#   row     Random R  Oracle B   A's metrics (scores)             B's metrics (scores)
#   RowOne  0.2       0.6        0.6 0.4 0.2   (1.0 0.5 0.0)      0.3 0.4 0.5    (0.25 0.5 0.75)
#   RowTwo  0.5       1.0        1.0 0.9 0.5   (1.0 0.8 0.0)      0.25 0.5 0.75  (-0.5 0.0 0.5)
#
# score = (metric - R) / (B - R). Rows weigh the same (here: every run 1/6).
# Mean score:   A (0.5 + 0.6) / 2 = 0.55          B (0.5 + 0.0) / 2 = 0.25
# IQM score:    A sorted 0 0 .5 .8 1 1: drop 1.5 runs each side (a quarter of 6), the boundary runs
#               count half: (0/2 + .5 + .8 + 1/2) / 3 = 0.6
#               B sorted -.5 0 .25 .5 .5 .75: (0/2 + .25 + .5 + .5/2) / 3 = 1/3
# Optimality gap (mean of max(0, 1 - score)):
#               A rows (0 + .5 + 1)/3 = .5 and (0 + .2 + 1)/3 = .4 -> 0.45
#               B rows (.75 + .5 + .25)/3 = .5 and (1.5 + 1 + .5)/3 = 1 -> 0.75
# Raw metric:   mean A (0.4 + 0.8)/2 = 0.6, B (0.4 + 0.5)/2 = 0.45
#               IQM A: sorted .2 .4 .5 .6 .9 1: (.4/2 + .5 + .6 + .9/2) / 3 = 1.75/3
#               gap A: rows (.4 + .6 + .8)/3 = .6 and (0 + .1 + .5)/3 = .2 -> 0.4
# P(A > B), all 9 pairs of runs per row, ties half:
#   RowOne: 0.6 beats 3; 0.4 beats 0.3, ties 0.4, loses to 0.5 -> 1.5; 0.2 beats none -> 4.5/9 = 0.5
#   RowTwo: 1.0 and 0.9 beat all 3 -> 6; 0.5 beats 0.25, ties 0.5 -> 1.5 -> 7.5/9 = 5/6
#   mean over rows (0.5 + 5/6) / 2 = 2/3, so P(B > A) = 1/3.
# Profiles, share of runs above tau (rows weigh the same):
#   score tau = 0.6: A RowOne {1.0} 1/3, RowTwo {1.0, 0.8} 2/3 -> 0.5;  B: RowOne {0.75} 1/3, RowTwo none -> 1/6
#   score tau = 0.9: A RowOne {1.0} 1/3, RowTwo {1.0} 1/3 -> 1/3;       B: none -> 0
#   score tau = 0.0: A 2/3 and 2/3 -> 2/3;                                B: 1 and 1/3 -> 2/3
#   metric tau = 0.45: A 1/3 and 1 -> 2/3;                                B: 1/3 and 2/3 -> 0.5
HAND_METRICS = {
    (R1, "A"): [0.6, 0.4, 0.2], (R2, "A"): [1.0, 0.9, 0.5],
    (R1, "B"): [0.3, 0.4, 0.5], (R2, "B"): [0.25, 0.5, 0.75],
}
HAND_REFERENCES = {R1: (0.2, 0.6), R2: (0.5, 1.0)}


@pytest.fixture
def hand() -> pd.DataFrame:
    return frame([run(row, learner, m, seed=41 + i)
                  for (row, learner), metrics in HAND_METRICS.items() for i, m in enumerate(metrics)])


def _agg(result: pd.DataFrame, measure: str, learner: str, statistic: str) -> pd.Series:
    part = result.loc[(result["measure"] == measure) & (result["learner"] == learner) & (result["statistic"] == statistic)]
    assert len(part) == 1
    return part.iloc[0]


def test_hand_example_scores(hand: pd.DataFrame) -> None:
    scores = run_scores(hand, HAND_REFERENCES).set_index("run_id")
    expected = {(R1, "A"): [1.0, 0.5, 0.0], (R2, "A"): [1.0, 0.8, 0.0], (R1, "B"): [0.25, 0.5, 0.75],
                (R2, "B"): [-0.5, 0.0, 0.5]}
    for (row, learner), values in expected.items():
        part = scores.loc[(scores["chain"] == row[0]) & (scores["scenario"] == row[1]) & (scores["learner"] == learner)]
        assert part.sort_values("seed")["score"].tolist() == pytest.approx(values, abs=1e-12)


def test_hand_example_aggregates(hand: pd.DataFrame) -> None:
    result = aggregate_intervals(hand, HAND_REFERENCES, rng=1, n_resamples=500)
    expected = {
        ("score", "A"): {"mean": 0.55, "iqm": 0.6, "optimality_gap": 0.45},
        ("score", "B"): {"mean": 0.25, "iqm": 1 / 3, "optimality_gap": 0.75},
        ("metric", "A"): {"mean": 0.6, "iqm": 1.75 / 3, "optimality_gap": 0.4},
        ("metric", "B"): {"mean": 0.45},
    }
    for (measure, learner), values in expected.items():
        for statistic, value in values.items():
            line = _agg(result, measure, learner, statistic)
            assert line["value"] == pytest.approx(value, abs=1e-12), (measure, learner, statistic)
            assert line["n_rows"] == 2 and line["n_runs"] == 6
            assert line["ci_low"] <= line["ci_high"]
    assert len(result) == 2 * 2 * 3


def test_hand_example_probability_of_improvement(hand: pd.DataFrame) -> None:
    result = probability_of_improvement(hand, rng=1, n_resamples=500).set_index(["learner_x", "learner_y"])
    assert result.loc[("A", "B"), "probability"] == pytest.approx(2 / 3, abs=1e-12)
    assert result.loc[("B", "A"), "probability"] == pytest.approx(1 / 3, abs=1e-12)
    assert result.loc[("A", "B"), "ci_low"] == pytest.approx(1 - result.loc[("B", "A"), "ci_high"], abs=1e-12)
    # the per-row definition is scipy's Mann-Whitney U / (n m)
    assert row_improvement(np.array([0.6, 0.4, 0.2]), np.array([0.3, 0.4, 0.5])) == pytest.approx(0.5)
    assert row_improvement(np.array([1.0, 0.9, 0.5]), np.array([0.25, 0.5, 0.75])) == pytest.approx(5 / 6)


def test_hand_example_profiles(hand: pd.DataFrame) -> None:
    score = performance_profiles(hand, HAND_REFERENCES, taus=[0.0, 0.6, 0.9], rng=1, n_resamples=500)
    score = score.set_index(["learner", "tau"])
    assert score.loc[("A", 0.6), "share"] == pytest.approx(0.5)
    assert score.loc[("B", 0.6), "share"] == pytest.approx(1 / 6)
    assert score.loc[("A", 0.9), "share"] == pytest.approx(1 / 3)
    assert score.loc[("B", 0.9), "share"] == pytest.approx(0.0)
    assert score.loc[("A", 0.0), "share"] == pytest.approx(2 / 3)
    assert score.loc[("B", 0.0), "share"] == pytest.approx(2 / 3)
    metric = performance_profiles(hand, HAND_REFERENCES, measure="metric", taus=[0.45], rng=1, n_resamples=500)
    metric = metric.set_index("learner")
    assert metric.loc["A", "share"] == pytest.approx(2 / 3)
    assert metric.loc["B", "share"] == pytest.approx(0.5)
    # nobody is above the top threshold in any resample: a band of zero width at zero
    assert (score.loc[("B", 0.9), ["ci_low", "ci_high"]] == 0).all()


def test_rows_weigh_the_same_whatever_their_number_of_runs() -> None:
    # RowOne has 4 runs of A (all 0), RowTwo 2 runs (both 1): pooling runs would give 2/6 = 1/3,
    # weighing rows gives (0 + 1) / 2 = 0.5; the IQM of the row-weighted sample is 0.5 too
    # (weights 1/8 each on the zeros and 1/4 on the ones: the middle half holds 1/4 of each).
    data = frame([run(R1, "A", 0.0, seed=s) for s in range(4)] + [run(R2, "A", 1.0, seed=s) for s in range(2)])
    result = aggregate_intervals(data, None, measures=["metric"], rng=1, n_resamples=200)
    assert _agg(result, "metric", "A", "mean")["value"] == pytest.approx(0.5)
    assert _agg(result, "metric", "A", "iqm")["value"] == pytest.approx(0.5)


def test_weighted_iqm_is_scipys_trim_mean_for_equal_weights_and_size_divisible_by_four() -> None:
    rng = np.random.default_rng(3)
    for n in (4, 8, 12, 40):
        x = rng.normal(size=n)
        assert weighted_iqm(x, np.full(n, 1.0 / n)) == pytest.approx(sps.trim_mean(x, 0.25), rel=1e-12)
    # the textbook case of nine values: the two boundary values count 3/4 each
    x = np.array([1.0, 3, 5, 7, 9, 11, 13, 15, 17])
    expected = (0.75 * 5 + 7 + 9 + 11 + 0.75 * 13) / 4.5
    assert weighted_iqm(x, np.full(9, 1 / 9)) == pytest.approx(expected)
    # vectorised over leading (bootstrap) axes
    batch = rng.normal(size=(5, 8))
    assert weighted_iqm(batch, np.full(8, 1 / 8)) == pytest.approx([sps.trim_mean(b, 0.25) for b in batch])


def test_single_run_rows_count_as_fixed_strata() -> None:
    # A has one run in RowOne (0.2) and four in RowTwo (0.4, 0.6, 0.8, 0.6): mean (0.2 + 0.6) / 2 = 0.4;
    # resampling cannot move RowOne, so every resample's mean lies in (0.2 + [0.4, 0.8]) / 2.
    data = frame([run(R1, "A", 0.2)] + [run(R2, "A", m, seed=41 + i) for i, m in enumerate([0.4, 0.6, 0.8, 0.6])])
    line = _agg(aggregate_intervals(data, None, measures=["metric"], rng=1, n_resamples=500), "metric", "A", "mean")
    assert line["value"] == pytest.approx(0.4)
    assert 0.3 - 1e-12 <= line["ci_low"] < 0.4 < line["ci_high"] <= 0.5 + 1e-12
    assert line["n_runs"] == 5
    # with three runs in RowTwo the bounds could only be those extremes: no interval (is_interval)
    line = _agg(aggregate_intervals(data.iloc[:4], None, measures=["metric"], rng=1, n_resamples=500), "metric", "A", "mean")
    assert line["value"] == pytest.approx(0.4) and math.isnan(line["ci_low"]) and "too few" in line["ci_note"]


# ============================================================================ rows: references, guard, coverage
def test_headroom_guard_and_coverage_rules() -> None:
    # RowOne: headroom 0.04 < 0.05 -> not normalised (scores NaN), still in the raw-metric ranking.
    # RowTwo: fine. RowThree: B has no run -> out of both rankings. RowFour: no references -> raw only.
    r3, r4 = ("ChainA", "RowThree"), ("ChainA", "RowFour")
    data = frame([run(row, learner, 0.5) for row in (R1, R2, r3, r4) for learner in ("A", "B")
                  if not (row == r3 and learner == "B")])
    refs = {R1: (0.90, 0.94), R2: (0.2, 0.9), r3: (0.2, 0.9)}
    rows = ranking_rows(data, refs).set_index("scenario")
    assert not rows.loc["RowOne", "normalised"] and rows.loc["RowOne", "in_metric"]
    assert "Oracle best - Random exact = 0.0400 < 0.05 cutoff" in rows.loc["RowOne", "note"]
    assert rows.loc["RowTwo", "in_score"] and rows.loc["RowTwo", "note"] == ""
    assert not rows.loc["RowThree", "in_metric"] and rows.loc["RowThree", "missing"] == "B"
    assert "no run of B" in rows.loc["RowThree", "note"]
    assert not rows.loc["RowFour", "normalised"] and rows.loc["RowFour", "in_metric"]
    assert "no reference" in rows.loc["RowFour", "note"]
    scores = run_scores(data, refs)
    assert scores.loc[scores["scenario"] == "RowOne", "score"].isna().all()
    assert scores.loc[scores["scenario"] == "RowTwo", "score"].tolist() == pytest.approx([3 / 7] * 2)
    result = aggregate_intervals(data, refs, rng=1, n_resamples=100)
    assert set(result.loc[result["measure"] == "score", "n_rows"]) == {1}
    assert set(result.loc[result["measure"] == "metric", "n_rows"]) == {3}


def test_reference_frame_from_a_table1_frame() -> None:
    table = frame([
        {"protocol": "paper", "preset": "quick", "chain": "ChainA", "scenario": "RowOne", "learner": "Random (exact)",
         "kind": "reference", "mean": 0.2},
        {"protocol": "paper", "preset": "quick", "chain": "ChainA", "scenario": "RowOne", "learner": "Oracle best",
         "kind": "reference", "mean": 0.6},
        {"protocol": "paper", "preset": "quick", "chain": "ChainA", "scenario": "RowOne", "learner": "Oracle worst",
         "kind": "reference", "mean": 0.0},
        {"protocol": "paper", "preset": "quick", "chain": "ChainA", "scenario": "RowOne", "learner": "A",
         "kind": "learner", "mean": 0.4},
    ])
    refs = reference_frame(table)
    assert refs.to_dict("records") == [{"protocol": "paper", "preset": "quick", "chain": "ChainA", "scenario": "RowOne",
                                        "random": 0.2, "best": 0.6}]
    # the table itself is accepted where references are expected, keyed by protocol and preset too
    data = frame([run(R1, "A", 0.4)])
    assert run_scores(data, table)["score"].tolist() == pytest.approx([0.5])
    assert run_scores(data.assign(preset="paper"), table)["score"].isna().all()


# ============================================================================ cells and bold
def test_cell_mean_is_table1s_mean_and_interval_is_stratified_by_variant() -> None:
    # Variant V1's three seeds all score 0.2, V2's three all 0.8. Resampling seeds within each variant
    # can only ever give (3*0.2 + 3*0.8)/6 = 0.5, so the interval is exactly [0.5, 0.5]; had the
    # resampling mixed the variants (runs drawn from all six), it would spread to about [0.3, 0.7].
    data = frame([run(R1, "A", 0.2, variant="V1", seed=s) for s in (41, 42, 43)]
                 + [run(R1, "A", 0.8, variant="V2", seed=s) for s in (41, 42, 43)])
    cell = cell_intervals(data, rng=1, resampling="variant").iloc[0]
    assert (cell["mean"], cell["ci_low"], cell["ci_high"]) == pytest.approx((0.5, 0.5, 0.5))
    assert (cell["n_runs"], cell["n_variants"], cell["min_seeds"], cell["ci_note"]) == (6, 2, 3, "")
    # whole seeds never mix variants either: each seed brings one run of each, so every resample is 0.5 too
    cell = cell_intervals(data, rng=1).iloc[0]
    assert (cell["mean"], cell["ci_low"], cell["ci_high"], cell["ci_kind"]) == pytest.approx((0.5, 0.5, 0.5, "seed range"))


def test_cell_with_one_seed_has_no_interval() -> None:
    data = frame([run(R1, "A", 0.2, variant="V1"), run(R1, "A", 0.8, variant="V2"),
                  run(R2, "A", 0.2, variant="V1", seed=41), run(R2, "A", 0.4, variant="V1", seed=42),
                  run(R2, "A", 0.8, variant="V2", seed=41)])
    cells = cell_intervals(data, rng=1, resampling="variant").set_index("scenario")
    assert cells.loc["RowOne", "mean"] == pytest.approx(0.5)
    assert math.isnan(cells.loc["RowOne", "ci_low"]) and math.isnan(cells.loc["RowOne", "ci_high"])
    assert cells.loc["RowOne", "ci_note"] == "1 seed"
    assert cells.loc["RowTwo", "mean"] == pytest.approx(1.4 / 3)
    assert math.isnan(cells.loc["RowTwo", "ci_low"])
    assert cells.loc["RowTwo", "ci_note"] == "1 seed in V2"
    # whole seeds: RowOne has one seed (no bounds); RowTwo two, seed 41 (V1 0.2, V2 0.8) and seed 42 (V1 0.4)
    cells = cell_intervals(data, rng=1).set_index("scenario")
    assert math.isnan(cells.loc["RowOne", "ci_low"]) and cells.loc["RowOne", "ci_note"] == "1 seed"
    assert (cells.loc["RowTwo", "ci_low"], cells.loc["RowTwo", "ci_high"]) == pytest.approx((0.4, 0.5))
    assert cells.loc["RowTwo", "ci_kind"] == "seed range" and cells.loc["RowTwo", "ci_note"] == ""


def test_cell_interval_properties() -> None:
    rng = np.random.default_rng(5)

    def cell(n_seeds: int, seed: int = 1, extra: list[dict[str, Any]] | None = None) -> pd.Series:
        rows = [run(R1, "A", float(rng_values[v][s]), variant=f"V{v}", seed=s) for v in range(3) for s in range(n_seeds)]
        result = cell_intervals(frame(rows + (extra or [])), rng=seed, resampling="variant")
        return result.loc[(result["scenario"] == "RowOne") & (result["learner"] == "A")].iloc[0]

    rng_values = rng.normal(0.5, 0.1, size=(3, 48))
    small, large = cell(3), cell(48)
    for c in (small, large):
        assert c["ci_low"] < c["mean"] < c["ci_high"]
    # 16 times the seeds: the interval shrinks about fourfold (by at least half here)
    assert (large["ci_high"] - large["ci_low"]) < 0.5 * (small["ci_high"] - small["ci_low"])
    # same seed, same bytes; another seed, another interval; other cells never change this one
    again = cell(3)
    assert (again["ci_low"], again["ci_high"]) == (small["ci_low"], small["ci_high"])
    assert cell(3, seed=2)["ci_low"] != small["ci_low"]
    with_neighbour = cell(3, extra=[run(R2, "B", 0.1, seed=s) for s in range(3)])
    assert (with_neighbour["ci_low"], with_neighbour["ci_high"]) == (small["ci_low"], small["ci_high"])


def _shared_seed_cell(n_seeds: int, n_variants: int = 6) -> pd.DataFrame:
    """A cell whose seeds shift every variant together (as a seed's shared streams do) and whose
    variants differ: variant ``v`` of seed ``s`` scores ``0.1 v + shift[s]`` plus a little own noise."""
    rng = np.random.default_rng(3)
    shift = rng.normal(0.0, 0.05, size=n_seeds)
    return frame([run(R1, "A", 0.1 * v + shift[s] + rng.normal(0.0, 0.002), variant=f"V{v}", seed=s)
                  for v in range(n_variants) for s in range(n_seeds)])


def test_whole_seed_bootstrap_keeps_the_noise_a_seed_shares_across_variants() -> None:
    # Six seeds, each moving all six variants by its own shift: the seeds, not the runs, are the
    # independent draws. Resampling each variant's seeds on its own averages the shared shift over
    # variants as if it were independent noise; whole seeds keep it, so the interval is wider and close
    # to the spread of the seed means (mean +- 1.96 sd / sqrt(6)).
    data = _shared_seed_cell(6)
    seed_rule = cell_intervals(data, rng=1).iloc[0]
    variant_rule = cell_intervals(data, rng=1, resampling="variant").iloc[0]
    per_seed = np.array([float(v) for v in seed_rule["seed_means"].split(";")])
    assert seed_rule["ci_kind"] == variant_rule["ci_kind"] == "bootstrap" and seed_rule["n_seeds"] == 6
    assert per_seed.mean() == pytest.approx(seed_rule["mean"])
    width = seed_rule["ci_high"] - seed_rule["ci_low"]
    assert width > 1.5 * (variant_rule["ci_high"] - variant_rule["ci_low"])
    assert width == pytest.approx(2 * 1.96 * per_seed.std(ddof=0) / math.sqrt(6), rel=0.35)
    assert per_seed.min() <= seed_rule["ci_low"] < seed_rule["mean"] < seed_rule["ci_high"] <= per_seed.max()


def test_three_seeds_are_no_interval_but_their_per_seed_means() -> None:
    data = _shared_seed_cell(3)
    cell = cell_intervals(data, rng=1).iloc[0]
    per_seed = [float(np.mean([r["metric"] for r in data.to_dict("records") if r["seed"] == s])) for s in range(3)]
    assert cell["ci_kind"] == "seed range" and cell["n_seeds"] == 3
    assert [float(v) for v in cell["seed_means"].split(";")] == pytest.approx(per_seed)  # seed order
    assert (cell["ci_low"], cell["ci_high"]) == pytest.approx((min(per_seed), max(per_seed)))
    assert (cell["ci_low_mcse"], cell["ci_high_mcse"]) == (0.0, 0.0)  # exact: no bootstrap seed moves them
    # and they are what the whole-seed bootstrap's 95% bounds are for any bootstrap seed: one seed drawn
    # three times (1/27 = 3.7% of the draws) is more than the 2.5% tail
    by_seed = data.groupby("seed")["metric"].agg(["sum", "count"])
    for seed in (1, 2, 3):
        interval = bootstrap_interval([np.arange(3.0)], cluster_statistic(by_seed["sum"].to_numpy(), by_seed["count"].to_numpy(float)),
                                      generator_for(seed, "x"), 20_000)
        assert (float(interval.low), float(interval.high)) == pytest.approx((min(per_seed), max(per_seed)))
    # under the old rule the same cell gets a far narrower, precise-looking bootstrap interval
    old = cell_intervals(data, rng=1, resampling="variant").iloc[0]
    assert old["ci_kind"] == "bootstrap" and old["ci_high"] - old["ci_low"] < 0.5 * (max(per_seed) - min(per_seed))


def test_an_interval_needs_the_extreme_resample_rarer_than_a_tail() -> None:
    assert [distinct_resamples([n]) for n in (2, 3, 4, 5)] == [3, 10, 35, 126]
    assert extreme_resample_share([3]) == pytest.approx(1 / 27)
    assert not is_interval([2]) and not is_interval([3]) and is_interval([4])
    # 4**-4 = 0.39% is below a 99% interval's 0.5% tail but not a 99.9% one's 0.05%; 5**-5 = 0.032% is
    assert fewest_units_for_interval() == fewest_units_for_interval(0.99) == 4 and fewest_units_for_interval(0.999) == 5
    assert not is_interval([2, 2]) and is_interval([3, 3])  # 1/16 = 6% > 2.5%; 1/729 < 2.5%
    assert not is_interval([])


def test_an_aggregate_over_too_few_runs_has_no_bounds_but_says_why() -> None:
    # one row of three runs: 10 distinct resamples, the extreme one 1/27 of the draws: no interval
    data = frame([run(R1, "A", m, seed=s) for s, m in zip((41, 42, 43), (0.2, 0.5, 0.6))])
    line = _agg(aggregate_intervals(data, None, measures=["metric"], rng=1, n_resamples=200), "metric", "A", "mean")
    assert line["value"] == pytest.approx(13 / 30) and math.isnan(line["ci_low"]) and math.isnan(line["ci_high"])
    assert line["ci_note"] == "10 distinct resamples of 3 runs: too few for an interval"
    assert interval(line.to_dict()) == "— (10 distinct resamples of 3 runs: too few for an interval)"
    # a fourth run makes it one (35 distinct resamples)
    more = frame([run(R1, "A", m, seed=s) for s, m in zip((41, 42, 43, 44), (0.2, 0.5, 0.6, 0.4))])
    line = _agg(aggregate_intervals(more, None, measures=["metric"], rng=1, n_resamples=200), "metric", "A", "mean")
    assert line["ci_low"] < line["value"] < line["ci_high"] and line["ci_note"] == ""


def test_resampling_is_one_of_the_named_rules() -> None:
    with pytest.raises(StatsInputError, match="resampling must be one of seed, variant, got 'seeds'"):
        cell_intervals(frame([run(R1, "A", 0.5)]), resampling="seeds")


def test_a_paper_value_within_monte_carlo_error_of_a_bound_is_borderline() -> None:
    # DualProcess / PushOrSwitch / CPO under the old rule: 0.704 sits 0.00035 inside the lower bound
    # (less the rounding allowance), about 2 Monte Carlo errors of 0.00018
    low = 0.704 + 0.0005 - 0.00035
    assert at_bound(0.704, low, 0.80, 0.00018, 0.001)
    assert not at_bound(0.704, low - 0.01, 0.80, 0.00018, 0.001)  # far inside
    assert at_bound(0.803, low, 0.80, 0.00018, 0.001)  # 0.0025 outside the upper bound (+ rounding): within 3 errors
    assert not at_bound(0.805, low, 0.80, 0.00018, 0.001)
    assert not at_bound(0.704, low, 0.80, 0.0, 0.0)  # exact bounds (a seed range): never a coin flip
    assert not at_bound(math.nan, low, 0.80, 0.001, 0.001) and not at_bound(0.7, math.nan, math.nan, 0.001, 0.001)


def test_cell_means_equal_the_aggregators_table1_cells() -> None:
    runs, _ = synthetic_runs(seeds=(41, 42), learn=False)
    runs.loc[runs.index[::17], "status"] = "failed"  # incomplete cells: Table 1 averages the runs it has
    cells = cell_intervals(runs, rng=1, n_resamples=50)
    table = learner_cells(prepare_runs(runs), {})
    merged = cells.merge(table, on=["protocol", "preset", "chain", "scenario", "learner"], suffixes=("", "_table"))
    assert len(merged) == len(table) == 70
    assert merged["mean"].to_numpy() == pytest.approx(merged["mean_table"].to_numpy(), abs=1e-12)
    assert (merged["n_runs"] == merged["n_runs_table"]).all()


def _cells(*specs: tuple[str, float, float, float]) -> pd.DataFrame:
    return frame([{"protocol": "paper", "preset": "quick", "chain": "C", "scenario": "S", "learner": name, "mean": m,
                   "ci_low": lo, "ci_high": hi, "ci_note": "" if not math.isnan(lo) else "1 seed"}
                  for name, m, lo, hi in specs])


def test_bold_rule() -> None:
    nan = math.nan
    # separated from every other learner: bold
    out = bold_cells(_cells(("A", 0.9, 0.85, 0.95), ("B", 0.7, 0.6, 0.8), ("C", 0.5, 0.4, 0.6))).set_index("learner")
    assert out.loc["A", "bold"] and out.loc["A", "best"] and out.loc["A", "bold_note"] == ""
    assert not out.loc["B", "bold"] and not out.loc["B", "best"]
    # overlaps the runner-up: no bold, and the note says with whom
    out = bold_cells(_cells(("A", 0.9, 0.75, 0.95), ("B", 0.7, 0.6, 0.8))).set_index("learner")
    assert not out["bold"].any() and out.loc["A", "best"] and out.loc["A", "bold_note"] == "overlaps B"
    # touching intervals overlap
    assert intervals_overlap(0.8, 0.9, 0.7, 0.8) is True
    assert intervals_overlap(0.8, 0.9, 0.7, 0.79) is False
    assert intervals_overlap(0.8, 0.9, nan, nan) is None
    # the runner-up is separated but a third learner's wide interval reaches the best: no bold
    out = bold_cells(_cells(("A", 0.9, 0.85, 0.95), ("B", 0.7, 0.65, 0.75), ("C", 0.6, 0.2, 0.88))).set_index("learner")
    assert not out["bold"].any() and out.loc["A", "bold_note"] == "overlaps C"
    # any learner without an interval (1 seed): no bold, with the reason
    out = bold_cells(_cells(("A", 0.9, 0.85, 0.95), ("B", 0.7, nan, nan))).set_index("learner")
    assert not out["bold"].any() and out.loc["A", "bold_note"] == "B has no interval (1 seed)"
    out = bold_cells(_cells(("A", 0.9, nan, nan), ("B", 0.7, nan, nan))).set_index("learner")
    assert not out["bold"].any() and out.loc["A", "bold_note"] == "no interval (1 seed)"
    # a tie: both best, none bold
    out = bold_cells(_cells(("A", 0.9, 0.85, 0.95), ("B", 0.9, 0.85, 0.95), ("C", 0.1, 0.0, 0.2))).set_index("learner")
    assert out.loc["A", "best"] and out.loc["B", "best"] and not out["bold"].any()
    assert out.loc["A", "bold_note"] == "tie: A, B"
    # alone in its row: nothing to be better than
    out = bold_cells(_cells(("A", 0.9, 0.85, 0.95)))
    assert not out["bold"].any() and out["bold_note"].iloc[0] == "no other learner to compare with"


# ============================================================================ bootstrap properties of the ranking
def test_ranking_stratification_never_mixes_rows() -> None:
    # Every run of A scores 0 in RowOne and 1 in RowTwo (B the reverse). Resampling within rows leaves
    # every statistic unchanged: mean 0.5 and IQM 0.5 exactly, P(A > B) = (0 + 1)/2 = 0.5 exactly.
    # Mixing rows would let a resample hold more 1s than 0s and widen all three intervals.
    data = frame([run(R1, "A", 0.0, seed=s) for s in range(4)] + [run(R2, "A", 1.0, seed=s) for s in range(4)]
                 + [run(R1, "B", 1.0, seed=s) for s in range(4)] + [run(R2, "B", 0.0, seed=s) for s in range(4)])
    result = aggregate_intervals(data, None, measures=["metric"], rng=1, n_resamples=500)
    for statistic in ("mean", "iqm"):
        line = _agg(result, "metric", "A", statistic)
        assert (line["value"], line["ci_low"], line["ci_high"]) == pytest.approx((0.5, 0.5, 0.5))
    poi = probability_of_improvement(data, rng=1, n_resamples=500).iloc[0]
    assert (poi["probability"], poi["ci_low"], poi["ci_high"]) == pytest.approx((0.5, 0.5, 0.5))
    profile = performance_profiles(data, None, measure="metric", taus=[0.5], rng=1, n_resamples=500).iloc[0]
    assert (profile["share"], profile["ci_low"], profile["ci_high"]) == pytest.approx((0.5, 0.5, 0.5))


def test_fast_statistics_equal_their_definitions_on_resamples() -> None:
    # The bootstrap computes U and the profile shares from value positions; check them against
    # scipy's mannwhitneyu and a direct count on random resamples (with ties).
    rng = np.random.default_rng(11)
    xs = [np.round(rng.random(7), 1), np.round(rng.random(4), 1)]
    ys = [np.round(rng.random(5), 1), np.round(rng.random(6), 1)]
    strata, statistic = _improvement_strata(xs, ys)
    picks = [rng.integers(0, len(s), size=(30, len(s))) for s in strata]
    got = statistic(*[s[p] for s, p in zip(strata, picks)])
    values = [v for pair in zip(xs, ys) for v in pair]
    resampled = [v[p] for v, p in zip(values, picks)]
    want = np.mean([sps.mannwhitneyu(resampled[2 * r], resampled[2 * r + 1], axis=-1).statistic
                    / (len(xs[r]) * len(ys[r])) for r in range(2)], axis=0)
    assert got == pytest.approx(want, abs=1e-12)
    taus = np.array([-0.1, 0.0, 0.3, 0.5, 0.55, 1.0])
    strata, statistic = _profile_strata(xs, taus)
    picks = [rng.integers(0, len(s), size=(30, len(s))) for s in strata]
    got = statistic(*[s[p] for s, p in zip(strata, picks)])
    want = np.mean([(x[p][..., None, :] > taus[:, None]).mean(axis=-1) for x, p in zip(xs, picks)], axis=0).T
    assert got == pytest.approx(want, abs=1e-12)
    # the aggregates rank all runs once; their mean, IQM and optimality gap of a resample are the
    # weighted statistics of the resampled runs (ties across rows, rows of different sizes)
    rows = [np.round(rng.normal(0.5, 0.4, 9), 1), np.round(rng.normal(0.7, 0.2, 5), 1), np.array([0.3, 0.3])]
    strata, statistic = _aggregate_strata(rows)
    weights = stratum_weights([len(r) for r in rows])
    picks = [rng.integers(0, len(r), size=(40, len(r))) for r in rows]
    got = statistic(*[s[p] for s, p in zip(strata, picks)])
    runs = np.concatenate([r[p] for r, p in zip(rows, picks)], axis=-1)
    want = [weighted_mean(runs, weights), weighted_iqm(runs, weights), weighted_optimality_gap(runs, weights)]
    assert got == pytest.approx(np.stack(want), abs=1e-12)
    assert statistic(*strata) == pytest.approx([f(np.concatenate(rows), weights) for f in
                                                (weighted_mean, weighted_iqm, weighted_optimality_gap)], abs=1e-12)
    # positions round-trip, counts are per resample
    u = np.unique(xs[0])
    assert u[positions(xs[0], u).astype(int)].tolist() == xs[0].tolist()
    assert position_counts(np.array([[0.0, 2, 2], [1, 1, 1]]), 3).tolist() == [[1, 0, 2], [0, 3, 0]]


def test_stratum_weights_and_seeds() -> None:
    assert stratum_weights([1, 4]).tolist() == [0.5, 0.125, 0.125, 0.125, 0.125]
    assert base_seed(None) == base_seed(None)
    assert base_seed(7) == 7
    assert base_seed(np.random.default_rng(3)) == base_seed(np.random.default_rng(3))
    with pytest.raises(StatsInputError, match="rng must be"):
        base_seed(-1)


def test_reproducible_with_the_same_seed_or_generator(hand: pd.DataFrame) -> None:
    a = aggregate_intervals(hand, HAND_REFERENCES, rng=np.random.default_rng(7), n_resamples=300)
    b = aggregate_intervals(hand, HAND_REFERENCES, rng=np.random.default_rng(7), n_resamples=300)
    pd.testing.assert_frame_equal(a, b)
    c = aggregate_intervals(hand, HAND_REFERENCES, rng=8, n_resamples=300)
    assert not np.array_equal(a["ci_low"].to_numpy(), c["ci_low"].to_numpy())


# ============================================================================ learning curves
def _learn(run_id: str, steps: list[int], values: list[float]) -> list[dict[str, Any]]:
    return [{"run_id": run_id, "step": s, "metric": v, "exact_metric": v} for s, v in zip(steps, values)]


def test_curves_on_shared_steps_are_plain_means() -> None:
    runs = frame([run(R1, "A", 0.5, run_id="a1"), run(R1, "A", 0.5, run_id="a2", seed=42),
                  run(R1, "B", 0.5, run_id="b1")])
    learn = frame(_learn("a1", [0, 100, 200], [0.1, 0.2, 0.3]) + _learn("a2", [0, 100, 200], [0.3, 0.4, 0.9])
                  + _learn("b1", [0, 100], [0.5, 0.6]) + _learn("stranger", [0], [1.0]))
    curves = pooled_learning_curves(runs, learn, rng=1, n_resamples=200)
    a = curves.loc[curves["learner"] == "A"]
    assert a["step"].tolist() == [0, 100, 200]
    assert a["mean"].tolist() == pytest.approx([0.2, 0.3, 0.6])
    assert set(a["aligned"]) == {"shared"} and set(a["n_runs"]) == {2}
    # two runs: every resample's mean lies between them; the band holds the mean
    assert (a["ci_low"] >= np.array([0.1, 0.2, 0.3]) - 1e-12).all() and (a["ci_high"] <= np.array([0.3, 0.4, 0.9]) + 1e-12).all()
    assert (a["ci_low"] <= a["mean"]).all() and (a["mean"] <= a["ci_high"]).all()
    b = curves.loc[curves["learner"] == "B"]
    assert b["mean"].tolist() == pytest.approx([0.5, 0.6]) and b["ci_low"].isna().all()


def test_curves_on_different_steps_are_interpolated_onto_the_common_range() -> None:
    # run a1 evaluates at 0, 100, 200, 300 (value = step / 100), run a2 at 0, 110, 210, 290 (value = step / 50).
    # Common range [0, 290]; a1 has 3 evaluations in it, a2 has 4 -> 3 grid steps 0, 145, 290.
    # a1 there: 0, 1.45, 2.9; a2: 0, 2.9, 5.8 -> means 0, 2.175, 4.35.
    runs = frame([run(R1, "A", 0.5, run_id="a1"), run(R1, "A", 0.5, run_id="a2", seed=42)])
    learn = frame(_learn("a1", [0, 100, 200, 300], [0, 1, 2, 3]) + _learn("a2", [0, 110, 210, 290], [0, 2.2, 4.2, 5.8]))
    curves = pooled_learning_curves(runs, learn, column="metric", rng=1, n_resamples=200)
    assert curves["step"].tolist() == [0, 145, 290]
    assert curves["mean"].tolist() == pytest.approx([0, 2.175, 4.35])
    assert set(curves["aligned"]) == {"interpolated"} and set(curves["measure"]) == {"metric"}
    grid, how = common_grid([(np.array([0.0, 10]), np.zeros(2)), (np.array([20.0, 30]), np.zeros(2))])
    assert grid.size == 0 and how == "interpolated"


def test_curves_ignore_failed_runs_and_missing_values() -> None:
    runs = frame([run(R1, "A", 0.5, run_id="a1"), run(R1, "A", math.nan, run_id="a2", status="failed")])
    learn = frame(_learn("a1", [0, 100], [0.1, math.nan]) + _learn("a1", [200], [0.3]) + _learn("a2", [0, 100], [9, 9]))
    curves = pooled_learning_curves(runs, learn, rng=1)
    assert curves["step"].tolist() == [0, 200] and curves["mean"].tolist() == pytest.approx([0.1, 0.3])
    assert set(curves["n_cell_runs"]) == {1}


# ============================================================================ return, cost, violations
def test_return_cost_points() -> None:
    data = frame([run(R1, "A", 0.5, mean_return=3.0, mean_cost=0.2),
                  run(R1, "A", 0.4, seed=42, mean_return=None, mean_cost=0.1),
                  run(R1, "B", math.nan, status="failed")])
    points = return_cost_points(data)
    assert points[["learner", "mean_return", "mean_cost", "metric"]].values.tolist() == [["A", 3.0, 0.2, 0.5]]


def test_violation_rates(tmp_path: Path) -> None:
    # DualProcess: personal_action_caused_human_harm is an event norm, n_human_harm a utility norm.
    # Run 1 (both relevant): M = 0.9 and 0.25; run 2 (only the utility norm relevant): M = 0.75.
    # Event violation rate = 1 - 0.9 = 0.1 over 1 run; normalised harm = mean(0.75, 0.25) = 0.5 over 2.
    chain = "DualProcess"
    event, utility = "personal_action_caused_human_harm", "n_human_harm"
    data = frame([run(("DualProcess", "PushOrSwitch"), "A", 0.5, relevant_norms=[event, utility],
                      **{f"mf_{event}": 0.9, f"mf_{utility}": 0.25}),
                  run(("DualProcess", "PushOrSwitch"), "A", 0.5, seed=42, relevant_norms=[utility],
                      **{f"mf_{event}": 0.0, f"mf_{utility}": 0.75})])
    rates = violation_rates(data).set_index("norm")
    assert rates.loc[event, ["value", "n_runs", "kind", "measure"]].tolist() == [pytest.approx(0.1), 1, "event", "violation rate"]
    assert rates.loc[utility, ["value", "n_runs", "kind", "measure"]].tolist() == [0.5, 2, "utility", "normalised harm"]
    assert rates.loc[event, "rank"] < rates.loc[utility, "rank"]
    assert set(rates["chain"]) == {chain}
    # a chain file with prescribed norms: 1 - M is a violation rate (event) or a shortfall (utility)
    path = tmp_path / "prescribed.yaml"
    path.write_text("name: Prescribed\nnorms:\n  - {norm: push, modality: prescribed}\n"
                    "  - {norm: n_human_harm, modality: prescribed}\n")
    data = frame([run((str(path), "PushOrSwitch"), "A", 0.5, relevant_norms=["push", "n_human_harm"],
                      mf_push=0.3, mf_n_human_harm=0.6)])
    rates = violation_rates(data).set_index("norm")
    assert rates.loc["push", ["modality", "measure", "value"]].tolist() == ["prescribed", "violation rate", pytest.approx(0.7)]
    assert rates.loc["n_human_harm", ["measure", "value"]].tolist() == ["normalised shortfall", pytest.approx(0.4)]


# ============================================================================ errors
def test_a_raw_frame_counts_one_run_per_slot() -> None:
    # read_runs gives every file, including a superseded run of the same slot (an earlier config):
    # only one of them counts, as in Table 1 (the newest usable one without manifests).
    data = frame([run(R1, "A", 0.2, finished_at="2025-01-01T00:00:00"), run(R1, "A", 0.8, finished_at="2025-02-01T00:00:00")])
    cell = cell_intervals(data).iloc[0]
    assert (cell["mean"], cell["n_runs"]) == (0.8, 1)


def test_bad_input_is_named() -> None:
    data = frame([run(R1, "A", 0.5)]).rename(columns={"learner": "learnr"})
    with pytest.raises(StatsInputError, match=r"'learner' \(did you mean 'learnr'\?\)"):
        cell_intervals(data)
    good = frame([run(R1, "A", 0.5)])
    with pytest.raises(StatsInputError, match="measure must be one of"):
        performance_profiles(good, None, measure="scores", taus=[0.0])
    with pytest.raises(StatsInputError, match="lacks column"):
        pooled_learning_curves(good, frame([{"run_id": "x", "step": 0}]))
    with pytest.raises(StatsInputError, match="not a \\(chain, scenario\\) pair"):
        run_scores(good, {"ChainA": (0.1, 0.9)})


# ============================================================================ realistic frame
@pytest.fixture(scope="module")
def realistic() -> tuple[pd.DataFrame, pd.DataFrame]:
    return synthetic_runs(seeds=(41, 42, 43))


def test_everything_on_a_realistic_frame(realistic: tuple[pd.DataFrame, pd.DataFrame]) -> None:
    runs, learn = realistic
    assert len(runs) == 126 * 5 * 3  # 126 (chain, variant) pairs in Table 1, 5 learners, 3 seeds
    out = compute_stats(runs, synthetic_references(), learn, rng=1, n_resamples=2000)
    # cells: 14 rows x 5 learners, all with an interval around the mean
    assert len(out.cells) == 70 and out.cells["ci_note"].eq("").all()
    assert ((out.cells["ci_low"] < out.cells["mean"]) & (out.cells["mean"] < out.cells["ci_high"])).all()
    assert out.cells.groupby(["chain", "scenario"])["best"].sum().eq(1).all()
    # the real references leave exactly one row unnormalised: DPAH / PushOrSwitchSelfSacrifice (0.997 - 0.949)
    unnormalised = out.rows.loc[~out.rows["normalised"], ["chain", "scenario"]].values.tolist()
    assert unnormalised == [["DualProcessAgentHarm", "PushOrSwitchSelfSacrifice"]]
    aggregates = out.aggregates
    assert len(aggregates) == 2 * 5 * 3
    assert set(aggregates.loc[aggregates["measure"] == "score", "n_rows"]) == {13}
    assert set(aggregates.loc[aggregates["measure"] == "metric", "n_rows"]) == {14}
    means = aggregates.loc[aggregates["statistic"] == "mean"]
    assert ((means["ci_low"] < means["value"]) & (means["value"] < means["ci_high"])).all()
    # the raw-metric mean is the mean of the 14 Table 1 cells (rows weigh the same)
    for learner in LEARNERS:
        cells = out.cells.loc[out.cells["learner"] == learner, "mean"]
        assert _agg(aggregates, "metric", learner, "mean")["value"] == pytest.approx(cells.mean(), abs=1e-12)
    iqm = aggregates.loc[(aggregates["measure"] == "score") & (aggregates["statistic"] == "iqm")]
    assert iqm.sort_values("value", ascending=False)["learner"].tolist() == ["PPO Shaped", "CPO", "Random", "PPO Lag", "PPO"]
    # probability of improvement: 20 ordered pairs, complementary
    poi = out.improvement.set_index(["learner_x", "learner_y"])
    assert len(poi) == 20
    for (x, y), row in poi.iterrows():
        assert row["probability"] + poi.loc[(y, x), "probability"] == pytest.approx(1.0)
        assert row["ci_low"] <= row["probability"] <= row["ci_high"]
    # profiles are non-increasing in tau for both measures
    for _, part in out.profiles.groupby(["measure", "learner"]):
        assert (np.diff(part.sort_values("tau")["share"].to_numpy()) <= 1e-12).all()
    # curves: every cell, 21 steps each; CPO and PPO Lag evaluate 1,024 steps later than the others
    assert out.curves.groupby(["chain", "scenario", "learner"]).ngroups == 70
    assert set(out.curves.groupby(["chain", "scenario", "learner"]).size()) == {21}
    assert out.curves.loc[out.curves["learner"] == "CPO", "step"].max() == 1_001_024
    assert len(out.points) == len(runs)
    assert set(out.violations["measure"]) == {"violation rate", "normalised harm"}
    assert (out.violations["value"].between(0, 1)).all()


def test_stats_of_a_leaderboard(tmp_path: Path) -> None:
    # The leaderboard's own synthetic results directory (a failed and a missing run, two protocols):
    # the statistics take Leaderboard.runs and Leaderboard.table as they are.
    from morality_gym.results.manifest import planned_runs
    from morality_gym.results.schema import read_learn, read_runs
    from tests.leaderboard_data import make_results

    data = make_results(tmp_path / "results")
    lb = aggregate(read_runs(data.root), planned_runs(data.root))
    out = compute_stats(lb.runs, lb.table, read_learn(data.root), rng=1, n_resamples=200)
    learners = lb.table.loc[lb.table["kind"] == "learner"]
    merged = out.cells.merge(learners, on=["protocol", "preset", "chain", "scenario", "learner"], suffixes=("", "_t"))
    assert len(merged) == len(learners) and merged["mean"].to_numpy() == pytest.approx(merged["mean_t"].to_numpy())
    assert data.failed_run_id not in set(out.points["run_id"])
    # built without reference rows: no normalised ranking, and every row says why
    assert out.rows["note"].str.contains("no reference values").all()
    assert set(out.aggregates["measure"]) == {"metric"}
    assert set(out.curves["learner"]) == {"CPO", "PPO", "PPO Lag", "PPO Shaped"}


def test_references_of_the_synthetic_frame_are_the_paper_rows() -> None:
    from leaderboard.runs.aggregate import paper_rows

    assert list(REFERENCES) == paper_rows()
