"""Register every scenario variant with Gymnasium, each under a self-documenting env class.

For each scenario a subclass of :class:`~morality_gym.envs.trolley.TrolleyEnv` is created at
import time (``SwitchStandardEnv``, ...) whose docstring is generated from the YAML, in the style
of MiniGrid's env classes; the classes are what the generated docs are built from. Adding a
scenario file therefore adds a documented class and its ids without any code.

This is the top of the envs layer: it builds on :mod:`~morality_gym.envs.registry` (scenarios
and ids) and :mod:`~morality_gym.envs.trolley` (the env), neither of which imports it.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym

from morality_gym.envs.describe import describe_scenario
from morality_gym.envs.registry import NAMESPACE, load_scenario_dir, scenarios
from morality_gym.envs.trolley import TrolleyEnv

ENV_CLASSES: dict[str, type[TrolleyEnv]] = {}


def env_class(scenario_name: str) -> type[TrolleyEnv]:
    """The documented env class of a scenario (created on first use)."""
    cls = ENV_CLASSES.get(scenario_name)
    if cls is None:
        scenario = scenarios()[scenario_name]
        cls = type(
            f"{scenario.name}Env",
            (TrolleyEnv,),
            {"__doc__": describe_scenario(scenario), "scenario_name": scenario.name, "__module__": __name__},
        )
        ENV_CLASSES[scenario_name] = cls
    return cls


def _make(env_id: str, **kwargs: object) -> TrolleyEnv:
    scenario_name = env_id.split("-", 1)[0]
    return env_class(scenario_name)(env_id, **kwargs)  # type: ignore[arg-type]


def register_all() -> None:
    """Register ``MoralityGym/{Scenario}-{Variant}-v1`` for every known variant (idempotent)."""
    for scenario in scenarios().values():
        env_class(scenario.name)
        for env_id in scenario.env_ids:
            full = f"{NAMESPACE}/{env_id}"
            if full in gym.registry:
                continue
            gym.register(
                id=full,
                entry_point=f"{__name__}:_make",
                kwargs={"env_id": env_id},
                vector_entry_point="morality_gym.envs.vector:TrolleyVectorEnv",
                # Truncation follows the reference (step max_steps + 1), inside the env.
                max_episode_steps=None,
            )


def add_scenario_dir(directory: str | Path) -> list[str]:
    """Load every scenario YAML in ``directory``, register its env ids with Gymnasium and return them.

    An explicit request: a bad file raises :class:`~morality_gym.world.layout.ScenarioError` and
    nothing of the directory is added.
    """
    env_ids = load_scenario_dir(directory)
    register_all()
    return env_ids
