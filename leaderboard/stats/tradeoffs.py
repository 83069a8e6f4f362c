"""Return versus cost, and what each learner violates: the safe-RL view of a Table 1 row.

**Points.** One per usable run: its final evaluation's mean task return and mean moral cost
(``mean_cost``: the minimal-mode step-wise cost of the run's chain, scale 1, memory reset per
episode, as the runner records it), with the metric, so a reader can see whether a learner buys
its return with cost.

**Violation rates.** Per (row, learner, norm), the mean of ``1 - M`` over the runs in which the
norm is relevant (the same runs Figure 2 pools, :func:`leaderboard.runs.aggregate.norm_long`). What
``1 - M`` means depends on the norm (evaluation spec 4.2):

* event norm: the share of evaluation episodes in which the norm was violated (a prohibited event
  occurred, or a prescribed one did not): ``measure = "violation rate"``;
* utility norm, prohibited: the episode total normalised by the variant's bounds,
  ``(u - lo) / (hi - lo)``, i.e. normalised harm (0 = the least the variant allows, 1 = the most):
  ``measure = "normalised harm"``;
* utility norm, prescribed: ``1 - (u - lo) / (hi - lo)``, the normalised shortfall:
  ``measure = "normalised shortfall"``.

Only relevant norms enter: an irrelevant norm has weight 0 in the metric and a utility norm with
equal bounds reports ``M = 1`` whatever happened, so its "rate" would be a meaningless 0.
"""

from __future__ import annotations

import pandas as pd

from leaderboard.runs.aggregate import chain_norm_order, norm_long
from leaderboard.stats.core import in_table1_order, require_columns, usable_runs
from morality_gym.norms.catalogue import CATALOGUE
from morality_gym.norms.chain import ChainError, get_chain

ROW_KEYS = ["protocol", "preset", "chain", "scenario"]
POINT_COLUMNS = ROW_KEYS + ["variant", "learner", "seed", "run_id", "mean_return", "mean_cost", "metric"]
VIOLATION, HARM, SHORTFALL = "violation rate", "normalised harm", "normalised shortfall"


def return_cost_points(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per usable run with ``mean_return``, ``mean_cost`` and ``metric`` (columns :data:`POINT_COLUMNS`).

    Runs without a finite return or cost are left out here (the run page still lists them).
    """
    ok = usable_runs(runs)
    require_columns(ok, POINT_COLUMNS, "runs", "pass Leaderboard.runs")
    points = ok[POINT_COLUMNS].copy()
    for column in ("mean_return", "mean_cost", "metric"):
        points[column] = pd.to_numeric(points[column], errors="coerce").astype(float)
    points = points.dropna(subset=["mean_return", "mean_cost"])
    return in_table1_order(points, then=["variant", "seed", "run_id"])


def _norm_meaning(chain: str, norm: str) -> tuple[str, str, str]:
    """(kind, modality, measure) of a norm in a chain; the catalogue's kind when the chain is unknown."""
    try:
        entry = get_chain(chain).norm(norm)
        kind, modality = entry.kind, entry.modality
    except (ChainError, KeyError, ValueError):
        info = CATALOGUE.get(norm)
        kind, modality = (info.kind if info else "unknown"), "unknown"
    if kind == "event":
        return kind, modality, VIOLATION
    if kind == "utility":
        return kind, modality, SHORTFALL if modality == "prescribed" else HARM
    return kind, modality, "1 - M"


def violation_rates(runs: pd.DataFrame) -> pd.DataFrame:
    """Mean ``1 - M`` per (protocol, preset, chain, scenario, learner, norm) over runs where the norm is relevant.

    Columns: protocol, preset, chain, scenario, learner, norm, kind (event | utility), modality
    (prohibited | prescribed), measure (see the module docstring), value, n_runs, rank (the
    norm's position in its chain, highest force first).
    """
    ok = usable_runs(runs)
    require_columns(ok, ROW_KEYS + ["variant", "learner", "seed", "run_id", "relevant_norms"], "runs",
                    "pass Leaderboard.runs")
    long = norm_long(ok)
    columns = ROW_KEYS + ["learner", "norm", "kind", "modality", "measure", "value", "n_runs", "rank"]
    if long.empty:
        return pd.DataFrame(columns=columns)
    long["violation"] = 1.0 - long["value"].astype(float)
    frame = long.groupby(ROW_KEYS + ["learner", "norm"], sort=True).agg(value=("violation", "mean"),
                                                                         n_runs=("violation", "size")).reset_index()
    meanings = {(c, n): _norm_meaning(c, n) for c, n in set(zip(frame["chain"], frame["norm"]))}
    frame["kind"] = [meanings[(c, n)][0] for c, n in zip(frame["chain"], frame["norm"])]
    frame["modality"] = [meanings[(c, n)][1] for c, n in zip(frame["chain"], frame["norm"])]
    frame["measure"] = [meanings[(c, n)][2] for c, n in zip(frame["chain"], frame["norm"])]
    orders = {chain: chain_norm_order(chain) for chain in frame["chain"].unique()}
    frame["rank"] = [orders[c].index(n) if n in orders[c] else len(orders[c]) for c, n in zip(frame["chain"], frame["norm"])]
    frame = in_table1_order(frame, then=["rank", "norm"])
    return frame[columns]
