"""Table 1's cells as the reproduction page judges them: each learner cell's numbers beside the
paper's value, and a verdict by one stated rule (:data:`RULE`).

Why its own module: the paper-protocol table, the corrected-protocol comparison
(:mod:`leaderboard.judging.protocol_change`) and the checks of the paper's claims all judge the same cells
the same way; the rule and the cell model live once, below all of them.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from leaderboard.outputs.tables import interval_text
from leaderboard.runs.aggregate import Group, Leaderboard, learner_order, paper_rows, paper_values
from leaderboard.stats.cells import BORDERLINE_MCSE, PAPER_ROUNDING, SEED_RANGE, at_bound
from leaderboard.stats.core import fewest_units_for_interval
from morality_gym.baselines.specs import learner_spec, trains_alike

#: The learners of Table 1 by their names in conf/algo (the page speaks of their labels).
TABLE1_LEARNERS = ("random", "ppo", "ppo_shaped", "ppo_lag", "cpo")
PAPER = Group("paper", "paper")
CORRECTED = Group("corrected", "paper")
#: The rule, as printed on the page.
RULE = ("**reproduces**: the paper's value (printed to three decimals, so ±0.0005) meets our 95% bootstrap interval "
        "of the cell mean, which resamples whole seeds (each with all its variants: they share the seed's random streams); "
        f"with fewer than {fewest_units_for_interval()} seeds such a bootstrap has too few distinct resamples to be an "
        "interval, and the cell's bounds are then the lowest and the highest of its per-seed means, printed as those "
        "values (\"seeds a, b, c\"), so \"reproduces\" reads: the paper's value lies within the range of our seeds "
        "(an interval's bounds are unrounded; the table prints each to the decimals it is stable to over bootstrap "
        "seeds, three or fewer); **close**: it does not, but lies within two seed standard deviations of our mean; "
        "**deviates**: farther; **not run**: the cell lacks runs (no verdict on a partial cell). A verdict marked "
        f"**(borderline)** has the paper's value within {BORDERLINE_MCSE:g} Monte Carlo standard errors of a bound: "
        "another bootstrap seed could turn \"reproduces\" into \"close\" or back.")
#: The rule under ``resampling="variant"`` (the rule before issue 48, for comparison pages only).
VARIANT_RULE = RULE.replace("which resamples whole seeds (each with all its variants: they share the seed's random "
                            "streams)", "which resamples each variant's seeds on their own (the rule before issue 48, "
                            "kept for comparison: it treats a seed's variants as independent)")
VERDICTS = ("reproduces", "close", "deviates", "not run")
#: A cell's place in Table 1: (chain, scenario, learner label).
CellKey = tuple[str, str, str]


@dataclass(frozen=True)
class Cell:
    """One learner cell of Table 1 with its numbers and verdict."""

    chain: str
    scenario: str
    learner: str
    mean: float
    ci_low: float
    ci_high: float
    sd: float
    n_runs: int
    n_expected: int
    paper: float
    verdict: str
    ci_low_mcse: float = math.nan  # Monte Carlo standard error of each bound: how many decimals it is printed with
    ci_high_mcse: float = math.nan
    ci_kind: str = ""  # "bootstrap", or "seed range" (too few seeds for an interval: the bounds are the per-seed extremes)
    seed_means: str = ""  # the per-seed means, ";"-separated, seed order

    @property
    def seed_range(self) -> bool:
        """Whether the bounds are the range of the per-seed means rather than a bootstrap interval."""
        return self.ci_kind == SEED_RANGE

    @property
    def borderline(self) -> bool:
        """Whether the verdict's reproduces-or-not hinges on the bootstrap seed (:func:`~leaderboard.stats.cells.at_bound`)."""
        return self.verdict != "not run" and at_bound(self.paper, self.ci_low, self.ci_high, self.ci_low_mcse,
                                                      self.ci_high_mcse)

    @property
    def verdict_text(self) -> str:
        """The verdict, with " (borderline)" when :attr:`borderline`."""
        return self.verdict + (" (borderline)" if self.borderline else "")

    @property
    def key(self) -> CellKey:
        return (self.chain, self.scenario, self.learner)

    def interval(self) -> str:
        """``[low, high]``, each bound to the decimals it is stable to (at most three); the per-seed means where
        too few seeds make no interval (``seeds a, b, c``); or a dash."""
        return interval_text({"ci_low": self.ci_low, "ci_high": self.ci_high, "ci_low_mcse": self.ci_low_mcse,
                              "ci_high_mcse": self.ci_high_mcse, "ci_kind": self.ci_kind,
                              "seed_means": self.seed_means}) or "—"


