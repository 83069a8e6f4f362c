"""Exact scores of one grid (or compact-observation) policy on an evaluation set.

A policy trained on the mixture sees grids (or their compact observations, :func:`takes_compact`),
so its action probabilities are asked for the observation of every reachable state of each env id
(one batched query per env id) and the resulting state-aligned
table is evaluated exactly (:func:`~morality_gym.evaluation.exact.exact_evaluate`: the expected
metric of the stochastic policy, no sampling noise). The distribution is propagated once per env id
with the events of every chain kept apart (:func:`pair_metrics`), and each chain's metric read off
it, which is what :func:`~morality_gym.evaluation.exact.exact_evaluate` computes chain by chain
(a test checks they agree). Each pair's metric is then placed between the
pair's exact oracle worst and best (``range_score``) and between Random and the best
(``random_score``, the leaderboard's normalised score).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from morality_gym.constants import BETA, MAX_STEPS
from morality_gym.envs.registry import state_graph
from morality_gym.evaluation.exact import propagate
from morality_gym.evaluation.policies import PolicyAdapter
from morality_gym.evaluation.result import EvaluationResult
from morality_gym.generalisation.sets import EvalSet, PairValues
from morality_gym.norms.metric import bind_chain
from morality_gym.world.compact_observe import COMPACT_WIDTH, compact_from_grid
from morality_gym.world.grid_observe import GridCodec
from morality_gym.world.vocab import EVENT_BIT, UTILITIES


def grid_table(env_id: str) -> np.ndarray:
    """The grid observation of every state of ``env_id``'s graph, state-aligned."""
    graph = state_graph(env_id)
    graph.tables()  # completes the graph: every reachable state gets its id
    codec = GridCodec(graph.world)
    return np.stack([codec.encode(state) for state in graph.states])


def takes_compact(policy: Any) -> bool:
    """Whether ``policy`` (an SB3 model or policy) reads the compact observation: one trained by a
    fleet on the track's mixture (:mod:`morality_gym.baselines.fleet.drawn_env`). Others read the grid."""
    space = getattr(policy, "observation_space", None)
    return getattr(space, "shape", None) == (COMPACT_WIDTH,)


def policy_table(policy: Any, env_id: str, deterministic: bool = False) -> np.ndarray | str:
    """Action probabilities ``[n_states, 6]`` of ``policy`` on ``env_id``'s grids, or on their
    compact observations for a policy that reads those (``"random"`` stays a name)."""
    if isinstance(policy, str):
        return policy
    grids = grid_table(env_id)
    obs = compact_from_grid(grids) if takes_compact(policy) else grids
    return PolicyAdapter(policy, deterministic=deterministic).probabilities(obs, np.arange(len(grids)))


def pair_metrics(table: np.ndarray, env_id: str, chains: list[str], beta: float = BETA,
                 max_steps: int = MAX_STEPS) -> dict[str, float]:
    """The exact metric of the state-aligned policy ``table`` under each chain, from one propagation."""
    bounds = {name: bind_chain(name, env_id, beta) for name in chains}
    event_mask = 0
    for bound in bounds.values():
        for norm in bound.chain.event_norms:
            event_mask |= 1 << EVENT_BIT[norm.name]
    final, utility, ret, length, truncated, goal = propagate(state_graph(env_id).tables(), table, event_mask,
                                                             max_steps + 1)
    utility_mean = {name: float(utility[i]) for i, name in enumerate(UTILITIES)}
    out = {}
    for name, bound in bounds.items():
        event_freq = {n.name: float(sum(p for m, p in final.items() if m >> EVENT_BIT[n.name] & 1))
                      for n in bound.chain.event_norms}
        out[name] = EvaluationResult.from_aggregates(
            bound, exact=True, event_freq=event_freq, utility_mean=utility_mean, mean_return=ret, mean_length=length,
            truncation_rate=truncated, goal_rate=goal).metric
    return out


def score_pair(pair: PairValues, metric: float) -> dict[str, Any]:
    """One pair's exact metric and scores."""
    return {"env_id": pair.env_id, "chain": pair.chain, "metric": float(metric), "best": pair.best,
            "worst": pair.worst, "random": pair.random, "range_score": pair.range_score(metric),
            "random_score": pair.random_score(metric)}


def score_set(policy: Any, eval_set: EvalSet, deterministic: bool = False) -> list[dict[str, Any]]:
    """Every pair of ``eval_set`` scored exactly (``policy="random"``: the exact Random values)."""
    rows = []
    by_env: dict[str, list[PairValues]] = {}
    for pair in eval_set.pairs:
        by_env.setdefault(pair.env_id, []).append(pair)
    for env_id, pairs in by_env.items():
        if isinstance(policy, str) and policy == "random":
            metrics = {p.chain: p.random for p in pairs}
        else:
            metrics = pair_metrics(policy_table(policy, env_id, deterministic), env_id, [p.chain for p in pairs])
        rows.extend({"set": eval_set.name, **score_pair(pair, metrics[pair.chain])} for pair in pairs)
    return rows
