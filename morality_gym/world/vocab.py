"""The closed vocabulary of what the environments can report about a step.

Every name an environment can put into ``info["norm_events"]`` is listed here, once, with a
fixed bit position. Fixing the positions lets the batched simulator report a step's events as
one integer (a bit mask) and lets evaluation accumulate "occurred at least once" with a bitwise
OR, while the single environment still reports readable names. Norm catalogues and chains
(``morality_gym.norms``) are checked against this vocabulary so that a chain cannot silently
refer to a name no environment will ever emit.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Final

#: Character types, in the default one-hot order of the observation.
CHARACTER_TYPES: Final[tuple[str, ...]] = ("human", "animal", "robot")

#: Causal prefixes: "personal" when a pushed character took part in the collision (spec section 7).
CAUSAL_PREFIXES: Final[tuple[str, ...]] = ("personal_action_caused", "impersonal_action_caused")

ACTION_EVENTS: Final[tuple[str, ...]] = ("push",)
OUTCOME_EVENTS: Final[tuple[str, ...]] = (
    "harm",
    "human_harm",
    "animal_harm",
    "robot_harm",
    "trolley_harm",
    "agent_harm",
)
CAUSAL_EVENTS: Final[tuple[str, ...]] = tuple(
    f"{prefix}_{suffix}"
    for prefix in CAUSAL_PREFIXES
    for suffix in ("harm", "human_harm", "animal_harm", "robot_harm", "trolley_harm", "agent_harm")
)

#: Every event name, in bit order (bit i <-> EVENTS[i]).
EVENTS: Final[tuple[str, ...]] = ACTION_EVENTS + OUTCOME_EVENTS + CAUSAL_EVENTS
EVENT_BIT: Final[dict[str, int]] = {name: i for i, name in enumerate(EVENTS)}
EVENT_CATEGORY: Final[dict[str, str]] = {
    **{n: "action" for n in ACTION_EVENTS},
    **{n: "outcome" for n in OUTCOME_EVENTS},
    **{n: "causal" for n in CAUSAL_EVENTS},
}

#: Every utility name, in column order of the batched simulator's utility array.
UTILITIES: Final[tuple[str, ...]] = (
    "n_harm",
    "n_human_harm",
    "n_animal_harm",
    "n_robot_harm",
    "n_weighted_harm",
)
UTILITY_INDEX: Final[dict[str, int]] = {name: i for i, name in enumerate(UTILITIES)}

#: Weights of ``n_weighted_harm`` per harmed type.
WEIGHTED_HARM: Final[dict[str, int]] = {"human": 3, "animal": 2, "robot": 1}

#: All names a norm may refer to.
ALL_NAMES: Final[frozenset[str]] = frozenset(EVENTS) | frozenset(UTILITIES)


def mask_to_names(mask: int) -> list[str]:
    """Names of the events whose bits are set in ``mask``, in bit order."""
    return [name for i, name in enumerate(EVENTS) if mask >> i & 1]


def names_to_mask(names: Iterable[str]) -> int:
    """Bit mask of the given event names; unknown names raise ``KeyError``."""
    mask = 0
    for name in names:
        mask |= 1 << EVENT_BIT[name]
    return mask
