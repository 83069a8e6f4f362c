"""What a fleet's training checkpoint is made of, apart from the trainer that writes it.

A fleet's state is the sum of its parts' ``state_dict()`` (networks, optimisers, random streams,
rollout collector, evaluations, counters); this module holds what they share: the error for a state
of another fleet, and the conversion of diagnostics rows into plain data that
``torch.load(weights_only=True)`` reads back. :mod:`.checkpoint` writes and reads the files.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np


class CheckpointMismatch(ValueError):
    """A saved training state that belongs to another fleet (learner, runs, budget, device...)."""


class NonFiniteTraining(ArithmeticError):
    """One run of a fleet whose training went non-finite: that run's failure, not its fleet's."""


def key_difference(mine: dict[str, Any], theirs: Any) -> str:
    """The first field in which a saved checkpoint key differs from this fleet's, in words."""
    if not isinstance(theirs, dict):
        return "the file holds no fleet checkpoint key"
    for key, value in mine.items():
        if theirs.get(key) != value:
            return f"{key} differs (saved {theirs.get(key)!r}, this fleet {value!r})"
    return f"saved fields {sorted(set(theirs) - set(mine))} are unknown here"


def plain_data(value: Any) -> Any:
    """``value`` (dicts, lists, scalars, as diagnostics and evaluation rows hold them) with numpy
    scalars as Python scalars and tuples as lists, which ``torch.load(weights_only=True)`` reads back.
    Exact: a float64 is a Python float, an integer an int."""
    if isinstance(value, dict):
        return {k: plain_data(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, deque)):
        return [plain_data(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value
