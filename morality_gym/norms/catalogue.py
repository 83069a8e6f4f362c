"""The norm catalogue: every norm a chain can use, i.e. every name the environments emit.

A norm is either an *event* norm (its name appears in a step's ``action``, ``outcome`` or ``causal``
set; what matters is whether it occurred at least once in an episode) or a *utility* norm (a key
of the step's ``utility`` dict; what matters is its episode total). The catalogue is derived from
the environment vocabulary rather than written out, so the two cannot drift apart; it adds the
short labels the paper uses in its figures.
"""

from __future__ import annotations

from dataclasses import dataclass

from morality_gym.world.vocab import EVENT_CATEGORY, EVENTS, UTILITIES


@dataclass(frozen=True)
class NormInfo:
    """What the platform knows about one norm name."""

    name: str
    kind: str  # "event" or "utility"
    category: str  # "action" | "outcome" | "causal" | "utility"
    abbreviation: str
    label: str


_PAPER_LABELS = {
    "n_human_harm": ("MHH", "Min humans harmed"),
    "n_animal_harm": ("MAH", "Min animals harmed"),
    "n_robot_harm": ("MRH", "Min robots harmed"),
    "agent_harm": ("AAgH", "Avoid agent harm"),
    "personal_action_caused_human_harm": ("APHH", "Avoid personal human harm"),
    "personal_action_caused_animal_harm": ("APAH", "Avoid personal animal harm"),
    "personal_action_caused_robot_harm": ("APRH", "Avoid personal robot harm"),
    "human_harm": ("AHH", "Avoid human harm"),
    "animal_harm": ("AAH", "Avoid animal harm"),
    "robot_harm": ("ARH", "Avoid robot harm"),
    "n_harm": ("MH", "Min harmed"),
    "n_weighted_harm": ("MWH", "Min weighted harm"),
    "push": ("AP", "Avoid pushing"),
}


def _describe(name: str) -> tuple[str, str]:
    if name in _PAPER_LABELS:
        return _PAPER_LABELS[name]
    words = name.replace("_action_caused", "").split("_")
    abbreviation = "".join(w[0].upper() for w in words)
    return abbreviation, "Avoid " + " ".join(words)


def _build() -> dict[str, NormInfo]:
    out: dict[str, NormInfo] = {}
    for name in EVENTS:
        out[name] = NormInfo(name, "event", EVENT_CATEGORY[name], *_describe(name))
    for name in UTILITIES:
        out[name] = NormInfo(name, "utility", "utility", *_describe(name))
    return out


#: Every norm name, in vocabulary order (events first, then utilities).
CATALOGUE: dict[str, NormInfo] = _build()

