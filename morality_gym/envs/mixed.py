"""One batched simulator whose copies may run *different* env ids (variants) of one scenario.

A fleet of training runs (:mod:`morality_gym.baselines.fleet`) steps every run's copies together,
and its runs may train on different variants. :class:`BatchedTrolleyEnv` gathers from the tables
of one state graph; this subclass concatenates the tables of several graphs, shifting each graph's
state ids by its offset, so that a step is still the same few gathers over all copies whatever
their env ids: transition row ``s * 6 + a`` of global state ``s`` is the row of the same action in
the same state of the copy's own graph, because each graph's transition block starts at six times
its state offset. Each copy starts (and auto-resets) at its own graph's start state.

The copies share one observation array, so their observations must have one width: variants of
one scenario do with the flat vector; every env id does with ``obs_type="grid"`` (the fixed-shape
grid). With ``pad_obs=True`` env ids of different widths (a fleet that mixes scenarios) share it
too, each observation zero-padded on the right to the widest (:attr:`obs_dims` keeps each id's own).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from morality_gym.constants import MAX_STEPS
from morality_gym.envs.batched import AutoReset, BatchedTrolleyEnv, sim_tables
from morality_gym.envs.registry import parse_env_id
from morality_gym.envs.table_cache import SimTables
from morality_gym.world.graph import N_ACTIONS


def _canonical(env_id: str) -> str:
    scenario, variant = parse_env_id(env_id)
    return scenario.env_id(variant)


class MixedBatchedTrolleyEnv(BatchedTrolleyEnv):
    """``len(env_ids)`` copies, copy ``i`` running ``env_ids[i]``; otherwise :class:`BatchedTrolleyEnv`.

    ``env_id`` is the first copy's id (kept for code that reads it); ``env_ids`` lists every copy's.
    ``copy_graph[i]`` is the index into :attr:`unique_env_ids` of copy ``i``'s graph.
    """

    def __init__(
        self,
        env_ids: Sequence[str],
        *,
        max_steps: int | None = MAX_STEPS,
        obs_dtype: type = np.float32,
        autoreset: AutoReset = "same_step",
        normalise_obs: bool = True,
        overrides: dict | None = None,
        obs_type: str = "flat",
        pad_obs: bool = False,
        graphs: Sequence[str] | None = None,
        table_cache: Path | None = None,
    ) -> None:
        env_ids = [_canonical(e) for e in env_ids]
        if not env_ids:
            raise ValueError("MixedBatchedTrolleyEnv needs at least one env id")
        #: The graphs whose tables are loaded, in order: ``graphs`` when given (every copy's id must
        #: be one of them), else the copies' distinct env ids.
        self.unique_env_ids: list[str] = list(dict.fromkeys(env_ids if graphs is None else [_canonical(e) for e in graphs]))
        unknown = sorted(set(env_ids) - set(self.unique_env_ids))
        if unknown:
            raise ValueError(f"copies run env ids that are not among graphs: {', '.join(unknown[:3])}")
        self.env_ids = env_ids
        self._loaded: list[SimTables] = []
        # The base class validates the arguments and sets everything up for the first id (its
        # tables are the first copy's of :meth:`_first_tables`, loaded with all the others); the
        # tables are then replaced by the concatenation over all ids.
        super().__init__(
            env_ids[0], len(env_ids), max_steps=max_steps, obs_dtype=obs_dtype, autoreset=autoreset,
            normalise_obs=normalise_obs, overrides=overrides, obs_type=obs_type, table_cache=table_cache,
        )
        tables, self._loaded = self._loaded, []
        observations = [t.obs for t in tables]
        dims = {e: int(o.shape[1]) for e, o in zip(self.unique_env_ids, observations)}
        #: Each env id's own observation width (before any padding).
        self.obs_dims = dims
        if len(set(dims.values())) > 1:
            if not pad_obs:
                raise ValueError(
                    f"the copies of one simulator must share an observation size, got {dims}; "
                    "fleet only variants of one scenario together, use obs_type='grid', or pad_obs=True"
                )
            width = max(dims.values())
            observations = [np.pad(o, ((0, 0), (0, width - o.shape[1]))) for o in observations]
        offsets = np.cumsum([0] + [t.n_states for t in tables])[:-1].astype(np.int32)
        #: Each graph's first state id in the concatenated tables (its start state).
        self.graph_offsets = offsets
        self._next = np.concatenate([t.next.astype(np.int32) + off for t, off in zip(tables, offsets)])
        self._reward = np.concatenate([t.reward for t in tables]).astype(np.float32)
        self._events = np.concatenate([t.events for t in tables])
        self._done = np.concatenate([t.done for t in tables])
        self._obs = np.ascontiguousarray(np.concatenate(observations))
        self.obs_dim = self._obs.shape[1]
        self.no_transition = len(self._next)
        utility = np.concatenate([t.utility for t in tables])
        self._utility = np.vstack([utility, np.zeros((1, utility.shape[1]), dtype=utility.dtype)])
        self._goal = np.append(np.concatenate([t.goal for t in tables]), False)
        index = {e: i for i, e in enumerate(self.unique_env_ids)}
        self.copy_graph = np.array([index[e] for e in env_ids], dtype=np.int32)
        self._start = offsets[self.copy_graph].astype(np.int32)
        self.state = self._start.copy()
        assert len(self._next) == N_ACTIONS * len(self._done)

    def _first_tables(self, obs_type: str, obs_dtype: type, table_cache: Path | None) -> SimTables:
        """Every graph's tables (kept for ``__init__``); the first copy's are the base class's."""
        overrides, normalise = self._graph_args
        self._loaded = [sim_tables(e, obs_type, obs_dtype, overrides=overrides, normalise=normalise, cache_dir=table_cache)
                        for e in self.unique_env_ids]
        return self._loaded[self.unique_env_ids.index(self.env_ids[0])]

    def __repr__(self) -> str:
        return (
            f"<MixedBatchedTrolleyEnv {', '.join(self.unique_env_ids)} x{self.num_envs} "
            f"max_steps={self.max_steps} autoreset={self.autoreset}>"
        )
