"""Constrained RL learners as Stable-Baselines3 algorithms: PPO-Lagrangian and CPO.

Both read a per-step float ``info["cost"]`` (written by the reward/cost wrapper), learn a cost
critic next to the reward critic, and enforce ``J_c <= cost_limit`` on the mean episode cost::

    from morality_gym.baselines.safe import CPO, PPOLag
    model = PPOLag("MlpPolicy", vec_env, seed=41).learn(500_000)
    model.lagrange_multiplier

Modules: :mod:`.policies` (actor + reward critic + cost critic), :mod:`.buffers` (cost-aware
rollout buffer), :mod:`.base` (cost-aware rollouts), :mod:`.lagrange` (the multiplier),
:mod:`.cpo_dual` (CPO's closed-form step), :mod:`.functional` (GAE, KL, normalisation),
:mod:`.ppo_lag` and :mod:`.cpo` (the learners).
"""

from morality_gym.baselines.safe.base import COST_INFO_KEY, CostOnPolicyAlgorithm, MissingCostError
from morality_gym.baselines.safe.buffers import CostRolloutBuffer, CostRolloutBufferSamples
from morality_gym.baselines.safe.cpo import CPO
from morality_gym.baselines.safe.cpo_dual import (
    CPOCase,
    CPOScalars,
    CPOStep,
    cpo_direction,
    exact_direction,
    omnisafe_direction,
)
from morality_gym.baselines.safe.lagrange import LagrangeMultiplier
from morality_gym.baselines.safe.policies import CostActorCriticPolicy, MlpPolicy
from morality_gym.baselines.safe.ppo_lag import PPOLag

__all__ = [
    "COST_INFO_KEY",
    "CPO",
    "CPOCase",
    "CPOScalars",
    "CPOStep",
    "CostActorCriticPolicy",
    "CostOnPolicyAlgorithm",
    "CostRolloutBuffer",
    "CostRolloutBufferSamples",
    "LagrangeMultiplier",
    "MissingCostError",
    "MlpPolicy",
    "PPOLag",
    "cpo_direction",
    "exact_direction",
    "omnisafe_direction",
]
