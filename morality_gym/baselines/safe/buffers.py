"""A rollout buffer that carries a cost stream next to the reward stream.

The cost is a second reward signal with its own critic ``V_c``, its own discount
(``cost_gamma``) and its own GAE parameter (``cost_gae_lambda``); returns and advantages are
computed with the very same recursion as for rewards (:func:`.functional.gae`).
"""

from __future__ import annotations

from collections.abc import Generator
from typing import NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.vec_env import VecNormalize

from morality_gym.baselines.safe.functional import gae


class CostRolloutBufferSamples(NamedTuple):
    """A minibatch: SB3's ``RolloutBufferSamples`` fields plus the cost-stream fields."""

    observations: th.Tensor
    actions: th.Tensor
    old_values: th.Tensor
    old_log_prob: th.Tensor
    advantages: th.Tensor
    returns: th.Tensor
    old_cost_values: th.Tensor
    cost_advantages: th.Tensor
    cost_returns: th.Tensor


class CostRolloutBuffer(RolloutBuffer):
    """:class:`~stable_baselines3.common.buffers.RolloutBuffer` that also stores costs, cost values,
    cost returns and cost advantages.

    :param cost_gamma: discount of the cost stream (0.99 in the paper's runs).
    :param cost_gae_lambda: GAE lambda of the cost stream (0.95 in the paper's runs).

    The other parameters are SB3's.
    """

    costs: np.ndarray
    cost_values: np.ndarray
    cost_returns: np.ndarray
    cost_advantages: np.ndarray

    _FLAT_FIELDS = (
        "observations",
        "actions",
        "values",
        "log_probs",
        "advantages",
        "returns",
        "cost_values",
        "cost_advantages",
        "cost_returns",
    )

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        gae_lambda: float = 1,
        gamma: float = 0.99,
        n_envs: int = 1,
        cost_gamma: float = 0.99,
        cost_gae_lambda: float = 0.95,
    ):
        self.cost_gamma = cost_gamma
        self.cost_gae_lambda = cost_gae_lambda
        super().__init__(buffer_size, observation_space, action_space, device, gae_lambda, gamma, n_envs)

    def reset(self) -> None:
        shape = (self.buffer_size, self.n_envs)
        self.costs = np.zeros(shape, dtype=np.float32)
        self.cost_values = np.zeros(shape, dtype=np.float32)
        self.cost_returns = np.zeros(shape, dtype=np.float32)
        self.cost_advantages = np.zeros(shape, dtype=np.float32)
        super().reset()

    def add(  # type: ignore[override]
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        episode_start: np.ndarray,
        value: th.Tensor,
        log_prob: th.Tensor,
        cost: np.ndarray,
        cost_value: th.Tensor,
    ) -> None:
        """SB3's ``add`` plus this step's cost (already bootstrapped on truncation) and ``V_c(s)``."""
        # Written before super().add, which advances self.pos.
        self.costs[self.pos] = np.asarray(cost, dtype=np.float32)
        self.cost_values[self.pos] = cost_value.clone().cpu().numpy().flatten()
        super().add(obs, action, reward, episode_start, value, log_prob)

    def compute_returns_and_advantage(  # type: ignore[override]
        self,
        last_values: th.Tensor,
        dones: np.ndarray,
        last_cost_values: th.Tensor | None = None,
    ) -> None:
        """GAE for both streams. ``last_cost_values`` is ``V_c`` of the observation after the
        rollout; it is required (it only defaults to ``None`` to keep SB3's signature)."""
        if last_cost_values is None:
            raise ValueError(
                "CostRolloutBuffer needs last_cost_values (V_c of the last observation) to bootstrap costs"
            )
        last_v = last_values.clone().cpu().numpy().flatten()
        last_vc = last_cost_values.clone().cpu().numpy().flatten()
        self.advantages, self.returns = gae(
            self.rewards, self.values, self.episode_starts, last_v, dones, self.gamma, self.gae_lambda
        )
        self.cost_advantages, self.cost_returns = gae(
            self.costs, self.cost_values, self.episode_starts, last_vc, dones, self.cost_gamma, self.cost_gae_lambda
        )

    def get(self, batch_size: int | None = None) -> Generator[CostRolloutBufferSamples, None, None]:  # type: ignore[override]
        """Shuffled minibatches over all ``n_steps * n_envs`` transitions (one batch if ``None``)."""
        assert self.full, "the rollout buffer must be full before sampling"
        total = self.buffer_size * self.n_envs
        indices = np.random.permutation(total)
        if not self.generator_ready:
            for name in self._FLAT_FIELDS:
                self.__dict__[name] = self.swap_and_flatten(self.__dict__[name])
            self.generator_ready = True
        batch_size = total if batch_size is None else batch_size
        for start in range(0, total, batch_size):
            yield self._get_samples(indices[start : start + batch_size])

    def _get_samples(  # type: ignore[override]
        self, batch_inds: np.ndarray, env: VecNormalize | None = None
    ) -> CostRolloutBufferSamples:
        data = (
            self.observations[batch_inds],
            self.actions[batch_inds].astype(np.float32, copy=False),
            self.values[batch_inds].flatten(),
            self.log_probs[batch_inds].flatten(),
            self.advantages[batch_inds].flatten(),
            self.returns[batch_inds].flatten(),
            self.cost_values[batch_inds].flatten(),
            self.cost_advantages[batch_inds].flatten(),
            self.cost_returns[batch_inds].flatten(),
        )
        return CostRolloutBufferSamples(*(self.to_torch(x) for x in data))
