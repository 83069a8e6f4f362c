"""A model trained on the compact observation, made to act in envs that give the flat one.

Why: a fleet trained on the generalisation track's mixture reads the compact observation
(:mod:`morality_gym.world.compact_observe`, 128 numbers) and its saved sidecar records
``obs_type: compact``. ``eval``, ``play`` and the exact evaluator feed a policy the env's *flat*
observation, whose width differs per scenario: such a model was refused there ("observation size
128"), or, were the widths equal, would have read numbers that mean something else.
:func:`~morality_gym.baselines.policy_ref.load_policy` therefore wraps it for the envs it is loaded
for: every reachable state's flat observation is mapped, once, to that state's compact
observation, and the model answers on that, exactly as the fleet's own policy does.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from morality_gym.envs.registry import state_graph
from morality_gym.evaluation.policies import PolicyAdapter
from morality_gym.world.compact_observe import compact_from_grid
from morality_gym.world.grid_observe import grid_table


def _key(row: np.ndarray) -> bytes:
    """A flat observation as a lookup key: float64, rounded (the batched envs give float32 rows)."""
    return np.asarray(row, dtype=np.float64).round(6).tobytes()


class CompactObservationPolicy:
    """``obs -> 6 action probabilities`` for the flat observations of ``env_ids``, computed by ``model``
    on the compact observation of the same state. ``model``: the SB3 model a fleet saved."""

    def __init__(self, model: Any, env_ids: Sequence[str]) -> None:
        self.model = model
        self.env_ids = tuple(env_ids)
        self._compact: dict[bytes, np.ndarray] = {}
        for env_id in self.env_ids:
            graph = state_graph(env_id)
            tables = graph.tables()  # completes the graph: every reachable state gets its id
            compact = compact_from_grid(grid_table(graph.world, list(graph.states)))
            for flat, row in zip(tables.obs, compact):
                key = _key(flat)
                seen = self._compact.setdefault(key, row)
                if not np.array_equal(seen, row):
                    raise ValueError(f"{env_id}: one flat observation stands for two states with different grids "
                                     f"among {', '.join(self.env_ids)}; evaluate the model on one env at a time")
        self._adapter = PolicyAdapter(model)

    def compact(self, obs: np.ndarray) -> np.ndarray:
        """The compact observation of the state whose flat observation is ``obs``."""
        try:
            return self._compact[_key(obs)]
        except KeyError:
            raise ValueError(f"an observation of none of the envs this model was loaded for ({', '.join(self.env_ids)}): "
                             "load it for the env it plays (load_policy(ref, env_ids))") from None

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self._adapter.probabilities(self.compact(obs)[None, :])[0]
