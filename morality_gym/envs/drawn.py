"""A batched simulator whose copies draw a new dilemma at every episode: the training mixture.

The generalisation track trains one policy on a pool of dilemmas (the train split under a chain),
each episode a dilemma drawn by the run's own stream. :class:`DrawnBatchedTrolleyEnv` does that for
many copies at once: it loads the tables of every graph of the pools once
(:class:`~morality_gym.envs.mixed.MixedBatchedTrolleyEnv`), and each time a copy restarts (a reset,
or the same-step auto-reset after an episode ends) it moves the copy to the start state of the next
graph of its stream. A step stays the same few gathers over all copies.

**Streams.** Copies come in blocks of ``copies_per_stream``: block ``s`` is stream ``s`` (in a
fleet: run ``s``'s copies), with its own pool and seed. Draw ``j`` of stream ``s`` (counting from 0,
over the stream's restarts in step order and, within a step, in copy order) is entry
``splitmix64(splitmix64(seed) + (j + 1) * 0x9E3779B97F4A7C15) mod len(pool)`` of its pool: a
function of the stream's seed and its own history only, so a run draws the same dilemmas whatever
other runs share its simulator (tested), and a checkpoint keeps one counter per stream. The modulo
bias is below ``len(pool) / 2**64``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Final

import numpy as np

from morality_gym.constants import MAX_STEPS
from morality_gym.envs.mixed import MixedBatchedTrolleyEnv
from morality_gym.envs.registry import canonical_env_id

_GOLDEN: Final = np.uint64(0x9E3779B97F4A7C15)
_MIX1: Final = np.uint64(0xBF58476D1CE4E5B9)
_MIX2: Final = np.uint64(0x94D049BB133111EB)


def _splitmix(z: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser on a uint64 array (wrapping arithmetic)."""
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


def stream_keys(seeds: Sequence[int]) -> np.ndarray:
    """Each stream's key: SplitMix64 of its seed (modulo 2**64)."""
    return _splitmix(np.array([int(s) % 2**64 for s in seeds], dtype=np.uint64))


def draw_entries(keys: np.ndarray, draws: np.ndarray, pool_sizes: np.ndarray) -> np.ndarray:
    """Pool entries of draw numbers ``draws`` of streams with ``keys`` (arrays of one length; the
    pools have ``pool_sizes`` entries)."""
    with np.errstate(over="ignore"):
        z = keys + (np.asarray(draws, dtype=np.uint64) + np.uint64(1)) * _GOLDEN
        return (_splitmix(z) % np.asarray(pool_sizes, dtype=np.uint64)).astype(np.int64)


def _check_streams(pools: Sequence[Sequence[str]], copies_per_stream: int, seeds: Sequence[int]) -> None:
    """Refuse streams that cannot be drawn from: an empty pool, a seed missing, no copies."""
    if not pools or any(len(p) == 0 for p in pools):
        raise ValueError("every stream needs a pool of at least one env id")
    if len(seeds) != len(pools):
        raise ValueError(f"one seed per stream: {len(pools)} pools, {len(seeds)} seeds")
    if not isinstance(copies_per_stream, int) or copies_per_stream < 1:
        raise ValueError(f"copies_per_stream must be a positive int, got {copies_per_stream!r}")


