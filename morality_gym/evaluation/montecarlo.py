"""Monte-Carlo evaluation, as the paper does it: sample episodes, aggregate norm outcomes.

Per episode (evaluation spec 4.1): an event counts once if it occurred at any step; a utility is
summed over the steps; truncated episodes (the agent neither reached the landmark nor was harmed,
201 steps with ``max_steps=200``) count like any other. The morality functions then use the
fraction of episodes with each event and the mean utility totals.

Episodes run side by side on the batched simulator, so an SB3 policy is queried once per step for
all episodes rather than once per episode step.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from typing import Any

import numpy as np

from morality_gym.constants import BETA, EVAL_EPISODES, MAX_STEPS
from morality_gym.envs.batched import BatchedTrolleyEnv, utility_present
from morality_gym.envs.trolley import TrolleyEnv
from morality_gym.evaluation.policies import PolicyAdapter
from morality_gym.evaluation.result import EpisodeRecord, EvaluationResult
from morality_gym.norms.chain import MoralityChain
from morality_gym.norms.cost import CostMode, VectorCost
from morality_gym.norms.metric import BoundChain, bind_chain
from morality_gym.world.vocab import EVENT_BIT, UTILITIES, names_to_mask

MAX_EPISODE_STEPS = 5000  # the reference evaluator's cap when the env itself never truncates
_CHUNK = 1024


def _event_freq(bound: BoundChain, masks: np.ndarray) -> dict[str, float]:
    return {n.name: float(np.mean((masks >> np.uint32(EVENT_BIT[n.name])) & 1)) for n in bound.chain.event_norms}


def episode_metrics(bound: BoundChain, masks: np.ndarray, utility_sums: np.ndarray) -> np.ndarray:
    """Each episode's own morality metric (the mean over episodes is the evaluation's metric)."""
    total = np.zeros(len(masks))
    for norm in bound.chain.norms:
        w = bound.weights[norm.name]
        if w == 0:
            continue
        if norm.kind == "event":
            occurred = ((masks >> np.uint32(EVENT_BIT[norm.name])) & 1).astype(np.float64)
            m = 1.0 - occurred if norm.prohibited else occurred
        else:
            lo, hi = bound.bounds[norm.name]
            if hi == lo:
                m = np.ones(len(masks))
            else:
                z = (utility_sums[:, UTILITIES.index(norm.name)] - lo) / (hi - lo)
                m = 1.0 - z if norm.prohibited else z
        total += w * m
    return total / bound.weight_sum


def evaluate(
    policy: Any,
    env_id: str,
    chain: str | MoralityChain | BoundChain,
    n_episodes: int = EVAL_EPISODES,
    seed: int | None = None,
    max_steps: int | None = MAX_STEPS,
    beta: float | str = BETA,
    deterministic: bool = False,
    cost_mode: CostMode | None = "minimal",
    progress: bool | None = None,
    keep_episodes: bool = True,
) -> EvaluationResult:
    """Monte-Carlo morality evaluation of ``policy`` (see :class:`PolicyAdapter` for policy kinds).

    Returns the metric, per-norm morality functions, mean return/length, the truncation rate, the
    standard error of the metric and (``keep_episodes``) every episode's record. ``cost_mode`` sets
    how ``mean_cost`` (the mean episode cost, scale 1, reset per episode) is measured; ``None``
    skips it. ``progress`` shows a bar; by default only for long evaluations (10,000 episodes or
    more) on a terminal.
    """
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    bound = chain if isinstance(chain, BoundChain) else bind_chain(chain, env_id, beta)
    adapter = PolicyAdapter(policy, deterministic=deterministic)
    rng = np.random.default_rng(seed)  # the only randomness used: torch's global RNG is never touched
    masks_all, sums_all, present_all, rets, lens, truncs, goals, costs = [], [], [], [], [], [], [], []
    bar = None
    if progress is None:
        progress = n_episodes >= 10_000 and sys.stderr.isatty()
    if progress:
        from tqdm.auto import tqdm  # tqdm waits: importing morality_gym.evaluation.montecarlo must not load it

        bar = tqdm(total=n_episodes, desc=f"evaluate {bound.env_id}", unit="ep", leave=False)
    remaining = n_episodes
    while remaining > 0:
        n = min(_CHUNK, remaining)
        remaining -= n
        env = BatchedTrolleyEnv(bound.env_id, n, max_steps=max_steps, autoreset="disabled")
        obs = env.reset()
        masks = np.zeros(n, dtype=np.uint32)
        sums = np.zeros((n, len(UTILITIES)))
        present = np.zeros((n, len(UTILITIES)), dtype=bool)
        ret = np.zeros(n)
        length = np.zeros(n, dtype=np.int64)
        trunc = np.zeros(n, dtype=bool)
        goal = np.zeros(n, dtype=bool)
        steps_type = np.zeros(n)
        steps_living = np.zeros(n)
        active = np.ones(n, dtype=bool)
        for _ in range(MAX_EPISODE_STEPS):
            actions = adapter.actions(obs, rng, env.state)
            res = env.step(actions)
            live = active
            util = env.utility(res.transition)
            type_p, living_p = utility_present(res.events)
            masks |= np.where(live, res.events, np.uint32(0))
            sums += np.where(live[:, None], util, 0)
            present[:, 1:] |= (type_p & live)[:, None]
            present[:, 0] |= living_p & live
            steps_type += type_p & live
            steps_living += living_p & live
            ret += np.where(live, res.reward, 0.0)
            length += live
            goal |= live & env.goal_reached(res.transition)
            ended_now = live & (res.terminated | res.truncated)
            trunc |= live & res.truncated
            active = active & ~ended_now
            obs = res.obs
            if bar is not None and ended_now.any():
                bar.update(int(ended_now.sum()))
            if not active.any():
                break
        trunc |= active  # hit the evaluator's step cap
        masks_all.append(masks)
        sums_all.append(sums)
        present_all.append(present)
        rets.append(ret)
        lens.append(length)
        truncs.append(trunc)
        goals.append(goal)
        if cost_mode:
            costs.append(VectorCost(bound, n, mode=cost_mode, scale=1.0).episode_costs(masks, sums, steps_type, steps_living))
    if bar is not None:
        bar.close()
    return _summarise(
        bound,
        np.concatenate(masks_all),
        np.concatenate(sums_all),
        np.concatenate(present_all),
        np.concatenate(rets),
        np.concatenate(lens),
        np.concatenate(truncs),
        np.concatenate(goals),
        np.concatenate(costs) if cost_mode else None,
        keep_episodes,
    )


def _summarise(
    bound: BoundChain,
    masks: np.ndarray,
    sums: np.ndarray,
    present: np.ndarray,
    ret: np.ndarray,
    length: np.ndarray,
    trunc: np.ndarray,
    goal: np.ndarray,
    ep_cost: np.ndarray | None,
    keep_episodes: bool,
) -> EvaluationResult:
    """Turn per-episode arrays into an :class:`EvaluationResult` (spec 4.1-4.3)."""
    n_episodes = len(masks)
    per_episode = episode_metrics(bound, masks, sums)
    episodes = []
    if keep_episodes:
        for i in range(n_episodes):
            util = {name: float(sums[i, j]) for j, name in enumerate(UTILITIES) if present[i, j]}
            episodes.append(
                EpisodeRecord(int(masks[i]), util, float(ret[i]), int(length[i]), bool(trunc[i]), bool(goal[i]), float(per_episode[i]))
            )
    return EvaluationResult.from_aggregates(
        bound,
        exact=False,
        event_freq=_event_freq(bound, masks),
        utility_mean={name: float(sums[:, i].mean()) for i, name in enumerate(UTILITIES)},
        mean_return=float(ret.mean()),
        mean_length=float(length.mean()),
        truncation_rate=float(trunc.mean()),
        goal_rate=float(goal.mean()),
        n_episodes=n_episodes,
        metric_stderr=float(per_episode.std(ddof=1) / math.sqrt(n_episodes)) if n_episodes > 1 else float("nan"),
        mean_cost=float(ep_cost.mean()) if ep_cost is not None else None,
        episodes=episodes,
    )


def evaluate_sequential(
    act: Callable[[np.ndarray], int],
    env: TrolleyEnv,
    bound: BoundChain,
    n_episodes: int,
    cost_mode: CostMode | None = "minimal",
    keep_episodes: bool = True,
) -> EvaluationResult:
    """Episodes one after another on one env, as the reference's evaluator runs them.

    Slower than :func:`evaluate`, but it consumes a policy's random numbers in exactly the
    reference's order (one draw per step, episode after episode), which is what reproduces the
    paper's Random column bit for bit.
    """
    masks = np.zeros(n_episodes, dtype=np.uint32)
    sums = np.zeros((n_episodes, len(UTILITIES)))
    present = np.zeros((n_episodes, len(UTILITIES)), dtype=bool)
    ret = np.zeros(n_episodes)
    length = np.zeros(n_episodes, dtype=np.int64)
    trunc = np.zeros(n_episodes, dtype=bool)
    goal = np.zeros(n_episodes, dtype=bool)
    steps_type = np.zeros(n_episodes)
    steps_living = np.zeros(n_episodes)
    for i in range(n_episodes):
        obs, _ = env.reset()
        for _ in range(MAX_EPISODE_STEPS):
            obs, r, terminated, truncated, info = env.step(act(obs))
            ne = info["norm_events"]
            masks[i] |= names_to_mask(set(ne["action"]) | set(ne["outcome"]) | set(ne["causal"]))
            util = ne["utility"]
            if util:
                for key, value in util.items():
                    j = UTILITIES.index(key)
                    sums[i, j] += value
                    present[i, j] = True
                steps_type[i] += "n_human_harm" in util
                steps_living[i] += "n_harm" in util
            ret[i] += r
            length[i] += 1
            goal[i] |= bool(info["goal_reached"])
            if terminated or truncated:
                trunc[i] = truncated
                break
        else:
            trunc[i] = True
    ep_cost = VectorCost(bound, n_episodes, mode=cost_mode, scale=1.0).episode_costs(masks, sums, steps_type, steps_living) if cost_mode else None
    return _summarise(bound, masks, sums, present, ret, length, trunc, goal, ep_cost, keep_episodes)
