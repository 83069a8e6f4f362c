"""The oracle: the best and the worst morality metric any policy can reach, and how.

The metric is linear in the distribution over episode outcomes, so no mixture of behaviours beats
the best single outcome; the environment is deterministic, so every outcome is reached by an action
sequence. The oracle therefore enumerates the outcomes reachable within the horizon
(``max_steps + 1`` steps) by dynamic programming over layers of (state, events so far, utility
totals so far), keeping for each node the highest task return that reaches it and a back pointer.
Among outcomes with equal metric, the one with the higher return wins (for best and worst alike).
Only the chain's relevant norms enter the search key; the reported morality functions of all
norms come from replaying the chosen sequence.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from morality_gym.constants import BETA, MAX_STEPS
from morality_gym.envs.registry import state_graph
from morality_gym.envs.trolley import TrolleyEnv
from morality_gym.norms.chain import MoralityChain
from morality_gym.norms.metric import BoundChain, bind_chain
from morality_gym.world.graph import N_ACTIONS
from morality_gym.world.vocab import EVENT_BIT, UTILITIES

_TIE = 1e-12


@dataclass(frozen=True)
class OracleOutcome:
    """One extreme: its metric, the action sequence reaching it, and what that sequence does."""

    metric: float
    actions: list[int]
    ret: float
    functions: dict[str, float]
    events: list[str]
    utility: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return {
            "metric": self.metric,
            "actions": self.actions,
            "return": self.ret,
            "functions": self.functions,
            "events": self.events,
            "utility": self.utility,
        }


@dataclass(frozen=True)
class OracleResult:
    env_id: str
    chain: str
    beta: float
    best: OracleOutcome
    worst: OracleOutcome
    n_outcomes: int  # distinct outcomes of the relevant norms within the horizon


def _group_max(keys: np.ndarray, score: np.ndarray) -> np.ndarray:
    """Indices of the highest-``score`` row of each distinct row of ``keys``."""
    order = np.lexsort((-score, *keys.T[::-1]))
    sorted_keys = keys[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = np.any(sorted_keys[1:] != sorted_keys[:-1], axis=1)
    return order[first]


def _replay(bound: BoundChain, actions: list[int], max_steps: int) -> tuple[float, dict[str, float], list[str], dict[str, float]]:
    env = TrolleyEnv(bound.env_id, max_steps=max_steps)
    env.reset()
    events: set[str] = set()
    sums: dict[str, float] = {}
    ret = 0.0
    for a in actions:
        _, r, terminated, truncated, info = env.step(a)
        ret += r
        ne = info["norm_events"]
        events |= set(ne["action"]) | set(ne["outcome"]) | set(ne["causal"])
        for k, v in ne["utility"].items():
            sums[k] = sums.get(k, 0.0) + v
        if terminated or truncated:
            break
    else:
        raise RuntimeError(f"oracle sequence for {bound.env_id} does not end the episode (bug)")
    functions = bound.morality_functions({e: 1.0 for e in events}, sums, strict=False)
    return ret, functions, sorted(events), sums


def oracle(
    env_id: str,
    chain: str | MoralityChain | BoundChain,
    beta: float | str = BETA,
    max_steps: int = MAX_STEPS,
) -> OracleResult:
    """Best and worst achievable metric of ``chain`` in ``env_id`` within ``max_steps`` (+1) steps.

    Kept as one function on purpose: the layer-by-layer search, the scoring of its terminal outcomes
    and the replay of the chosen action sequences share the same arrays (``finals``, ``parents``,
    ``acts``), and the closures below read them in place; split apart, each piece would need all of
    them passed in and the algorithm would no longer read in one pass.
    """
    if max_steps is None or max_steps < 0:
        raise ValueError("the oracle needs a finite max_steps (the paper uses 200)")
    bound = chain if isinstance(chain, BoundChain) else bind_chain(chain, env_id, beta)
    t = state_graph(bound.env_id).tables()
    rel_events = [n.name for n in bound.chain.event_norms if bound.weights[n.name] > 0]
    rel_utils = [n.name for n in bound.chain.utility_norms if bound.weights[n.name] > 0]
    event_mask = np.uint32(sum(1 << EVENT_BIT[n] for n in rel_events))
    cols = [UTILITIES.index(n) for n in rel_utils]
    util_table = t.utility[:, cols].astype(np.int64)
    horizon = max_steps + 1

    states = np.zeros(1, dtype=np.int64)
    masks = np.zeros(1, dtype=np.int64)
    sums = np.zeros((1, len(cols)), dtype=np.int64)
    rets = np.zeros(1)
    parents: list[np.ndarray] = []
    acts: list[np.ndarray] = []
    # terminal outcomes: key (mask, sums...) -> (return, layer, index in that layer's expansion)
    finals: dict[tuple[int, ...], tuple[float, int, int, int]] = {}
    for step in range(1, horizon + 1):
        n = len(states)
        idx = np.repeat(np.arange(n), N_ACTIONS)
        act = np.tile(np.arange(N_ACTIONS), n)
        k = states[idx] * N_ACTIONS + act
        nxt = t.next[k].astype(np.int64)
        nmask = masks[idx] | (t.events[k] & event_mask).astype(np.int64)
        nsum = sums[idx] + util_table[k]
        nret = rets[idx] + t.reward[k]
        ended = t.done[nxt] if step < horizon else np.ones(len(k), dtype=bool)
        if ended.any():
            e_idx = np.flatnonzero(ended)
            keys = np.column_stack([nmask[e_idx], nsum[e_idx]])
            for j in _group_max(keys, nret[e_idx]):
                key = tuple(int(x) for x in keys[j])
                cand = (float(nret[e_idx[j]]), step, int(idx[e_idx[j]]), int(act[e_idx[j]]))
                if key not in finals or cand[0] > finals[key][0] + _TIE:
                    finals[key] = cand
        cont = np.flatnonzero(~ended)
        if len(cont) == 0:
            break
        keys = np.column_stack([nxt[cont], nmask[cont], nsum[cont]])
        keep = cont[_group_max(keys, nret[cont])]
        parents.append(idx[keep])
        acts.append(act[keep])
        states, masks, sums, rets = nxt[keep], nmask[keep], nsum[keep], nret[keep]

    def metric_of(key: tuple[int, ...]) -> float:
        mask, totals = key[0], key[1:]
        ev = {n: float(mask >> EVENT_BIT[n] & 1) for n in rel_events}
        ut = dict(zip(rel_utils, map(float, totals)))
        return bound.metric(bound.morality_functions(ev, ut, strict=False))

    scored = [(metric_of(key), value[0], key) for key, value in finals.items()]
    best = max(scored, key=lambda x: (round(x[0] / _TIE) * _TIE, x[1]))
    worst = min(scored, key=lambda x: (round(x[0] / _TIE) * _TIE, -x[1]))

    def actions_of(key: tuple[int, ...]) -> list[int]:
        _, layer, parent, action = finals[key]
        seq = [action]
        for depth in range(layer - 2, -1, -1):  # layer L was expanded from node `parent` of layer L-1
            seq.append(int(acts[depth][parent]))
            parent = int(parents[depth][parent])
        return seq[::-1]

    def outcome(choice: tuple[float, float, tuple[int, ...]]) -> OracleOutcome:
        actions = actions_of(choice[2])
        ret, functions, events, utility = _replay(bound, actions, max_steps)
        metric = bound.metric(functions)
        if abs(metric - choice[0]) > 1e-9 or abs(ret - choice[1]) > 1e-9:
            raise RuntimeError(f"oracle replay mismatch in {bound.env_id}: {metric} vs {choice[0]}, {ret} vs {choice[1]}")
        return OracleOutcome(metric, actions, ret, functions, events, utility)

    return OracleResult(bound.env_id, bound.chain.name, bound.beta, outcome(best), outcome(worst), len(finals))