class DrawnBatchedTrolleyEnv(MixedBatchedTrolleyEnv):
    """``len(pools) * copies_per_stream`` copies; stream ``s`` (copies ``s * copies_per_stream`` on)
    draws its episodes' env ids from ``pools[s]`` with seed ``seeds[s]`` (module docstring).

    :attr:`copy_entry` is each copy's entry in its stream's pool for the current episode (what a
    per-dilemma cost reads); :attr:`copy_graph` its graph's index into :attr:`unique_env_ids`.
    ``table_cache``: a folder keeping the pools' tables between processes (:mod:`.table_cache`)."""

    def __init__(
        self,
        pools: Sequence[Sequence[str]],
        copies_per_stream: int,
        seeds: Sequence[int],
        *,
        max_steps: int | None = MAX_STEPS,
        obs_type: str = "compact",
        obs_dtype: type = np.float32,
        table_cache: Path | None = None,
    ) -> None:
        _check_streams(pools, copies_per_stream, seeds)
        canonical = [[canonical_env_id(e) for e in pool] for pool in pools]
        graphs = list(dict.fromkeys(e for pool in canonical for e in pool))
        first = [pool[0] for pool in canonical for _ in range(copies_per_stream)]
        self.n_streams = len(pools)
        self.copies_per_stream = copies_per_stream
        self.seeds = [int(s) for s in seeds]
        self.pools = canonical
        self._drawing = False  # no draw while the base class builds (its reset-free __init__ sets the starts)
        super().__init__(first, max_steps=max_steps, obs_type=obs_type, obs_dtype=obs_dtype, graphs=graphs,
                         table_cache=table_cache)
        self._index_pools()
        #: Draws made so far per stream (the next draw's number).
        self.draws = np.zeros(self.n_streams, dtype=np.int64)
        self.copy_entry = np.zeros(self.num_envs, dtype=np.int64)
        self._drawing = True

    def _index_pools(self) -> None:
        """Each pool as graph indices, flattened with offsets, so a draw is one gather for every copy."""
        index = {e: g for g, e in enumerate(self.unique_env_ids)}
        #: Per stream: its pool's entries as graph indices.
        self.pool_graphs = [np.array([index[e] for e in pool], dtype=np.int32) for pool in self.pools]
        self.stream_of_copy = np.repeat(np.arange(self.n_streams), self.copies_per_stream)
        self._keys = stream_keys(self.seeds)
        self._pool_sizes = np.array([len(p) for p in self.pool_graphs], dtype=np.int64)
        self._pool_offsets = np.concatenate([[0], np.cumsum(self._pool_sizes)[:-1]]).astype(np.int64)
        self._pool_flat = np.concatenate(self.pool_graphs)

    def _redraw(self, mask: np.ndarray | None) -> None:
        if not self._drawing:
            return
        chosen = np.ones(self.num_envs, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        per_stream = chosen.reshape(self.n_streams, self.copies_per_stream)
        counts = per_stream.sum(axis=1)
        # draw number of each chosen copy: its stream's counter plus its rank among the stream's chosen copies
        ranks = np.cumsum(per_stream, axis=1) - 1
        streams = self.stream_of_copy[chosen]
        numbers = self.draws[streams] + ranks.reshape(-1)[chosen]
        entries = draw_entries(self._keys[streams], numbers, self._pool_sizes[streams])
        self.copy_entry[chosen] = entries
        self.copy_graph[chosen] = self._pool_flat[self._pool_offsets[streams] + entries]
        self.draws += counts
        self._start[chosen] = self.graph_offsets[self.copy_graph[chosen]]

    def current_env_ids(self) -> list[str]:
        """Each copy's env id in its current episode."""
        return [self.unique_env_ids[g] for g in self.copy_graph]

    def state_dict(self) -> dict[str, np.ndarray]:
        """The base's state plus each copy's current pool entry and each stream's draw counter."""
        return {**super().state_dict(), "entry": self.copy_entry.copy(), "draws": self.draws.copy()}

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        entry = np.asarray(state["entry"], dtype=np.int64)
        draws = np.asarray(state["draws"], dtype=np.int64)
        if entry.shape != self.copy_entry.shape or draws.shape != self.draws.shape:
            raise ValueError(f"drawn simulator: expected {self.num_envs} entries and {self.n_streams} counters, got "
                             f"{entry.shape} and {draws.shape}")
        sizes = self._pool_sizes[self.stream_of_copy]
        if (entry < 0).any() or (entry >= sizes).any() or (draws < 0).any():
            raise ValueError("drawn simulator: a pool entry or draw counter out of range")
        graph = self._pool_flat[self._pool_offsets[self.stream_of_copy] + entry].astype(np.int32)
        super().load_state_dict(state)
        self.copy_entry, self.draws, self.copy_graph = entry.copy(), draws.copy(), graph
        self._start = self.graph_offsets[graph].astype(np.int32)

    def __repr__(self) -> str:
        return (f"<DrawnBatchedTrolleyEnv {self.n_streams} streams x{self.copies_per_stream}, "
                f"{len(self.unique_env_ids)} graphs, max_steps={self.max_steps}>")
