"""MoralityGym: trolley-dilemma gridworlds, morality chains and a lexicographic morality metric.

``import morality_gym`` registers every env id with Gymnasium as
``MoralityGym/{Scenario}-{Variant}-v1``.
"""

from __future__ import annotations

from morality_gym.envs.registration import register_all
from morality_gym.envs.registry import UnknownEnvError, add_scenario_dir, list_envs, parse_env_id, scenarios
from morality_gym.envs.trolley import InvalidActionError, TrolleyEnv
from morality_gym.world.rules import ACTION_NAMES

__version__ = "0.1.0"

register_all()

__all__ = [
    "ACTION_NAMES",
    "InvalidActionError",
    "TrolleyEnv",
    "UnknownEnvError",
    "add_scenario_dir",
    "list_envs",
    "parse_env_id",
    "scenarios",
]
