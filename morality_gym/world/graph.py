"""The state graph of one world: memoised transitions, full enumeration and numpy tables.

The worlds are tiny, discrete and deterministic, so every (state, action) pair needs to be
simulated once per process at most. :class:`StateGraph` interns kernel states to integer ids and
caches each transition together with everything an environment returns for it (observation,
reward, flags, norm events), so a step of the Gymnasium environment is a list lookup. The same
graph, enumerated completely by :meth:`StateGraph.expand`, becomes numpy tables for the batched
simulator, the exact evaluator and the oracle.

Cached objects are shared between steps and environments, so they are never handed out directly:
observations are read-only arrays and the environment returns copies of them and of the info
mappings (Gymnasium requires new objects on every call); event-name sets are frozensets.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from morality_gym.world.observe import ObservationCodec
from morality_gym.world.rules import State, World
from morality_gym.world.vocab import EVENT_CATEGORY, EVENTS, UTILITIES

N_ACTIONS = 6


NormEvents = tuple[frozenset[str], frozenset[str], frozenset[str], dict[str, int]]


def make_norm_events(mask: int, utility: dict[str, int]) -> NormEvents:
    """The (action, outcome, causal, utility) parts of ``info["norm_events"]`` (spec section 8)."""
    cats: dict[str, set[str]] = {"action": set(), "outcome": set(), "causal": set()}
    for i, name in enumerate(EVENTS):
        if mask >> i & 1:
            cats[EVENT_CATEGORY[name]].add(name)
    return frozenset(cats["action"]), frozenset(cats["outcome"]), frozenset(cats["causal"]), dict(utility)


def norm_events_dict(parts: NormEvents) -> dict[str, Any]:
    """A fresh ``info["norm_events"]`` dict (Gymnasium requires new info objects on every call)."""
    return {"action": parts[0], "outcome": parts[1], "causal": parts[2], "utility": dict(parts[3])}


EMPTY_NORM_EVENTS: NormEvents = make_norm_events(0, {})


class Edge(NamedTuple):
    """One memoised transition with everything ``step`` returns for it."""

    next: int
    reward: float
    terminated: bool
    obs: np.ndarray  # read-only; copy before handing out
    norm_events: NormEvents
    statuses: dict[str, bool]  # shared; copy before handing out
    goal: int
    events: int
    utility: tuple[int, ...]  # values in vocab.UTILITIES order, 0 when absent


@dataclass(frozen=True)
class GraphTables:
    """The whole reachable graph as arrays; row ``s * 6 + a`` describes action ``a`` in state ``s``.

    Terminated states have inert self-loops (reward 0, no events), like the environment after the
    end of an episode.
    """

    next: np.ndarray  # int32 [S*6]
    reward: np.ndarray  # float64 [S*6]
    events: np.ndarray  # uint32 [S*6] bit masks over vocab.EVENTS
    utility: np.ndarray  # int32 [S*6, 5] in vocab.UTILITIES order
    goal: np.ndarray  # bool [S*6]
    done: np.ndarray  # bool [S]: world terminated
    obs: np.ndarray  # float64 [S, obs_dim]

    @property
    def n_states(self) -> int:
        return int(self.done.shape[0])


class StateGraph:
    """Interned states and memoised transitions of one world (see the module docstring)."""

    def __init__(self, world: World, codec: ObservationCodec) -> None:
        self.world = world
        self.codec = codec
        self.states: list[State] = []
        self.ids: dict[State, int] = {}
        self.obs: list[np.ndarray] = []
        self.done: list[bool] = []
        self.statuses: list[dict[str, bool]] = []
        #: edges[s][a] is the memoised transition or None; rows are appended, never replaced.
        self.edges: list[list[Edge | None]] = []
        self._events_cache: dict[tuple[int, tuple[tuple[str, int], ...]], NormEvents] = {}
        self._lock = threading.Lock()
        self._tables: GraphTables | None = None
        self.intern(world.initial_state)

    def intern(self, state: State) -> int:
        """The id of ``state``, adding it (with its observation and statuses) if new."""
        sid = self.ids.get(state)
        if sid is not None:
            return sid
        sid = len(self.states)
        obs = np.asarray(self.codec.flat(state), dtype=np.float64)
        obs.setflags(write=False)
        self.obs.append(obs)
        self.done.append(World.is_done(state))
        self.statuses.append(self.world.termination_statuses(state))
        self.edges.append([None] * N_ACTIONS)
        self.states.append(state)
        self.ids[state] = sid
        return sid

    def edge(self, sid: int, action: int) -> Edge:
        """The transition of ``action`` in state ``sid``, simulating it on first use."""
        cached = self.edges[sid][action]
        if cached is not None:
            return cached
        with self._lock:
            cached = self.edges[sid][action]
            if cached is not None:
                return cached
            state = self.states[sid]
            if self.done[sid]:
                edge = Edge(sid, 0.0, True, self.obs[sid], EMPTY_NORM_EVENTS, self.statuses[sid], 0, 0, (0,) * len(UTILITIES))
            else:
                out = self.world.step(state, action)
                nid = self.intern(out.state)
                key = (out.events, tuple(sorted(out.utility.items())))
                norm_events = self._events_cache.get(key)
                if norm_events is None:
                    norm_events = self._events_cache[key] = make_norm_events(out.events, out.utility)
                edge = Edge(
                    nid,
                    out.reward,
                    self.done[nid],
                    self.obs[nid],
                    norm_events,
                    self.statuses[nid],
                    int(out.goal_reached),
                    out.events,
                    tuple(out.utility.get(name, 0) for name in UTILITIES),
                )
            self.edges[sid][action] = edge
            return edge

    def expand(self) -> int:
        """Enumerate every state reachable from the start (breadth first); returns the count."""
        seen = [False] * len(self.states)
        queue = deque([0])
        seen[0] = True
        while queue:
            sid = queue.popleft()
            for a in range(N_ACTIONS):
                nid = self.edge(sid, a).next
                if nid >= len(seen):
                    seen.extend([False] * (nid + 1 - len(seen)))
                if not seen[nid]:
                    seen[nid] = True
                    queue.append(nid)
        return len(self.states)

    def tables(self) -> GraphTables:
        """The complete graph as numpy arrays (enumerates it on first call)."""
        if self._tables is not None:
            return self._tables
        n = self.expand()
        nxt = np.empty(n * N_ACTIONS, dtype=np.int32)
        reward = np.empty(n * N_ACTIONS, dtype=np.float64)
        events = np.empty(n * N_ACTIONS, dtype=np.uint32)
        utility = np.empty((n * N_ACTIONS, len(UTILITIES)), dtype=np.int32)
        goal = np.empty(n * N_ACTIONS, dtype=bool)
        for sid in range(n):
            for a in range(N_ACTIONS):
                e = self.edge(sid, a)
                k = sid * N_ACTIONS + a
                nxt[k] = e.next
                reward[k] = e.reward
                events[k] = e.events
                utility[k] = e.utility
                goal[k] = e.goal
        obs = np.stack(self.obs[:n])
        done = np.array(self.done[:n], dtype=bool)
        for arr in (nxt, reward, events, utility, goal, obs, done):
            arr.setflags(write=False)
        self._tables = GraphTables(nxt, reward, events, utility, goal, done, obs)
        return self._tables
