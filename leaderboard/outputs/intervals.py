"""Table 1 with interval estimates: ``ci_low``, ``ci_high`` and the bold rule from :mod:`leaderboard.stats`.

Why a separate step: :mod:`leaderboard.runs.aggregate` makes the table and :mod:`leaderboard.stats`
imports it, so the intervals are joined onto ``Leaderboard.table`` here, after both, and every
writer (CSV, Markdown, LaTeX, site) reads the same columns.

The bold rule (one definition, :data:`leaderboard.outputs.marks.BOLD_RULE`, quoted by every output): a learner cell is bold
when it has the highest mean of its row among the *complete* learner cells and its 95% interval
overlaps the interval of no other complete learner of the row. Incomplete cells are left out of
the comparison, as before (issue 11: they are never bold and not compared with the paper). No
interval (one seed) means no bold: a single seed says nothing about seed-to-seed variation.
"""

from __future__ import annotations

from dataclasses import replace

import pandas as pd

from leaderboard.outputs.marks import BOLD_RULE, BOLD_RULE_TEX  # noqa: F401 - re-exported: tables and pages quote them
from leaderboard.runs.aggregate import Leaderboard
from leaderboard.stats import bold_cells
from leaderboard.stats.cells import at_bound

KEYS = ["protocol", "preset", "chain", "scenario", "learner"]
#: The columns this step adds to ``Leaderboard.table`` (NaN / "" / False on reference rows).
#: ``ci_low_mcse``/``ci_high_mcse``: each bound's Monte Carlo standard error, which decides how
#: many decimals it is printed with (:mod:`leaderboard.outputs.precision`).
#: ``ci_kind``/``seed_means``: whether the bounds are bootstrap quantiles or, with too few seeds for
#: an interval, the range of the per-seed means, which are then printed instead (:mod:`leaderboard.stats.cells`).
#: ``borderline``: the paper's value within Monte Carlo error of a bound (:func:`leaderboard.stats.cells.at_bound`).
COLUMNS = ["ci_low", "ci_high", "ci_low_mcse", "ci_high_mcse", "ci_kind", "seed_means", "ci_note", "borderline", "bold",
           "bold_note"]
MCSE = ["ci_low_mcse", "ci_high_mcse"]
TEXT = ["ci_kind", "seed_means"]


def with_intervals(lb: Leaderboard, cells: pd.DataFrame) -> Leaderboard:
    """``lb`` whose table carries :data:`COLUMNS`; ``cells`` = ``LeaderboardStats.cells`` (or ``cell_intervals``)."""
    table = lb.table.drop(columns=[c for c in COLUMNS if c in lb.table.columns])
    kept = [c for c in MCSE + TEXT if c in cells.columns]  # cells computed before these were kept have none
    intervals = cells[KEYS + ["ci_low", "ci_high", *kept, "ci_note"]]
    if intervals.empty:  # no usable run: the empty frame's key columns have no dtype to merge on
        table = table.assign(ci_low=float("nan"), ci_high=float("nan"), ci_note="")
    else:
        table = table.merge(intervals, on=KEYS, how="left", validate="many_to_one")
    for column in MCSE:
        if column not in table.columns:
            table[column] = float("nan")
    for column in ["ci_note", *TEXT]:
        table[column] = table[column].fillna("") if column in table.columns else ""
    learner = table["kind"] == "learner"
    complete = learner & table["complete"].astype(bool) & table["mean"].notna()
    if complete.any():
        judged = bold_cells(table.loc[complete, KEYS + ["mean", "ci_low", "ci_high", "ci_note"]])
        table["bold"] = judged["bold"].reindex(table.index, fill_value=False).astype(bool)
        table["bold_note"] = judged["bold_note"].reindex(table.index, fill_value="")
    else:
        table["bold"] = False
        table["bold_note"] = ""
    table.loc[~learner, ["ci_note", "bold_note", *TEXT]] = ""
    # only where the cell is compared with the paper at all (a delta is given: complete, the paper's budget)
    compared = table["delta"].notna() if "delta" in table.columns else pd.Series(False, index=table.index)
    paper = table["paper"].where(compared) if "paper" in table.columns else pd.Series(float("nan"), index=table.index)
    table["borderline"] = [bool(is_learner) and at_bound(*map(float, (p, lo, hi, lm, hm))) for is_learner, p, lo, hi, lm, hm
                           in zip(learner, paper, table["ci_low"], table["ci_high"], table["ci_low_mcse"], table["ci_high_mcse"])]
    return replace(lb, table=table)
