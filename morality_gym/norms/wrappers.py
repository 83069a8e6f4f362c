"""Wrappers that put the moral cost into ``info`` and normalise or shape the reward.

Evaluation spec section 6.1. Each step:

* ``info["orig_reward"]`` = the environment's reward ``r``; ``info["cost"]`` = the cost ``c``;
* the reward becomes ``r / F`` with ``F = max(|lo|, |hi|)`` of the return bounds (``[-300, 100]``
  in every run of the paper, so ``F = 300``), or ``r`` if normalisation is off;
* with shaping (PPO-Shaped) it becomes ``(r / F - c) / (1 + scale)`` (or ``r - c`` without
  normalisation); the cost already carries the scale, so the paper's runs train on
  ``(r / 300 - 50 c) / 51``.

:class:`MoralityWrapper` wraps a single Gymnasium env; :class:`VecMoralityWrapper` wraps an SB3
``VecEnv`` (on :class:`~morality_gym.envs.vector.TrolleyVecEnv` it works on the batched arrays
directly, elsewhere it reads ``info["norm_events"]``).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from morality_gym.norms.cost import VectorCost
from morality_gym.norms.metric import BoundChain
from morality_gym.norms.reward_cost import PAPER_RETURN_BOUNDS, RewardCostSpec  # noqa: F401 - re-exported
from morality_gym.world.vocab import UTILITIES, names_to_mask

#: The paper's default (frozen, so one shared instance is a safe default argument).
DEFAULT_SPEC = RewardCostSpec()


class MoralityWrapper(gym.Wrapper):
    """Adds ``info["cost"]`` and ``info["orig_reward"]`` to a single env; normalises/shapes reward."""

    def __init__(self, env: gym.Env, bound: BoundChain, spec: RewardCostSpec = DEFAULT_SPEC) -> None:
        super().__init__(env)
        self.bound = bound
        self.reward_cost = spec
        self.cost = VectorCost(bound, 1, mode=spec.cost_mode, scale=spec.cost_scale, reset=spec.cost_reset)

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        if self.reward_cost.cost_reset == "per_episode":
            self.cost.reset()
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        cost = self.cost.from_norm_events(info["norm_events"], ended=terminated or truncated)
        info["orig_reward"] = reward
        info["cost"] = cost
        return obs, float(self.reward_cost.transform(reward, cost)), terminated, truncated, info


class VecMoralityWrapper(VecEnvWrapper):
    """The same for SB3 vectorised envs; per-copy cost memories, reset when a copy's episode ends."""

    def __init__(self, venv: VecEnv, bound: BoundChain, spec: RewardCostSpec = DEFAULT_SPEC) -> None:
        super().__init__(venv)
        self.bound = bound
        self.reward_cost = spec
        self.cost = VectorCost(bound, venv.num_envs, mode=spec.cost_mode, scale=spec.cost_scale, reset=spec.cost_reset)
        self._batched = hasattr(venv, "last_step") and hasattr(venv, "batch")

    def reset(self) -> Any:
        if self.reward_cost.cost_reset == "per_episode":
            self.cost.reset()
        return self.venv.reset()

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        if self._batched:
            res = self.venv.last_step  # type: ignore[attr-defined]
            events, utility = res.events, self.venv.batch.utility(res.transition)  # type: ignore[attr-defined]
            present = None
        else:
            n = len(infos)
            events = np.zeros(n, dtype=np.uint32)
            utility = np.zeros((n, len(UTILITIES)), dtype=np.float64)
            type_present = np.zeros(n, dtype=bool)
            living_present = np.zeros(n, dtype=bool)
            for i, info in enumerate(infos):
                ne = info["norm_events"]
                events[i] = names_to_mask(set(ne["action"]) | set(ne["outcome"]) | set(ne["causal"]))
                util = ne["utility"]
                utility[i] = [util.get(name, 0) for name in UTILITIES]
                type_present[i] = "n_human_harm" in util
                living_present[i] = "n_harm" in util
            present = (type_present, living_present)
        costs = self.cost(events, utility, dones, present)
        for info, r, c in zip(infos, rewards.tolist(), costs.tolist()):
            info["orig_reward"] = r
            info["cost"] = c
        new_rewards = np.asarray(self.reward_cost.transform(rewards.astype(np.float64), costs), dtype=np.float32)
        return obs, new_rewards, dones, infos
