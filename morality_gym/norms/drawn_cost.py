"""The step-wise cost of copies that draw a new dilemma every episode (the track's training mixture).

A cost's normalisation belongs to the env id it is bound to (per-variant bounds, evaluation spec
section 5): a copy of :class:`~morality_gym.envs.drawn.DrawnBatchedTrolleyEnv` that moves to another
dilemma must be costed with that dilemma's bound chain from its first step on. :class:`DrawnCost`
keeps one row of cost terms per pool entry (a :class:`~morality_gym.norms.cost.StackedCost` over the
entries) and a per-copy :class:`StackedCost` whose columns are the rows of the copies' current
entries: copied in when a copy starts an episode, so a step costs exactly what
:class:`~morality_gym.norms.cost.VectorCost` of the copy's current bound chain charges (tested), at
the stacked cost's speed.

The memory of charged events is cleared at every episode end: each episode is another dilemma, and
a first violation in one says nothing about the next (the ``never`` reset policy of the paper's
single-env PPO-Lag and CPO runs has no meaning here; docs/protocols.md).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from morality_gym.norms.cost import CostMode, StackedCost, VectorCost
from morality_gym.norms.metric import BoundChain


class DrawnCost:
    """Costs of ``n_copies`` copies, copy ``i`` under ``entries[copy_entry[i]]`` (see the module docstring)."""

    def __init__(self, entries: Sequence[BoundChain], n_copies: int, *, mode: CostMode = "minimal",
                 scale: float = 1.0) -> None:
        if not entries:
            raise ValueError("DrawnCost needs at least one bound chain")
        groups = [(np.array([row]), VectorCost(bound, 1, mode=mode, scale=scale, reset="per_episode"))
                  for row, bound in enumerate(entries)]
        table = StackedCost.of_groups(groups, len(entries))
        if table is None:
            raise ValueError("a prescribed norm (charged at an episode's end) is not supported on the drawn mixture")
        self.table = table
        self.entries = list(entries)
        self.rows = np.zeros(n_copies, dtype=np.int64)
        self.copies = table.gathered(self.rows)

    def assign(self, mask: np.ndarray, rows: np.ndarray) -> None:
        """Copies where ``mask`` is true start an episode under entries ``rows`` (one per copy, all
        copies' rows given; only the masked ones are read). Their charged memory is cleared."""
        mask = np.asarray(mask, dtype=bool)
        chosen = np.asarray(rows, dtype=np.int64)[mask]
        self.rows[mask] = chosen
        for name in StackedCost.COLUMNS_1D:
            getattr(self.copies, name)[mask] = getattr(self.table, name)[chosen]
        for name in StackedCost.COLUMNS_2D:
            getattr(self.copies, name)[:, mask] = getattr(self.table, name)[:, chosen]
        self.copies.charged[mask] = 0

    def __call__(self, events: np.ndarray, utility: np.ndarray, ended: np.ndarray) -> np.ndarray:
        """Costs of one step of every copy, each under its current entry's bound chain."""
        return self.copies(events, utility, ended)

    def state_dict(self) -> dict[str, np.ndarray]:
        """The charged memory and each copy's entry (the columns follow from the entries)."""
        return {"charged": self.copies.charged.copy(), "rows": self.rows.copy()}

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        rows = np.asarray(state["rows"], dtype=np.int64)
        if rows.shape != self.rows.shape or (rows < 0).any() or (rows >= len(self.entries)).any():
            raise ValueError(f"drawn cost rows: expected {self.rows.shape} entries in 0..{len(self.entries) - 1}")
        self.assign(np.ones(len(rows), dtype=bool), rows)
        self.copies.load_state_dict({"charged": state["charged"]})

