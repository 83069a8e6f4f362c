"""The training environment of a fleet: every run's copies in one simulator, each run's own cost.

What a single run's learner sees through ``TrolleyVecEnv -> VecMonitor -> VecMoralityWrapper``, for
``K`` runs at once: copy ``k * n_envs + i`` is env ``i`` of run ``k``, on run ``k``'s env id (the
variants may differ, :class:`~morality_gym.envs.mixed.MixedBatchedTrolleyEnv`). The cost of a step
is the run's chain's (runs on the same env id and chain share one
:class:`~morality_gym.norms.cost.VectorCost` over their copies; its memory is per copy), and the
reward is the learner's transform of the env reward and that cost, exactly as the wrapper computes
them. Nothing is exchanged between runs except the arrays they are stepped in.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from morality_gym.constants import MAX_STEPS
from morality_gym.envs.mixed import MixedBatchedTrolleyEnv
from morality_gym.norms.cost import StackedCost, VectorCost
from morality_gym.norms.metric import BoundChain
from morality_gym.norms.wrappers import RewardCostSpec


class FleetStep(NamedTuple):
    """One step of all copies (arrays of length ``K * n_envs``)."""

    obs: np.ndarray  # float32 [N, obs_dim], after auto-reset
    rewards: np.ndarray  # float32: the reward the learner trains on
    costs: np.ndarray  # float64: the step-wise moral cost
    dones: np.ndarray  # terminated | truncated
    truncated: np.ndarray  # truncated and not terminated (SB3's "TimeLimit.truncated")
    final_obs: np.ndarray | None  # last observations of the ended copies (auto-reset), else None


class FleetEnv:
    """``n_envs`` copies per run for every bound chain in ``bounds`` (one per run)."""

    def __init__(self, bounds: Sequence[BoundChain], n_envs: int, reward_cost: RewardCostSpec, max_steps: int | None = MAX_STEPS) -> None:
        self.n_runs = len(bounds)
        self.n_envs = n_envs
        self.reward_cost = reward_cost
        self.sim = MixedBatchedTrolleyEnv([b.env_id for b in bounds for _ in range(n_envs)], max_steps=max_steps)
        self.obs_dim = self.sim.obs_dim
        groups: dict[tuple[str, str, float], list[int]] = {}
        for k, b in enumerate(bounds):
            groups.setdefault((b.env_id, b.chain.name, float(b.beta)), []).append(k)
        self._costs: list[tuple[np.ndarray, VectorCost]] = []
        for runs in groups.values():
            copies = np.concatenate([np.arange(k * n_envs, (k + 1) * n_envs) for k in runs])
            cost = VectorCost(
                bounds[runs[0]], len(copies), mode=reward_cost.cost_mode, scale=reward_cost.cost_scale, reset=reward_cost.cost_reset
            )
            self._costs.append((copies, cost))
        # all groups in one pass (the same bits as the loop over groups; None with a prescribed norm)
        self._stacked = StackedCost.of_groups(self._costs, self.n_runs * n_envs)
        self._all = np.ones(self.n_runs * n_envs, dtype=bool)

    def state_dict(self) -> dict[str, Any]:
        """Everything stepping changes: the simulator's copies and every cost memory (the stacked
        one, or one per group). Nothing here draws random numbers. For a training checkpoint."""
        costs = [self._stacked.state_dict()] if self._stacked is not None else [cost.state_dict() for _, cost in self._costs]
        return {"sim": self.sim.state_dict(), "costs": costs}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict` into a simulator built for the same runs."""
        owners = [self._stacked] if self._stacked is not None else [cost for _, cost in self._costs]
        if len(state["costs"]) != len(owners):
            raise ValueError(f"cost memories: expected {len(owners)}, got {len(state['costs'])}")
        self.sim.load_state_dict(state["sim"])
        for owner, memory in zip(owners, state["costs"]):
            owner.load_state_dict(memory)

    def copies_of(self, runs: np.ndarray) -> np.ndarray:
        """Boolean mask over the copies of the runs where ``runs`` (``[K]`` bool) is true."""
        return np.repeat(np.asarray(runs, dtype=bool), self.n_envs)

    def reset(self, runs: np.ndarray | None = None) -> np.ndarray:
        """Reset every copy (or the copies of the runs where ``runs`` is true); returns all observations.

        As ``VecMoralityWrapper.reset``: the cost memory of the reset copies is cleared only under
        the ``per_episode`` policy (under ``never`` it survives, as in the paper's runs).
        """
        mask = None if runs is None else self.copies_of(runs)
        if self.reward_cost.cost_reset == "per_episode":
            if self._stacked is not None:
                self._stacked.reset(mask)
            else:
                for copies, cost in self._costs:
                    cost.reset(None if mask is None else mask[copies])
        return self.sim.reset(mask)

    def step(self, actions: np.ndarray) -> FleetStep:
        res = self.sim.step(actions)
        dones = res.terminated | res.truncated
        utility = self.sim.utility(res.transition)
        if self._stacked is not None:
            costs = self._stacked(res.events, utility, dones)
        else:
            costs = np.empty(len(dones), dtype=np.float64)
            for copies, cost in self._costs:
                costs[copies] = cost(res.events[copies], utility[copies], dones[copies])
        rewards = np.asarray(self.reward_cost.transform(res.reward.astype(np.float64), costs), dtype=np.float32)
        return FleetStep(res.obs, rewards, costs, dones, res.truncated & ~res.terminated, res.final_obs)
