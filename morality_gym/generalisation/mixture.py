"""A Gymnasium env whose episodes are dilemmas drawn from a pool: one policy for every dilemma.

Each :meth:`DilemmaMixtureEnv.reset` draws one ``(env id, chain)`` pair of the pool uniformly with
the env's own generator (seeded by ``seed``, or by ``reset(seed=...)``), so the sequence of
dilemmas is a function of the seed alone. Every dilemma is seen through ``obs_type="grid"`` (one
``uint8`` shape ``(20, 16, 16)`` for all of them) and the reward is the one the learner's spec
trains on (:class:`~morality_gym.norms.wrappers.MoralityWrapper`: ``r / 300`` for PPO, the shaped
reward for PPO-Shaped), with the pair's chain giving the cost. ``info["env_id"]`` and
``info["chain"]`` name the drawn dilemma.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from morality_gym.api import make
from morality_gym.constants import BETA, MAX_STEPS
from morality_gym.norms.reward_cost import RewardCostSpec
from morality_gym.norms.wrappers import MoralityWrapper
from morality_gym.world.grid_observe import GridCodec

#: Envs kept alive at once (each keeps the grids of the states it met): enough for a split's
#: frequent redraws without holding all 1,458 train envs' grids in memory.
ENV_CACHE = 256


class DilemmaMixtureEnv(gym.Env):
    """Episodes drawn from ``pairs`` (``(env_id, chain_name)``), seen as grids (module docstring)."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}

    def __init__(
        self,
        pairs: Sequence[tuple[str, str]],
        seed: int = 0,
        reward_cost: RewardCostSpec | None = None,
        max_steps: int | None = MAX_STEPS,
        beta: float = BETA,
    ) -> None:
        if not pairs:
            raise ValueError("DilemmaMixtureEnv needs at least one (env id, chain) pair")
        self.pairs = [(str(e), str(c)) for e, c in pairs]
        self.reward_cost = reward_cost or RewardCostSpec()
        self.max_steps = max_steps
        self.beta = beta
        self.observation_space = GridCodec.space()
        self.action_space = gym.spaces.Discrete(6)
        self._draws = np.random.default_rng(seed)
        self._envs: OrderedDict[tuple[str, str], MoralityWrapper] = OrderedDict()
        self._current: MoralityWrapper | None = None
        self.current_pair: tuple[str, str] | None = None

    def draw(self) -> tuple[str, str]:
        """The next pair of the seed's sequence."""
        return self.pairs[int(self._draws.integers(len(self.pairs)))]

    def _env(self, pair: tuple[str, str]) -> MoralityWrapper:
        env = self._envs.get(pair)
        if env is None:
            base, bound = make(pair[0], pair[1], beta=self.beta, obs_type="grid", max_steps=self.max_steps)
            env = MoralityWrapper(base, bound, self.reward_cost)
            self._envs[pair] = env
            while len(self._envs) > ENV_CACHE:
                self._envs.popitem(last=False)
        else:
            self._envs.move_to_end(pair)
        return env

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self._draws = np.random.default_rng(seed)
        self.current_pair = self.draw()
        self._current = self._env(self.current_pair)
        obs, info = self._current.reset()
        return obs, {**info, "env_id": self.current_pair[0], "chain": self.current_pair[1]}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._current is None:
            raise RuntimeError("call reset() before step()")
        obs, reward, terminated, truncated, info = self._current.step(action)
        assert self.current_pair is not None
        info["env_id"], info["chain"] = self.current_pair
        return obs, float(reward), terminated, truncated, info
