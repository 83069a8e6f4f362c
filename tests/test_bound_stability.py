"""Issue 32, item 4: every interval bound the leaderboard prints is stable to its last printed digit.

A percentile bound is a quantile of finitely many bootstrap resamples, so it moves with the seed.
The ranking page once printed a lower bound that 60 other seeds put 2.5 standard deviations away.
Now each bound comes with its Monte Carlo standard error (MCSE, read off the resamples), each
statistic draws enough resamples (:data:`leaderboard.stats.RESAMPLES`) to keep three decimals for
most intervals, and a bound is printed only to the decimals on which its MCSE is at most a quarter of
a unit (:mod:`leaderboard.precision`): two standard errors within half a unit.

The test that matters recomputes, on the shipped release, every interval the pages print (Table 1
cells, the ranking's mean / IQM / optimality gap on both scales, P(X > Y)) with another bootstrap
seed, and checks the criterion where it can be checked: in units of each interval's printed last
digit, the difference between two seeds' bounds has standard deviation at most sqrt(2) / 4 = 0.354
if every bound meets the criterion. Equality of the printed digits is not the criterion: a bound
that sits on a rounding boundary flips by one unit however many resamples are drawn.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from leaderboard.outputs.precision import STABLE_SHARE, stable_decimals
from leaderboard.outputs.tables import interval_text
from leaderboard.stats import (
    RESAMPLES,
    aggregate_intervals,
    cell_intervals,
    probability_of_improvement,
    ranking_rows,
)
from leaderboard.stats.core import bootstrap_interval, generator_for, quantile_mcse
from leaderboard.web.ranking_page import left_out, left_out_rows
from leaderboard.web.render import clean_records
from tests.stats_data import reference_frame as synthetic_references
from tests.stats_data import synthetic_runs

ROOT = Path(__file__).resolve().parents[1]
RELEASE = ROOT / "releases" / "paper-table1-v1"
#: The bootstrap seed the pages use (None: DEFAULT_SEED) and another one.
SEEDS = (None, 2024)
#: Standard deviation of the difference of two seeds' bounds, in units of the printed last digit,
#: when both meet the criterion (MCSE <= STABLE_SHARE units): sqrt(2) * STABLE_SHARE.
MOST_SPREAD = np.sqrt(2) * STABLE_SHARE


# ---------------------------------------------------------------------------------------- the rule
def test_stable_decimals_and_the_printed_interval() -> None:
    assert [stable_decimals(e, 3) for e in (0.0, 0.0001, 0.00025, 0.00026, 0.0025, 0.003, 0.03)] == [3, 3, 3, 2, 2, 1, 0]
    assert stable_decimals(None, 3) == stable_decimals(float("nan"), 3) == 3  # no error known: as before
    cell = {"ci_low": 0.74184, "ci_high": 0.85977, "ci_low_mcse": 0.0006, "ci_high_mcse": 0.0002}
    assert interval_text(cell) == "[0.74, 0.86]"  # both bounds to the decimals both are stable to
    assert interval_text(cell | {"ci_low_mcse": 0.0002}) == "[0.742, 0.860]"
    assert interval_text(cell | {"ci_low_mcse": 0.0002}, 2) == "[0.74, 0.86]"  # never more than the page's digits
    assert interval_text({"ci_low": 0.74184, "ci_high": 0.85977}) == "[0.742, 0.860]"  # a table without errors
    assert interval_text({"ci_low": float("nan"), "ci_high": 0.8}) == ""


def test_quantile_mcse_matches_the_spread_of_bounds_over_seeds() -> None:
    """The MCSE read off one seed's resamples is the spread of the bound over 60 seeds, within 30 %."""
    rng = np.random.default_rng(3)

    def mean(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
        return np.mean(np.concatenate(samples, axis=-1), axis=-1)

    for samples in ([rng.normal(size=30)], [rng.exponential(size=25)], [rng.normal(size=3) for _ in range(11)]):
        results = [bootstrap_interval(samples, mean, generator_for(seed, "mcse"), 2000) for seed in range(60)]
        for bound, error in (("low", "low_mcse"), ("high", "high_mcse")):
            spread = np.std([getattr(r, bound) for r in results], ddof=1)
            estimate = np.mean([getattr(r, error) for r in results])
            assert 0.75 * spread < estimate < 1.35 * spread, (bound, spread, estimate)
    # an exactly normal sample of draws: the textbook sqrt(q (1 - q) / B) / density at the quantile
    draws = np.random.default_rng(5).normal(size=(200, 20_000))
    textbook = np.sqrt(0.025 * 0.975 / 20_000) / (np.exp(-1.959964**2 / 2) / np.sqrt(2 * np.pi))
    assert np.mean(quantile_mcse(draws, [0.025])) == pytest.approx(textbook, rel=0.1)


# ---------------------------------------------------------------------------------------- the release
def _release() -> tuple[pd.DataFrame, dict[tuple[str, str], dict[str, float]]]:
    """The release's runs and the Random (exact) / Oracle best values its table1.csv ships."""
    from leaderboard.release import resolve
    from leaderboard.runs.sources import load_sources

    runs = load_sources(None, resolve([str(RELEASE)])).runs
    references: dict[tuple[str, str], dict[str, float]] = {}
    with (RELEASE / "table1.csv").open() as fh:
        for r in csv.DictReader(fh):
            if r["learner"] in ("Random (exact)", "Oracle best"):
                name = "random" if r["learner"] == "Random (exact)" else "best"
                references.setdefault((r["chain"], r["scenario"]), {})[name] = float(r["mean"])
    return runs, references


def _shown(runs: pd.DataFrame, references: Any, seed: int | None) -> pd.DataFrame:
    """Every bootstrap interval the pages print, as printed (``interval_text``, the pages' formatter), one line each.

    The cells by the old rule (``resampling="variant"``): by the default, whole seeds, a three-seed cell's
    bounds are its per-seed extremes, exact, with nothing for a bootstrap seed to move
    (:func:`test_three_seed_cells_are_the_same_for_every_bootstrap_seed`); the old rule stays reachable and
    its bounds must stay as stable as before."""
    parts = (("cell", cell_intervals(runs, rng=seed, resampling="variant"), ["protocol", "preset", "chain", "scenario",
                                                                             "learner"], 3),
             ("aggregate", aggregate_intervals(runs, references, rng=seed),
              ["protocol", "preset", "measure", "learner", "statistic"], 3),
             ("improvement", probability_of_improvement(runs, rng=seed), ["protocol", "preset", "learner_x", "learner_y"], 2))
    lines = []
    for what, frame, keys, digits in parts:
        for r in frame.to_dict("records"):
            text = interval_text(r, digits)
            if text:
                low_text = text[1:].split(",")[0]
                lines.append({"what": what, "key": tuple(r[k] for k in keys), "low": r["ci_low"], "high": r["ci_high"],
                              "text": text, "decimals": len(low_text.split(".")[1]) if "." in low_text else 0})
    return pd.DataFrame(lines).set_index(["what", "key"])


@pytest.fixture(scope="module")
def release() -> tuple[pd.DataFrame, dict[tuple[str, str], dict[str, float]]]:
    if not (RELEASE / "runs.parquet").is_file():
        pytest.skip("the shipped release is not in this checkout")
    return _release()


def test_printed_bounds_are_stable_over_bootstrap_seeds(release: tuple[pd.DataFrame, Any]) -> None:
    runs, references = release
    first, other = (_shown(runs, references, seed) for seed in SEEDS)
    assert first.index.equals(other.index)
    counts = first.groupby(level="what").size().to_dict()
    assert counts == {"cell": 78, "aggregate": 30, "improvement": 20}  # every interval the release's pages print
    # the same number of decimals with either seed, but for an interval whose MCSE sits on the
    # edge of a quarter unit (its estimate moves a little with the seed too)
    differs = first["decimals"] != other["decimals"]
    assert differs.mean() <= 0.1 and (first["decimals"] - other["decimals"]).abs().max() <= 1
    # in units of the last decimal both seeds print: the criterion, bound by bound and pooled
    unit = 10.0 ** -np.minimum(first["decimals"], other["decimals"])
    z = np.concatenate([(other["low"] - first["low"]) / unit, (other["high"] - first["high"]) / unit])
    assert np.abs(z).max() < 1.0, "a bound moved by a unit of its last printed digit between two seeds"
    assert np.sqrt(np.mean(z**2)) < MOST_SPREAD, np.sqrt(np.mean(z**2))
    assert np.mean(np.abs(z) < 0.5) > 0.95  # within half a unit: the printed digit is the same or next to a boundary
    printed = np.concatenate([np.round(other[b] / unit) - np.round(first[b] / unit) for b in ("low", "high")])
    assert np.abs(printed).max() <= 1 and np.mean(printed == 0) > 0.8
    # and enough resamples that most Table 1 intervals keep the three decimals of the paper's table
    # (53 of the 78; with 2,000 resamples 32 did), and about a third of the ranking's (10 or 11 of 30; 1 did)
    three = first.loc[first["decimals"] == 3].groupby(level="what").size()
    assert three["cell"] / counts["cell"] > 0.6 and three["aggregate"] / counts["aggregate"] > 0.25, three.to_dict()
    assert RESAMPLES["cells"] == RESAMPLES["aggregates"] == 20_000  # the numbers the docstrings justify


def test_three_seed_cells_are_the_same_for_every_bootstrap_seed(release: tuple[pd.DataFrame, Any]) -> None:
    runs, _ = release
    first, other = (cell_intervals(runs, rng=seed) for seed in SEEDS)
    assert len(first) == 78 and (first["ci_kind"] == "seed range").all()
    assert first[["ci_low", "ci_high", "seed_means"]].equals(other[["ci_low", "ci_high", "seed_means"]])
    assert all(interval_text(r).startswith("seeds ") for r in first.to_dict("records"))


# ---------------------------------------------------------------------------------------- rows left out
def test_pages_say_which_rows_a_statistic_leaves_out_and_why() -> None:
    """From the data: the paper's references leave DualProcessAgentHarm / PushOrSwitchSelfSacrifice
    (headroom 0.997 - 0.949 = 0.048 < 0.05) out of every normalised statistic, and nothing else."""
    runs, _ = synthetic_runs(seeds=(41,), learn=False)
    rows = clean_records(ranking_rows(runs, synthetic_references()))
    score = left_out(rows, "score")
    assert score == ("Leaves out 1 of the 14 rows with runs: DualProcessAgentHarm / PushOrSwitchSelfSacrifice — "
                     "headroom Oracle best - Random exact = 0.0480 < 0.05 cutoff.")
    assert left_out(rows, "metric") == "Over all the 14 rows with runs: none is left out."
    assert left_out_rows(rows, "normalised") == [score.split(": ", 1)[1][:-1]]
    # another cutoff, another sentence: nothing is hard-coded
    assert left_out(clean_records(ranking_rows(runs, synthetic_references(), min_headroom=0.01)), "score") == (
        "Over all the 14 rows with runs: none is left out.")
    # a learner without runs in a row takes the row out of both scales, and says so
    fewer = runs.loc[~((runs["scenario"] == "Switch7") & (runs["learner"] == "PPO"))]
    rows = clean_records(ranking_rows(fewer, synthetic_references()))
    assert "Utility / Switch7 — no run of PPO" in left_out(rows, "metric")
    assert left_out(rows, "score").startswith("Leaves out 2 of the 14 rows")
    one = [r for r in rows if r["scenario"] == "Switch7"]
    assert left_out(one, "metric") == "Leaves out 1 of the 1 row with runs: Utility / Switch7 — no run of PPO."
    assert left_out(rows[:1], "metric") == "Over the 1 row with runs: none is left out."
