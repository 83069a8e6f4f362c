"""Register every scenario variant with Gymnasium, each under a self-documenting env class.

For each scenario a subclass of :class:`~morality_gym.envs.trolley.TrolleyEnv` is created at
import time (``SwitchStandardEnv``, ...) whose docstring is generated from the YAML, in the style
of MiniGrid's env classes; the classes are what the generated docs are built from. Adding a
scenario file therefore adds a documented class and its ids without any code.

This is the top of the envs layer: it builds on :mod:`~morality_gym.envs.registry` (scenarios
and ids) and :mod:`~morality_gym.envs.trolley` (the env), neither of which imports it.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

import gymnasium as gym
from gymnasium.vector import VectorEnv

from morality_gym.envs.describe import describe_scenario
from morality_gym.envs.registry import BUILTIN_DIR, NAMESPACE, load_scenario_dir, scenarios
from morality_gym.envs.trolley import TrolleyEnv

ENV_CLASSES: dict[str, type[TrolleyEnv]] = {}
_CLASS_SUFFIX = "Env"


def _reduce_env(env: TrolleyEnv) -> tuple[Any, ...]:
    """How a per-scenario env pickles: its class is made at run time, so it is named by its
    scenario (and, for a user's scenario, the file that defines it, which a fresh process such as
    a spawned vector-env worker loads first), and rebuilt by :func:`_rebuild_env`."""
    source = Path(env.scenario.source)
    user_file = None if source.resolve().parent == BUILTIN_DIR.resolve() else str(source.resolve())
    return _rebuild_env, (env.scenario.name, user_file), env.__getstate__()


def _rebuild_env(scenario_name: str, user_file: str | None) -> TrolleyEnv:
    """An empty instance of the scenario's env class, for pickle to fill (``__setstate__``)."""
    if scenario_name not in scenarios() and user_file is not None:
        add_scenario_dir(Path(user_file).parent)
    cls = env_class(scenario_name)
    return cls.__new__(cls)


def __getattr__(name: str) -> type[TrolleyEnv]:
    """``from morality_gym.envs.registration import SwitchStandardEnv``: the env classes are made
    from the scenario files, so they are found by name here rather than defined in the source."""
    if name.endswith(_CLASS_SUFFIX) and name[: -len(_CLASS_SUFFIX)] in scenarios():
        return env_class(name[: -len(_CLASS_SUFFIX)])
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def env_class(scenario_name: str) -> type[TrolleyEnv]:
    """The documented env class of a scenario (created on first use)."""
    cls = ENV_CLASSES.get(scenario_name)
    if cls is None:
        scenario = scenarios()[scenario_name]
        cls = type(
            f"{scenario.name}{_CLASS_SUFFIX}",
            (TrolleyEnv,),
            {"__doc__": describe_scenario(scenario), "scenario_name": scenario.name, "__module__": __name__,
             "__reduce__": _reduce_env},
        )
        ENV_CLASSES[scenario_name] = cls
    return cls


def _make(env_id: str, **kwargs: object) -> TrolleyEnv:
    scenario_name = env_id.split("-", 1)[0]
    return env_class(scenario_name)(env_id, **kwargs)  # type: ignore[arg-type]


def make_vector(env_id: str, num_envs: int = 1, *, device: Any = None, **kwargs: Any) -> VectorEnv:
    """``gym.make_vec``'s entry point: the numpy :class:`~morality_gym.envs.vector.TrolleyVectorEnv`,
    or with ``device=`` (``"cuda"``, ``"cpu"``, ...) the torch
    :class:`~morality_gym.envs.torch_vector.TorchTrolleyVectorEnv` with ``num_envs`` copies of ``env_id``.

    The modules are imported here, when asked for: the numpy one loads Stable-Baselines3, the torch
    one torch, and ``import morality_gym`` (which registers the ids) must load neither.
    """
    if device is None:
        return importlib.import_module("morality_gym.envs.vector").TrolleyVectorEnv(env_id, num_envs, **kwargs)
    torch_vector = importlib.import_module("morality_gym.envs.torch_vector")
    return torch_vector.TorchTrolleyVectorEnv([env_id], copies_per_env=num_envs, device=device, **kwargs)


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
                vector_entry_point=f"{__name__}:make_vector",
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