def verdict(mean: float, low: float, high: float, sd: float, paper: float, complete: bool) -> str:
    """The cell's verdict under :data:`RULE`."""
    if not complete or math.isnan(mean):
        return "not run"
    slack = PAPER_ROUNDING + 1e-12
    if not math.isnan(low) and low - slack <= paper <= high + slack:
        return "reproduces"
    if not math.isnan(sd) and abs(mean - paper) <= 2 * sd + slack:
        return "close"
    return "deviates"


def count_verdicts(judged: Iterable[Cell]) -> dict[str, int]:
    """How many of ``judged`` got each verdict, every verdict of :data:`VERDICTS` present."""
    verdicts = [c.verdict for c in judged]
    return {v: verdicts.count(v) for v in VERDICTS}


def _num(value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        return math.nan
    return out


def cells(lb: Leaderboard, group: Group) -> list[Cell]:
    """Every (chain, scenario, learner) of the paper's Table 1 in ``group``, in the paper's order."""
    table = lb.table.loc[(lb.table["protocol"] == group.protocol) & (lb.table["preset"] == group.preset)
                         & (lb.table["kind"] == "learner")]
    paper = paper_values()
    out = []
    for chain, scenario in paper_rows():
        for learner in learner_order(paper[(chain, scenario)]):
            row = table.loc[(table["chain"] == chain) & (table["scenario"] == scenario) & (table["learner"] == learner)]
            r = row.iloc[0].to_dict() if len(row) else {}
            mean, low, high, sd = (_num(r.get(k)) for k in ("mean", "ci_low", "ci_high", "std"))
            value = paper[(chain, scenario)][learner]
            complete = bool(r.get("complete", False))
            out.append(Cell(chain, scenario, learner, mean, low, high, sd, int(_num(r.get("n_runs")) or 0) if r else 0,
                            int(_num(r.get("n_expected")) or 0) if r else 0, value,
                            verdict(mean, low, high, sd, value, complete),
                            _num(r.get("ci_low_mcse")), _num(r.get("ci_high_mcse")), str(r.get("ci_kind") or ""),
                            str(r.get("seed_means") or "")))
    return out


def protocol_neutral_learners() -> list[str]:
    """The labels of Table 1's learners that train identically under both protocols: the corrected
    protocol (conf/protocol/corrected.yaml) overrides nothing of theirs, and Random's evaluation is
    not among them (its final evaluation's random stream is a protocol setting). Their corrected
    cells are their paper-protocol cells, so the corrected sweep does not run them again."""
    return [learner_spec(name).label for name in TABLE1_LEARNERS if trains_alike(name, ("paper", "corrected"))]


@dataclass(frozen=True)
class Judgement:
    """Table 1 judged under both protocols, and the learners the corrected protocol leaves alone.

    Why one object, built once per page by :func:`judge`: the reproduction page asks about the same
    cells in a dozen places (the table, each diagnosis, the protocol comparison, the claims). Judged
    once, every place reads the same cells, and the page is not rebuilt from the table (and the
    learners' configs re-read) per question: that took 12 of the page's 20 seconds."""

    paper: tuple[Cell, ...]
    corrected: tuple[Cell, ...]
    #: The labels of :func:`protocol_neutral_learners`.
    neutral: tuple[str, ...]

    def cells(self, group: Group) -> tuple[Cell, ...]:
        """``group``'s cells in the paper's order."""
        if group == PAPER:
            return self.paper
        if group == CORRECTED:
            return self.corrected
        raise ValueError(f"no Table 1 is judged for {group}")

    def cell(self, group: Group, key: CellKey) -> Cell | None:
        """One cell of ``group``, or None when Table 1 has no such cell."""
        return next((c for c in self.cells(group) if c.key == key), None)

    def as_run(self, group: Group) -> dict[CellKey, Cell]:
        """``group``'s cells by key; under the corrected protocol a protocol-neutral learner's cells
        are its paper-protocol ones (it trains identically, so the corrected sweep does not run it)."""
        out = {c.key: c for c in self.cells(group)}
        if group != PAPER:
            out.update({c.key: c for c in self.paper if c.learner in self.neutral})
        return out

    def rerun(self) -> list[Cell]:
        """The corrected protocol's own cells: those of the learners it runs again."""
        return [c for c in self.corrected if c.learner not in self.neutral]


def judge(lb: Leaderboard) -> Judgement:
    """Judge ``lb``'s Table 1 under both protocols (:func:`cells`), once."""
    return Judgement(tuple(cells(lb, PAPER)), tuple(cells(lb, CORRECTED)), tuple(protocol_neutral_learners()))
