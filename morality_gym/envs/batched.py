"""The batched simulator: N copies of one environment stepped with numpy arrays in and out.

Every copy of an env id walks the same enumerated state graph, so stepping all of them is a few
array gathers: ``next_state = table[state * 6 + action]``. Observations, rewards and flags are
gathered the same way, and a step's norm events come back as bit masks over
:data:`morality_gym.world.vocab.EVENTS`. This is the engine behind the Gymnasium ``VectorEnv``
and the SB3 ``VecEnv`` in :mod:`morality_gym.envs.vector`, and it reproduces the single
environment step for step (tested), including truncation on step ``max_steps + 1``.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np

from morality_gym.constants import MAX_STEPS
from morality_gym.envs.registry import canonical_env_id, parse_env_id, state_graph
from morality_gym.envs.table_cache import CACHED_OBS_TYPES, SimTables, entry_key, read_entry, write_entry
from morality_gym.envs.trolley import _overrides
from morality_gym.world.compact_observe import compact_from_grid
from morality_gym.world.graph import N_ACTIONS, StateGraph
from morality_gym.world.grid_observe import grid_table
from morality_gym.world.rules import Overrides
from morality_gym.world.vocab import EVENT_BIT

AutoReset = Literal["same_step", "disabled"]
#: What the simulators' observation rows hold: the scenario's flat vector, or the fixed-shape grid
#: (:mod:`morality_gym.world.grid_observe`) flattened in C order, the same length for every scenario,
#: or the compact observation (:mod:`morality_gym.world.compact_observe`): the grid's facts in 128 numbers.
BATCHED_OBS_TYPES = ("flat", "grid", "compact")

#: Event bits that make the utility keys present (:func:`utility_present`). Plain ints, so that the same
#: test works on numpy's uint32 masks and on torch's int64 ones (:mod:`morality_gym.envs.torch_sim`).
HARM_BIT = 1 << EVENT_BIT["harm"]
LIVING_BITS = sum(1 << EVENT_BIT[n] for n in ("human_harm", "animal_harm", "robot_harm"))


class BatchStep(NamedTuple):
    """What one batched step returns; all arrays have length ``num_envs``.

    ``transition`` is the row of each copy's transition, so callers can gather more
    (:meth:`BatchedTrolleyEnv.utility`, :meth:`BatchedTrolleyEnv.goal_reached`) only when they need
    it; a copy that had already ended (auto-reset disabled) gets :attr:`BatchedTrolleyEnv.NO_TRANSITION`
    semantics: the row of an empty transition (no utility, no landmark).
    ``final_obs`` holds the last observation of the copies that ended in this step (zeros
    elsewhere) when auto-reset is on, and is ``None`` otherwise.
    """

    obs: np.ndarray
    reward: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    events: np.ndarray
    transition: np.ndarray
    final_obs: np.ndarray | None


#: Each live graph's compact table: the track's fleets build one simulator per learner on the same
#: pool (hundreds of thousands of states), and encoding every state's grid again cost a minute each.
_COMPACT_TABLES: weakref.WeakKeyDictionary[StateGraph, tuple[tuple[int, str], np.ndarray]] = weakref.WeakKeyDictionary()


def observation_table(graph: StateGraph, obs_type: str, dtype: type) -> np.ndarray:
    """One observation row per state of the (enumerated) ``graph``, as the simulators gather them.

    ``compact`` rows are :func:`~morality_gym.world.compact_observe.compact_from_grid` of the grids
    (the projection paid once per state here, never per step). ``grid`` rows are the grid observation flattened (reshape a row to ``(GRID_CHANNELS,
    GRID_HEIGHT, GRID_WIDTH)``): every env id gives rows of one length, so copies of different
    scenarios can share one simulator (:class:`~morality_gym.envs.mixed.MixedBatchedTrolleyEnv`).
    """
    if obs_type not in BATCHED_OBS_TYPES:
        raise ValueError(f"obs_type must be one of {BATCHED_OBS_TYPES}, got {obs_type!r}")
    tables = graph.tables()
    if obs_type == "flat":
        return np.ascontiguousarray(tables.obs.astype(dtype))
    if obs_type == "compact":
        key = (tables.n_states, np.dtype(dtype).str)
        cached = _COMPACT_TABLES.get(graph)
        if cached is None or cached[0] != key:
            table = compact_from_grid(grid_table(graph.world, graph.states[: tables.n_states])).astype(dtype)
            table.setflags(write=False)
            cached = _COMPACT_TABLES[graph] = (key, table)
        return cached[1]
    grids = grid_table(graph.world, graph.states[: tables.n_states])
    return np.ascontiguousarray(grids.reshape(tables.n_states, -1).astype(dtype))


def sim_tables(env_id: str, obs_type: str, obs_dtype: type, *, overrides: Overrides | None = None,
               normalise: bool = True, cache_dir: Path | None = None) -> SimTables:
    """The tables a batched simulator gathers from for ``env_id`` (canonical id), with observation
    rows of ``obs_type``. With a ``cache_dir`` they are read from there when a sound entry exists,
    else built and written there (:mod:`.table_cache`; a world with ``overrides``, or grid rows, are
    always built: neither is worth an entry)."""
    scenario, variant = parse_env_id(env_id)
    path = key = None
    if cache_dir is not None and overrides is None and obs_type in CACHED_OBS_TYPES:
        key = entry_key(scenario, variant, obs_type, obs_dtype, normalise)
        path = Path(cache_dir) / f"{key}.npz"
        found = read_entry(path, key, obs_dtype)
        if found is not None:
            return found
    graph = state_graph(env_id, overrides, normalise)
    t = graph.tables()
    tables = SimTables(t.next, t.reward, t.events, t.utility, t.goal, t.done, observation_table(graph, obs_type, obs_dtype))
    if path is not None and key is not None:
        write_entry(path, key, env_id, tables)
    return tables


def utility_present(events: Any) -> tuple[Any, Any]:
    """Which utility keys a step reported, from its event masks (spec section 8).

    Returns (``type_keys``, ``n_harm``): ``n_human_harm``, ``n_animal_harm``, ``n_robot_harm`` and
    ``n_weighted_harm`` are present whenever anything (the trolley included) was harmed;
    ``n_harm`` only when a human, animal or robot (the agent included) was harmed. The cost needs
    this because a present zero is normalised differently from an absent key. ``events`` is a numpy
    uint32 array or a torch int64 tensor; the result is of the same kind.
    """
    return (events & HARM_BIT) != 0, (events & LIVING_BITS) != 0


class Layout(NamedTuple):
    """The tables of several graphs laid end to end: what both batched simulators gather from.

    Each graph's states are shifted by its offset, so transition row ``s * 6 + a`` of a global
    state is the same row of the copy's own graph; observations are zero-padded on the right to one
    width (padding appends zeros and changes no value). ``utility`` and ``goal`` have one extra,
    empty row (:attr:`no_transition`): what a copy that had already ended "did" in a step.
    """

    obs_dims: dict[str, int]  # each env id's own observation width
    graph_offsets: np.ndarray  # int32 [G]: each graph's first state
    next: np.ndarray  # int32 [S*6], global state ids
    reward: np.ndarray  # float32 [S*6]
    events: np.ndarray  # uint32 [S*6]
    done: np.ndarray  # bool [S]
    obs: np.ndarray  # [S, width], C-contiguous
    utility: np.ndarray  # [S*6 + 1, len(UTILITIES)]
    goal: np.ndarray  # bool [S*6 + 1]
    no_transition: int  # S*6: the empty row


def lay_out(tables: Sequence[SimTables], env_ids: Sequence[str], width: int | None = None) -> Layout:
    """``tables`` (of ``env_ids``, one each) end to end, observations padded to ``width``.

    ``width=None``: every graph must have one observation width (copies of one simulator are fed
    to one network). The host simulator and the device one (:mod:`morality_gym.envs.torch_sim`)
    both lay out their tables here, so they step the same tables by construction.
    """
    dims = {e: int(t.obs.shape[1]) for e, t in zip(env_ids, tables)}
    observations = _padded([t.obs for t in tables], dims, width)
    offsets = np.cumsum([0] + [t.n_states for t in tables])[:-1].astype(np.int32)
    nxt = _joined([t.next.astype(np.int32, copy=False) + off if off else t.next for t, off in zip(tables, offsets)])
    done = _joined([t.done for t in tables])
    assert len(nxt) == N_ACTIONS * len(done)
    utility = _joined([t.utility for t in tables])
    return Layout(
        obs_dims=dims, graph_offsets=offsets, next=nxt, reward=_joined([t.reward for t in tables]).astype(np.float32),
        events=_joined([t.events for t in tables]), done=done, obs=np.ascontiguousarray(_joined(observations)),
        utility=np.vstack([utility, np.zeros((1, utility.shape[1]), dtype=utility.dtype)]),
        goal=np.append(_joined([t.goal for t in tables]), False), no_transition=len(nxt),
    )


def advance(next_state: Any, done: Any, state: Any, elapsed: Any, actions: Any, limit: int) -> tuple[Any, Any, Any, Any, Any]:
    """One step of every copy before any reset: the transition rows, the next states, the steps
    taken, and which copies terminated and which were truncated (on step ``limit + 1``).

    Written once for both simulators: only indexing, ``*``, ``+`` and ``>``, which numpy arrays (the
    host's) and torch tensors (:mod:`morality_gym.envs.torch_sim`) do alike. What happens to the
    copies that ended is each simulator's own (the host's may leave them inert; the device's never
    branches on data).
    """
    k = state * N_ACTIONS + actions
    nxt = next_state[k]
    elapsed = elapsed + 1
    return k, nxt, elapsed, done[nxt], elapsed > limit


def _padded(observations: list[np.ndarray], dims: dict[str, int], width: int | None) -> list[np.ndarray]:
    """Each graph's observation rows zero-padded on the right to ``width`` (None: they must all
    have one width already, else a :class:`ValueError` that says how to mix scenarios)."""
    if width is None:
        if len(set(dims.values())) > 1:
            raise ValueError(
                f"the copies of one simulator must share an observation size, got {dims}; "
                "fleet only variants of one scenario together, use obs_type='grid', or pad_obs=True"
            )
        return observations
    if width < max(dims.values()):
        raise ValueError(f"obs_dim={width} is narrower than the widest observation ({max(dims.values())}) of {list(dims)}")
    return [o if o.shape[1] == width else np.pad(o, ((0, 0), (0, width - o.shape[1]))) for o in observations]


class BatchedTrolleyEnv:
    """``num_envs`` copies of one env id, stepped together with arrays.

    Args:
        env_id: a registered id such as ``PushOrSwitch-Human-v1``.
        num_envs: number of copies.
        max_steps: truncation on step ``max_steps + 1`` (``None``: never).
        obs_dtype: dtype of the observation arrays (float32 halves memory traffic; the values are
            the reference's float64 values rounded to float32).
        autoreset: ``"same_step"`` resets a copy in the step it ends (its last observation goes to
            ``final_obs``), as SB3 expects; ``"disabled"`` leaves ended copies inert (reward 0, no
            events) until :meth:`reset` is called for them.
        obs_type: ``"flat"`` (default) the scenario's flat vector; ``"grid"`` the fixed-shape grid
            observation, flattened; ``"compact"`` the compact observation (:func:`observation_table`).
        table_cache: a folder that keeps the graphs' tables between processes (:func:`sim_tables`).

    The simulator is built for the general case, copies of several env ids whose graphs are laid
    end to end (:class:`~morality_gym.envs.mixed.MixedBatchedTrolleyEnv`, :meth:`_build`); one env id
    is a mixture of one, whose tables are used as they are (no copy).
    """

    #: The batched simulator does not render (SB3 and Gymnasium probe this attribute).
    render_mode: str | None = None

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        *,
        max_steps: int | None = MAX_STEPS,
        obs_dtype: type = np.float32,
        autoreset: AutoReset = "same_step",
        normalise_obs: bool = True,
        overrides: dict | None = None,
        obs_type: str = "flat",
        table_cache: Path | None = None,
    ) -> None:
        if not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive int, got {num_envs!r}")
        self._build([env_id] * num_envs, max_steps=max_steps, obs_dtype=obs_dtype, autoreset=autoreset,
                    normalise_obs=normalise_obs, overrides=overrides, obs_type=obs_type, table_cache=table_cache)

    def _build(
        self,
        env_ids: Sequence[str],
        *,
        max_steps: int | None,
        obs_dtype: type,
        autoreset: AutoReset,
        normalise_obs: bool,
        overrides: dict | None,
        obs_type: str,
        table_cache: Path | None,
        pad_obs: bool = False,
        graphs: Sequence[str] | None = None,
    ) -> None:
        """Set up ``len(env_ids)`` copies, copy ``i`` running ``env_ids[i]``, over the tables of
        ``graphs`` (default: the copies' distinct env ids), loaded once each and laid end to end."""
        if autoreset not in ("same_step", "disabled"):
            raise ValueError(f"autoreset must be 'same_step' or 'disabled', got {autoreset!r}")
        if max_steps is not None and (isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 0):
            raise ValueError(f"max_steps must be a non-negative int or None, got {max_steps!r}")
        spelled = {e: canonical_env_id(e) for e in dict.fromkeys(env_ids)}
        #: Every copy's env id, as the registry spells it.
        self.env_ids: list[str] = [spelled[e] for e in env_ids]
        #: The first copy's env id (the only one of a simulator of one env id).
        self.env_id = self.env_ids[0]
        #: The graphs whose tables are loaded, in order: ``graphs`` when given (every copy's id must
        #: be one of them), else the copies' distinct env ids.
        self.unique_env_ids: list[str] = list(dict.fromkeys(self.env_ids if graphs is None else map(canonical_env_id, graphs)))
        unknown = sorted(set(self.env_ids) - set(self.unique_env_ids))
        if unknown:
            raise ValueError(f"copies run env ids that are not among graphs: {', '.join(unknown[:3])}")
        self.num_envs = len(self.env_ids)
        self.max_steps = max_steps
        self.autoreset = autoreset
        self.obs_type = obs_type
        self._graph_args = (_overrides(overrides), normalise_obs)
        tables = [sim_tables(e, obs_type, obs_dtype, overrides=self._graph_args[0], normalise=normalise_obs, cache_dir=table_cache)
                  for e in self.unique_env_ids]
        self._lay_out(tables, pad_obs)
        index = {e: i for i, e in enumerate(self.unique_env_ids)}
        #: Each copy's graph, as an index into :attr:`unique_env_ids`.
        self.copy_graph = np.array([index[e] for e in self.env_ids], dtype=np.int32)
        #: Each copy's start state: its own graph's first state in the tables.
        self._start = self.graph_offsets[self.copy_graph].astype(np.int32)
        self._limit = np.iinfo(np.int32).max if max_steps is None else max_steps
        self.state = self._start.copy()
        self.elapsed = np.zeros(self.num_envs, dtype=np.int32)
        self.ended = np.zeros(self.num_envs, dtype=bool)
        self._zero_reward = np.float32(0.0)

    def _lay_out(self, tables: list[SimTables], pad_obs: bool) -> None:
        """The graphs' tables end to end (:func:`lay_out`), kept as this simulator's arrays."""
        width = max(int(t.obs.shape[1]) for t in tables) if pad_obs else None
        laid = lay_out(tables, self.unique_env_ids, width)
        #: Each env id's own observation width (before any padding).
        self.obs_dims = laid.obs_dims
        #: Each graph's first state id in the tables (its start state).
        self.graph_offsets = laid.graph_offsets
        self._next, self._reward, self._events, self._done = laid.next, laid.reward, laid.events, laid.done
        self._obs, self._utility, self._goal = laid.obs, laid.utility, laid.goal
        self.obs_dim = self._obs.shape[1]
        #: The extra, empty row after the graphs' transitions: what an ended copy "did" in a step.
        self.no_transition = laid.no_transition

    @property
    def graph(self) -> StateGraph:
        """The (shared, memoised) state graph of :attr:`env_id`: enumerated only if asked for, since
        tables read from a cache need none."""
        return state_graph(self.env_id, *self._graph_args)

    # ------------------------------------------------------------------ API
    def reset(self, mask: np.ndarray | None = None) -> np.ndarray:
        """Reset every copy (or those where ``mask`` is true); returns all observations."""
        self._redraw(mask)
        if mask is None:
            self.state[:] = self._start
            self.elapsed.fill(0)
            self.ended.fill(False)
        else:
            self.state[mask] = self._start[mask]
            self.elapsed[mask] = 0
            self.ended[mask] = False
        return self._gather(self.state)

    def step(self, actions: np.ndarray) -> BatchStep:
        """Advance every copy by one action (integers 0..5, one per copy)."""
        actions = np.asarray(actions)
        if actions.shape != (self.num_envs,):
            raise ValueError(f"expected {self.num_envs} actions, got an array of shape {actions.shape}")
        if actions.dtype.kind not in "iu":
            raise ValueError(f"actions must be integers 0..5, got dtype {actions.dtype}")
        if actions.size and (actions.min() < 0 or actions.max() >= N_ACTIONS):
            bad = actions[(actions < 0) | (actions >= N_ACTIONS)][0]
            raise ValueError(f"invalid action {bad}: expected integers in 0..5")
        k, nxt, self.elapsed, terminated, truncated = advance(self._next, self._done, self.state, self.elapsed,
                                                              actions, self._limit)
        reward = self._reward[k]
        events = self._events[k]
        final_obs = None
        if self.autoreset == "disabled":
            if self.ended.any():
                frozen = self.ended
                nxt = np.where(frozen, self.state, nxt)
                k = np.where(frozen, self.no_transition, k)
                reward = np.where(frozen, self._zero_reward, reward)
                events = np.where(frozen, np.uint32(0), events)
                self.elapsed[frozen] -= 1
                terminated = np.where(frozen, self._done[self.state], terminated)
                truncated = np.where(frozen, self.elapsed > self._limit, truncated)
            self.ended |= terminated | truncated
            self.state = nxt
            obs = self._gather(nxt)
        else:
            ended = terminated | truncated
            if ended.any():
                final_obs = np.zeros((self.num_envs, self.obs_dim), dtype=self._obs.dtype)
                final_obs[ended] = self._obs[nxt[ended]]
                self._redraw(ended)
                nxt = np.where(ended, self._start, nxt).astype(np.int32)
                self.elapsed[ended] = 0
            self.state = nxt
            obs = self._gather(nxt)
        return BatchStep(obs, reward, terminated, truncated, events, k, final_obs)

    def state_dict(self) -> dict[str, np.ndarray]:
        """What a step changes (each copy's state, steps taken, ended flag), as copies: with the
        same env ids, :meth:`load_state_dict` puts the simulator back where it was (a training
        checkpoint, :mod:`morality_gym.baselines.fleet.checkpoint`). Stepping draws no random
        number, so there is no RNG to keep."""
        return {"state": self.state.copy(), "elapsed": self.elapsed.copy(), "ended": self.ended.copy()}

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        """Restore :meth:`state_dict`'s arrays (shapes and dtypes must match this simulator's)."""
        for name in ("state", "elapsed", "ended"):
            current = getattr(self, name)
            value = np.asarray(state[name])
            if value.shape != current.shape:
                raise ValueError(f"simulator {name}: expected shape {current.shape}, got {value.shape}")
            setattr(self, name, value.astype(current.dtype, copy=True))
        _check_range("state", self.state, 0, len(self._obs) - 1)
        _check_range("elapsed", self.elapsed, 0, int(self._limit) + 1)  # limit + 1: a copy frozen at its truncation

    # ------------------------------------------------------------------ helpers
    def _redraw(self, mask: np.ndarray | None) -> None:
        """Called before the copies where ``mask`` is true (None: all) restart: a subclass may move
        them to another graph by changing their :attr:`_start` (:mod:`morality_gym.envs.drawn`)."""

    def _gather(self, states: np.ndarray) -> np.ndarray:
        return self._obs[states]

    def utility(self, transition: np.ndarray) -> np.ndarray:
        """Utility values ``[n, 5]`` (``vocab.UTILITIES`` order, 0 when absent) of the given transitions."""
        return self._utility[transition]

    def goal_reached(self, transition: np.ndarray) -> np.ndarray:
        """Whether each transition reached the landmark."""
        return self._goal[transition]

    def __repr__(self) -> str:
        return f"<BatchedTrolleyEnv {self.env_id} x{self.num_envs} max_steps={self.max_steps} autoreset={self.autoreset}>"


def _check_range(name: str, values: np.ndarray, low: int, high: int) -> None:
    """Refuse a restored array with a value outside ``[low, high]`` (a damaged checkpoint: an
    out-of-range state would index past the tables at the next step, or read another env's)."""
    wide = values.astype(np.int64)
    bad = (wide < low) | (wide > high)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"simulator {name}: copy {i} holds {int(wide[i])}, outside {low}..{high}")


def _joined(arrays: list[np.ndarray]) -> np.ndarray:
    """The arrays one after another; a single array as it is (a simulator of one env id shares its
    graph's tables instead of copying them)."""
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)
