"""What the runs of one Table 1 cell say beyond its mean: the reachable range on its variants, its
learning curve and what its constrained learner did at each update.

Why its own module: the reproduction page's evidence for a cell that misses the paper and the
corrected protocol's comparison read the same facts from the same runs; they are read once, here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import pandas as pd

from leaderboard.runs.aggregate import Group, Leaderboard
from leaderboard.runs.sources import Sources


def reference_over(lb: Leaderboard, chain: str, scenario: str, variants: Sequence[str]) -> dict[str, dict[str, float]]:
    """Per variant: exact Random, oracle best and worst (``lb.reference``), for the variants a cell covers."""
    for entry in lb.reference.values():
        if entry.get("chain") == chain and entry.get("scenario") == scenario:
            per = entry.get("variants", {})
            return {v: {"random": per[v]["random_exact"], "best": per[v]["oracle_best"], "worst": per[v]["oracle_worst"]}
                    for v in variants if v in per}
    return {}


def variant_records(lb: Leaderboard, group: Group, chain: str, scenario: str, learner: str) -> pd.DataFrame:
    """The cell's rows of ``lb.variants``: one per variant, with its mean over seeds and its runs' ids."""
    v = lb.variants
    return v.loc[(v["protocol"] == group.protocol) & (v["preset"] == group.preset) & (v["chain"] == chain)
                 & (v["scenario"] == scenario) & (v["learner"] == learner)]


def curve_summary(learn: pd.DataFrame, run_ids: Sequence[str]) -> tuple[list[tuple[int, float]], float] | None:
    """The mean learn-time metric of the runs at each evaluation step, and its gain over the last
    quarter of training (how much the curve still rose when training stopped)."""
    part = learn.loc[learn["run_id"].isin(run_ids)]
    if part.empty:
        return None
    column = "exact_metric" if "exact_metric" in part and part["exact_metric"].notna().any() else "metric"
    curve = part.groupby("step")[column].mean().sort_index()
    steps = curve.index.to_numpy()
    last = steps[-1]
    before = curve.loc[steps[steps <= 0.75 * last]]
    gain = float(curve.iloc[-1] - before.iloc[-1]) if len(before) else math.nan
    return [(int(s), float(v)) for s, v in curve.items()], gain


@dataclass(frozen=True)
class Updates:
    """The update records of some runs, and how many updates a record stands for, per run.

    A release keeps only every Nth update (and each run's last): shares computed from it are
    estimates, and a line built from them says so, so that a release's page and a results
    directory's page may differ by a point or two without either looking wrong."""

    frame: pd.DataFrame
    #: Per run id: one record kept in how many updates (1 for a results directory).
    strides: Mapping[str, int]

    @property
    def stride(self) -> int:
        """The coarsest stride among the runs: what a share over all of them is an estimate from."""
        return max((self.strides.get(r, 1) for r in self.frame["run_id"].unique()), default=1)

    @property
    def kept(self) -> str:
        """`` (over one update in N, as the release keeps them)``, or nothing when every update is kept."""
        return f" (over one update in {self.stride}, as the release keeps them)" if self.stride > 1 else ""

    def of_runs(self, run_ids: Sequence[str]) -> Updates | None:
        """The records of ``run_ids`` only (None when none of them has any): read once for a page,
        then cut per cell or per chain."""
        part = self.frame.loc[self.frame["run_id"].isin(run_ids)]
        return Updates(part, self.strides) if len(part) else None


def read_updates(sources: Sources, run_ids: Sequence[str]) -> Updates | None:
    """The update records of ``run_ids`` (those that have any), or None when none has."""
    frames = []
    strides = {}
    for run_id in run_ids:
        side = sources.updates_of(run_id)
        if side is not None:
            frames.append(side.read())
            release = sources.release_of(run_id)
            strides[run_id] = int(release.manifest.get("updates_stride", 1)) if release is not None else 1
    if not frames:
        return None
    return Updates(pd.concat(frames, ignore_index=True), strides)


def is_cpo(updates: Updates) -> bool:
    """Whether the records are CPO's (a dual case per update) rather than PPO-Lag's."""
    return "cpo_case" in updates.frame and bool(updates.frame["cpo_case"].notna().any())


def is_ppo_lag(updates: Updates) -> bool:
    """Whether the records are PPO-Lag's (a Lagrange multiplier per update)."""
    u = updates.frame
    return not is_cpo(updates) and "lagrange_multiplier" in u and bool(u["lagrange_multiplier"].notna().any())


def cpo_case_shares(updates: Updates) -> dict[int, float]:
    """The share of updates that took each of OmniSafe's dual cases (docs/protocols.md#cpo-uses-omnisafes-dual-solution), by case number."""
    shares = updates.frame["cpo_case"].dropna().value_counts(normalize=True).sort_index()
    return {int(case): float(share) for case, share in shares.items()}


def accepted_share(updates: Updates) -> float:
    """The share of CPO updates whose line search accepted a step (the actor moved; docs/protocols.md#cpo-line-search)."""
    return float((updates.frame["accept_step"] > 0).mean())


def one_pass_share(updates: Updates) -> float:
    """The share of PPO-Lag updates that stopped after their first pass (the KL early stop, docs/protocols.md#ppo-lag-kl-early-stop-sums-over-states)."""
    u = updates.frame
    return float((u["passes"] == 1).mean()) if "passes" in u else math.nan


def mean_passes(updates: Updates) -> float:
    """PPO-Lag's mean passes over the epoch's samples per update (up to 40 when the KL never stops it)."""
    u = updates.frame
    return float(u["passes"].mean()) if "passes" in u else math.nan


def final_multipliers(updates: Updates) -> pd.Series:
    """Each run's Lagrange multiplier after its last update."""
    last = updates.frame.sort_values("update").groupby("run_id").tail(1)
    return last["lagrange_multiplier"]


def updates_summary(updates: Updates | None) -> str:
    """One line on what the constrained learner did at its updates (CPO's dual cases and accepted
    line-search steps; PPO-Lag's passes and Lagrange multiplier), over the runs; empty without records."""
    if updates is None:
        return ""
    if is_cpo(updates):
        shares = ", ".join(f"case {case} {share:.0%}" for case, share in cpo_case_shares(updates).items())
        return (f"CPO updates{updates.kept}: {shares}; a line-search step accepted in "
                f"{accepted_share(updates):.0%} of updates")
    if is_ppo_lag(updates):
        final = final_multipliers(updates)
        return (f"PPO-Lag updates{updates.kept}: {one_pass_share(updates):.0%} stopped after one pass; final Lagrange "
                f"multiplier mean {final.mean():.3f} (range {final.min():.3f}-{final.max():.3f})")
    return ""
