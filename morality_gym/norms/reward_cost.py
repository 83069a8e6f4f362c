"""How a learner sees reward and cost (:class:`RewardCostSpec`), apart from the wrappers that apply it.

Why its own module: the learner specs (:mod:`morality_gym.baselines.specs`) and through them the
configuration readers (``runners.compose.search_path``, which the leaderboard asks for a preset's seeds) need
this small dataclass, and the wrappers import Stable-Baselines3 and with it torch (about a second
of every leaderboard build). :mod:`morality_gym.norms.wrappers` re-exports both names.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from morality_gym.norms.cost import CostMode, ResetPolicy

PAPER_RETURN_BOUNDS = (-300.0, 100.0)


@dataclass(frozen=True)
class RewardCostSpec:
    """How a learner sees reward and cost (one per learner in the paper's runs)."""

    cost_mode: CostMode = "minimal"
    cost_scale: float = 1.0
    cost_reset: ResetPolicy = "per_episode"
    normalise_reward: bool = True
    return_bounds: tuple[float, float] = PAPER_RETURN_BOUNDS
    shape_reward: bool = False

    @property
    def reward_factor(self) -> float:
        lo, hi = self.return_bounds
        return max(abs(lo), abs(hi)) if self.normalise_reward else 1.0

    def transform(self, reward: np.ndarray | float, cost: np.ndarray | float) -> Any:
        """The reward the learner trains on."""
        r = reward / self.reward_factor
        if not self.shape_reward:
            return r
        if self.normalise_reward:
            return (r - cost) / (1.0 + self.cost_scale)
        return r - cost
