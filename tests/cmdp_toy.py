"""A tiny constrained MDP for testing the constrained learners: two routes from a fork.

::

    fork --RISKY--> r1 --> r2 (hazard: cost 1) --> goal   reward 1.0
         --SAFE---> s1 --> s2                  --> goal   reward 0.8
         --WAIT---> fork                                  reward -0.01, no cost

Actions: 0 = RISKY, 1 = SAFE, 2 = WAIT. At the fork they choose the route (WAIT stays); on a route
every action moves one cell on, so the only decision is the one at the fork, three steps before
its consequences. Each step costs a small time penalty (-0.01), so a reward maximiser takes the
risky route (return about 0.97 against 0.77), and a learner that keeps the episode cost at 0 must
take the safe one. Episodes are truncated after ``max_episode_steps`` (only reachable by waiting),
so time-limit truncation is exercised too.

Observations are one-hot ``Box`` vectors over the seven cells; the cost is in ``info["cost"]``
(absent when ``emit_cost=False``, to test the error raised then).
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

RISKY, SAFE, WAIT = 0, 1, 2
FORK, R1, R2, S1, S2 = 0, 1, 2, 3, 4
N_CELLS = 5
ROUTE_LENGTH = 3  # steps from the fork to either goal
RISKY_REWARD, SAFE_REWARD, STEP_PENALTY = 1.0, 0.8, -0.01
HAZARD_COST = 1.0


class TwoRouteCMDP(gym.Env[np.ndarray, int]):
    """The fork/two-route CMDP described in the module docstring."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}

    def __init__(self, max_episode_steps: int = 8, emit_cost: bool = True) -> None:
        self.observation_space = spaces.Box(0.0, 1.0, shape=(N_CELLS,), dtype=np.float32)
        self.action_space = spaces.Discrete(3)
        self.max_episode_steps = max_episode_steps
        self.emit_cost = emit_cost
        self._cell = FORK
        self._t = 0

    def _obs(self) -> np.ndarray:
        obs = np.zeros(N_CELLS, dtype=np.float32)
        obs[self._cell] = 1.0
        return obs

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._cell, self._t = FORK, 0
        return self._obs(), {}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        action = int(action)
        if not self.action_space.contains(action):
            raise ValueError(f"invalid action {action!r}")
        self._t += 1
        reward, cost, terminated = STEP_PENALTY, 0.0, False
        if self._cell == FORK:
            self._cell = {RISKY: R1, SAFE: S1, WAIT: FORK}[action]
        elif self._cell == R1:
            self._cell, cost = R2, HAZARD_COST
        elif self._cell == S1:
            self._cell = S2
        else:  # R2 or S2: the next step reaches the goal
            reward += RISKY_REWARD if self._cell == R2 else SAFE_REWARD
            terminated = True
        truncated = not terminated and self._t >= self.max_episode_steps
        info: dict[str, Any] = {"cost": cost} if self.emit_cost else {}
        return self._obs(), reward, terminated, truncated, info


def fork_observation() -> np.ndarray:
    """The observation at the fork, as a batch of one."""
    obs = np.zeros((1, N_CELLS), dtype=np.float32)
    obs[0, FORK] = 1.0
    return obs


def all_observations() -> np.ndarray:
    """Every cell's observation, one row each (for exact action-probability comparisons)."""
    return np.eye(N_CELLS, dtype=np.float32)
