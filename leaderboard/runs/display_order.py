"""The order, names and colours the leaderboard shows: sweep groups (protocol, preset), the paper's rows and
learners, each chain's norms, file-name-safe identifiers (part of :mod:`leaderboard.runs.aggregate`), and
each learner's colour in every figure and page.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from functools import cache

from morality_gym.norms.chain import ChainError, get_chain
from morality_gym.paper import LEARNERS, table1
from morality_gym.results.presets import PresetError, load_preset, preset_names

#: The rows of Table 1 computed from the environments rather than from runs
#: (:func:`leaderboard.runs.reference_rows.compute_reference`).
RANDOM_EXACT, ORACLE_BEST, ORACLE_WORST = "Random (exact)", "Oracle best", "Oracle worst"
REFERENCE_LEARNERS = (RANDOM_EXACT, ORACLE_BEST, ORACLE_WORST)


# ---------------------------------------------------------------------------------------- groups
@dataclass(frozen=True, order=True)
class Group:
    """One sweep setting in a results directory: its protocol and preset."""

    protocol: str
    preset: str

    @property
    def slug(self) -> str:
        """A file-name-safe identifier, used for figure folders and HTML ids."""
        return safe_name(f"{self.protocol}-{self.preset}")

    @property
    def label(self) -> str:
        return f"protocol {self.protocol}, preset {self.preset}"


def safe_name(text: str) -> str:
    """``text`` with every character outside ``[A-Za-z0-9._-]`` replaced, for file names.

    Run ids are content hashes and scenario names identifiers, so this changes nothing for real
    data; it exists so that a hostile or odd name can never escape the output directory.
    """
    cleaned = re.sub(r"[^A-Za-z0-9._-]", "_", str(text)).lstrip(".")
    return cleaned or "_"


# ---------------------------------------------------------------------------------------- ordering
def paper_rows() -> list[tuple[str, str]]:
    """The (chain, scenario) rows of the paper's Table 1, in the paper's order."""
    return [(row.chain, row.scenario) for row in table1()]


def paper_values() -> dict[tuple[str, str], dict[str, float]]:
    """Published Table 1 numbers by (chain, scenario), then learner."""
    return {(row.chain, row.scenario): dict(row.paper) for row in table1()}


def learner_order(learners: Iterable[str]) -> list[str]:
    """The paper's learners in the paper's order, then any others alphabetically."""
    found = set(learners)
    return [name for name in LEARNERS if name in found] + sorted(found - set(LEARNERS))


def row_order(pairs: Iterable[tuple[str, str]]) -> list[tuple[str, str]]:
    """(chain, scenario) pairs: the paper's rows in its order first, then the rest sorted."""
    found = set(pairs)
    known = [pair for pair in paper_rows() if pair in found]
    return known + sorted(found - set(known))


def chain_norm_order(chain: str) -> list[str]:
    """The chain's norms, highest force first (the x axis of Figure 2); [] for an unknown chain."""
    try:
        return get_chain(chain).norm_names
    except ChainError:
        return []


@cache
def preset_rank() -> dict[str, int]:
    """The display rank of each preset of ``conf/preset``: the one that trains most first (the paper's,
    then quick, then smoke), read from the preset files; a file that does not load is left out."""
    budgets = {}
    for name in preset_names():
        try:
            budgets[name] = load_preset(name).budget
        except PresetError:
            continue
    return {name: rank for rank, name in enumerate(sorted(budgets, key=lambda n: (-budgets[n], n)))}


def group_order(groups: Iterable[Group]) -> list[Group]:
    """Protocol ``paper`` before others, then the presets of ``conf/preset`` by :func:`preset_rank`
    (paper > quick > smoke), then other presets by name."""
    rank = preset_rank()
    return sorted(set(groups), key=lambda g: (g.protocol != "paper", g.protocol, rank.get(g.preset, len(rank)), g.preset))


# ---------------------------------------------------------------------------------------- colours
#: Okabe-Ito colours (distinguishable with the common colour-vision deficiencies) for the paper's learners.
LEARNER_COLOURS = {
    "CPO": "#0072B2",
    "PPO": "#D55E00",
    "PPO Lag": "#009E73",
    "PPO Shaped": "#CC79A7",
    "Random": "#7F7F7F",
}
#: Colours for other learners, handed out in the order of :func:`learner_palette`'s argument.
EXTRA_COLOURS = ["#E69F00", "#56B4E9", "#F0E442", "#000000", "#8C564B", "#17BECF", "#BCBD22", "#9467BD"]
#: The resolution of every figure the leaderboard draws.
DPI = 120


def learner_palette(learners: Iterable[str]) -> dict[str, str]:
    """A colour per learner: the fixed ones for the paper's learners, the extras for the rest.

    Build it once from *all* learners of the results and pass it to every figure, so that an
    unknown learner gets the same colour in every plot of one build.
    """
    palette: dict[str, str] = {}
    extra = 0
    for name in learners:
        if name in LEARNER_COLOURS:
            palette[name] = LEARNER_COLOURS[name]
        else:
            palette[name] = EXTRA_COLOURS[extra % len(EXTRA_COLOURS)]
            extra += 1
    return palette
