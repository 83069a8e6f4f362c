"""Exact evaluation: the expected morality metric of a stationary policy, without sampling.

The environments are deterministic and their state graphs small, so the distribution over states
after ``t`` steps can be propagated exactly: from each (state, accumulated events) pair with
probability ``p``, action ``a`` leads with probability ``p * pi(a | obs(state))`` to one known
successor. Utilities, return and length are linear in these probabilities and accumulate on the
way; an event's morality function needs the probability that it occurred *at least once*, which is
why the events seen so far (restricted to the chain's event norms) are part of the propagated key.
The horizon is ``max_steps + 1`` steps, where the environment truncates.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from morality_gym.constants import BETA, MAX_STEPS
from morality_gym.envs.registry import state_graph
from morality_gym.evaluation.montecarlo import MAX_EPISODE_STEPS
from morality_gym.evaluation.policies import PolicyAdapter
from morality_gym.evaluation.result import EvaluationResult
from morality_gym.norms.chain import MoralityChain
from morality_gym.norms.metric import BoundChain, bind_chain
from morality_gym.world.graph import N_ACTIONS, GraphTables
from morality_gym.world.vocab import EVENT_BIT, UTILITIES

_TINY = 1e-15


def state_policy(policy: Any, env_id: str, deterministic: bool = False) -> np.ndarray:
    """Action probabilities ``[n_states, 6]`` for every reachable state (one batched query)."""
    tables = state_graph(env_id).tables()
    adapter = PolicyAdapter(policy, deterministic=deterministic)
    return adapter.probabilities(tables.obs, np.arange(tables.n_states))


def propagate(
    tables: GraphTables, probs: np.ndarray, event_mask: int, horizon: int
) -> tuple[dict[int, float], np.ndarray, float, float, float, float]:
    """Propagate the start state for ``horizon`` steps.

    Returns (probability of each final event mask, expected utility totals [5], expected return,
    expected length, truncation probability, probability of reaching the landmark).
    """
    done = tables.done
    states = np.zeros(1, dtype=np.int64)
    masks = np.zeros(1, dtype=np.uint64)
    mass = np.ones(1)
    final: dict[int, float] = {}
    utility = np.zeros(len(UTILITIES))
    ret = length = truncated = goal = 0.0
    mask = np.uint64(event_mask)
    for t in range(1, horizon + 1):
        length += float(mass.sum())
        k = (states[:, None] * N_ACTIONS + np.arange(N_ACTIONS)).ravel()
        pr = (mass[:, None] * probs[states]).ravel()
        keep = pr > 0
        k, pr = k[keep], pr[keep]
        prev_masks = np.repeat(masks, N_ACTIONS)[keep]
        ret += float(pr @ tables.reward[k])
        utility += pr @ tables.utility[k]
        goal += float(pr @ tables.goal[k])
        nxt = tables.next[k].astype(np.int64)
        new_masks = prev_masks | (tables.events[k].astype(np.uint64) & mask)
        ended = done[nxt]
        if t == horizon:
            truncated += float(pr[~ended].sum())
            ended = np.ones_like(ended)
        if ended.any():
            for m, p in zip(*_combine(new_masks[ended], pr[ended])):
                final[int(m)] = final.get(int(m), 0.0) + float(p)
        cont = ~ended
        if not cont.any():
            break
        key = (nxt[cont].astype(np.uint64) << np.uint64(32)) | new_masks[cont]
        uniq, summed = _combine(key, pr[cont])
        live = summed > _TINY
        uniq, summed = uniq[live], summed[live]
        states = (uniq >> np.uint64(32)).astype(np.int64)
        masks = uniq & np.uint64(0xFFFFFFFF)
        mass = summed
    return final, utility, ret, length, truncated, goal


def _combine(keys: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    uniq, inverse = np.unique(keys, return_inverse=True)
    return uniq, np.bincount(inverse.ravel(), weights=weights, minlength=len(uniq))


def exact_evaluate(
    policy: Any,
    env_id: str,
    chain: str | MoralityChain | BoundChain,
    max_steps: int | None = MAX_STEPS,
    beta: float | str = BETA,
    deterministic: bool = False,
) -> EvaluationResult:
    """The exact expectation of everything :func:`~morality_gym.evaluation.montecarlo.evaluate` estimates.

    ``policy`` must be stationary (its action probabilities depend only on the observation); see
    :class:`~morality_gym.evaluation.policies.PolicyAdapter` for accepted kinds. With
    ``max_steps=None`` the horizon is the reference evaluator's 5,000-step cap.
    """
    bound = chain if isinstance(chain, BoundChain) else bind_chain(chain, env_id, beta)
    tables = state_graph(bound.env_id).tables()
    probs = state_policy(policy, bound.env_id, deterministic)
    event_mask = 0
    for norm in bound.chain.event_norms:
        event_mask |= 1 << EVENT_BIT[norm.name]
    horizon = MAX_EPISODE_STEPS if max_steps is None else max_steps + 1
    final, utility, ret, length, truncated, goal = propagate(tables, probs, event_mask, horizon)
    total = sum(final.values())
    if abs(total - 1.0) > 1e-9:
        raise RuntimeError(f"probability mass {total} != 1 after propagation (bug)")
    event_freq = {
        n.name: float(sum(p for m, p in final.items() if m >> EVENT_BIT[n.name] & 1)) for n in bound.chain.event_norms
    }
    return EvaluationResult.from_aggregates(
        bound,
        exact=True,
        event_freq=event_freq,
        utility_mean={name: float(utility[i]) for i, name in enumerate(UTILITIES)},
        mean_return=ret,
        mean_length=length,
        truncation_rate=truncated,
        goal_rate=goal,
    )
