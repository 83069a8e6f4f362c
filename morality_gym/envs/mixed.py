"""One batched simulator whose copies may run *different* env ids (variants, or scenarios).

A fleet of training runs (:mod:`morality_gym.baselines.fleet`) steps every run's copies together,
and its runs may train on different variants. :class:`BatchedTrolleyEnv` is built for that general
case (its :meth:`~BatchedTrolleyEnv._build` lays the tables of several graphs end to end, shifting
each graph's state ids by its offset, so that a step is still the same few gathers over all copies
whatever their env ids: transition row ``s * 6 + a`` of global state ``s`` is the row of the same
action in the same state of the copy's own graph); a simulator of one env id is a mixture of one.
This subclass only takes one env id per copy. Each copy starts (and auto-resets) at its own
graph's start state.

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
from morality_gym.envs.batched import AutoReset, BatchedTrolleyEnv


class MixedBatchedTrolleyEnv(BatchedTrolleyEnv):
    """``len(env_ids)`` copies, copy ``i`` running ``env_ids[i]``; otherwise :class:`BatchedTrolleyEnv`.

    ``env_id`` is the first copy's id (kept for code that reads it); ``env_ids`` lists every copy's.
    ``copy_graph[i]`` is the index into :attr:`unique_env_ids` of copy ``i``'s graph. ``graphs``:
    the env ids whose tables are loaded (default: the copies'), for copies that move to other
    graphs later (:class:`~morality_gym.envs.drawn.DrawnBatchedTrolleyEnv`).
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
        if isinstance(env_ids, str) or not env_ids:
            raise ValueError("MixedBatchedTrolleyEnv needs at least one env id")
        self._build(env_ids, max_steps=max_steps, obs_dtype=obs_dtype, autoreset=autoreset, normalise_obs=normalise_obs,
                    overrides=overrides, obs_type=obs_type, table_cache=table_cache, pad_obs=pad_obs, graphs=graphs)

    def __repr__(self) -> str:
        return (
            f"<MixedBatchedTrolleyEnv {', '.join(self.unique_env_ids)} x{self.num_envs} "
            f"max_steps={self.max_steps} autoreset={self.autoreset}>"
        )
