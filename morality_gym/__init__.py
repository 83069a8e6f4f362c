"""MoralityGym: trolley-dilemma gridworlds, morality chains and a lexicographic morality metric.

``import morality_gym`` registers every env id with Gymnasium as
``MoralityGym/{Scenario}-{Variant}-v1``.
"""

from __future__ import annotations

import importlib

from morality_gym.api import make
from morality_gym.envs.batched import BatchedTrolleyEnv
from morality_gym.envs.registration import add_scenario_dir, register_all
from morality_gym.envs.registry import UnknownEnvError, env_ids, list_envs, parse_env_id, scenarios
from morality_gym.envs.trolley import InvalidActionError, TrolleyEnv
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.montecarlo import evaluate
from morality_gym.evaluation.oracle import oracle
from morality_gym.norms.chain import ChainError, MoralityChain, builtin_chains, get_chain
from morality_gym.norms.cost import VectorCost
from morality_gym.norms.metric import BoundChain, bind_chain
from morality_gym.world.rules import ACTION_NAMES

__version__ = "0.1.0"

register_all()

# These import Stable-Baselines3 or torch (~1.5 s); load them only when first used.
_LAZY = {
    "TorchCostWrapper": "morality_gym.norms.torch_vector_cost",
    "TorchTrolleyVectorEnv": "morality_gym.envs.torch_vector",
    "TrolleyVecEnv": "morality_gym.envs.vector",
    "TrolleyVectorEnv": "morality_gym.envs.vector",
    "MoralityWrapper": "morality_gym.norms.wrappers",
    "RewardCostSpec": "morality_gym.norms.wrappers",
    "VecMoralityWrapper": "morality_gym.norms.wrappers",
    # Generated splits (Pillow, for their pictures): loaded when first asked for, like the above.
    "load_split": "morality_gym.generator.splits",
}


def __getattr__(name: str) -> object:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'morality_gym' has no attribute {name!r}")

__all__ = [
    "ACTION_NAMES",
    "BatchedTrolleyEnv",
    "BoundChain",
    "ChainError",
    "InvalidActionError",
    "MoralityChain",
    "MoralityWrapper",
    "RewardCostSpec",
    "TorchCostWrapper",
    "TorchTrolleyVectorEnv",
    "TrolleyEnv",
    "TrolleyVecEnv",
    "TrolleyVectorEnv",
    "UnknownEnvError",
    "VecMoralityWrapper",
    "VectorCost",
    "add_scenario_dir",
    "bind_chain",
    "builtin_chains",
    "env_ids",
    "evaluate",
    "exact_evaluate",
    "get_chain",
    "list_envs",
    "load_split",
    "make",
    "oracle",
    "parse_env_id",
    "scenarios",
]
