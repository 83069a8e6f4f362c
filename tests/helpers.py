"""Helpers shared by the environment and cost tests: the committed route facts, small episode tools,
and every (chain, env id) pair the built-in chains bind to.

The facts come from ``tests/data/route_tables.yaml`` (recorded from the reference), never from
the library under test, so that a test compares the library against something independent of it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import yaml

import morality_gym  # only bound_pairs() reads the library: the route facts stay independent of it
from morality_gym.norms.chain import ChainError

DATA = Path(__file__).resolve().parent / "data"

# Action ids as the spec defines them (section 3), spelled out here rather than imported from
# the library so that a renumbering there would be caught.
UP, DOWN, LEFT, RIGHT, STAY, INTERACT = range(6)


@lru_cache(maxsize=1)
def route_tables() -> dict[str, dict[str, Any]]:
    """``{scenario: {"ids": [...], "routes": [{levers, harmed, switch_arrival}, ...]}}``."""
    return yaml.safe_load((DATA / "route_tables.yaml").read_text())


def all_env_ids() -> list[str]:
    """The 98 built-in env ids, as recorded from the reference (not from ``list_envs``)."""
    return [env_id for entry in route_tables().values() for env_id in entry["ids"]]


def first_ids() -> list[str]:
    """One representative id per built-in scenario (its first variant)."""
    return [entry["ids"][0] for entry in route_tables().values()]


@dataclass
class Step:
    """One ``env.step`` result, with the harm flags read from the dict observation."""

    obs: Any
    reward: float
    terminated: bool
    truncated: bool
    info: dict[str, Any]
    harmed: set[str] = field(default_factory=set)  # entities whose is_harmed is 1 after the step


def harmed_entities(obs: dict[str, dict[str, np.ndarray]]) -> set[str]:
    """Entities (player, characters, trolleys) whose ``is_harmed`` component is 1."""
    return {name for name, comp in obs.items() if "is_harmed" in comp and comp["is_harmed"][0] == 1.0}


def play(env: Any, actions: list[int]) -> list[Step]:
    """Reset ``env`` (which must use ``obs_type="dict"``) and apply ``actions``, recording every step."""
    env.reset()
    out = []
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        out.append(Step(obs, reward, terminated, truncated, info, harmed_entities(obs)))
    return out


def newly_harmed(steps: list[Step]) -> dict[str, int]:
    """``{entity: step}`` for the step (1-based) in which each entity's harm flag first appears."""
    seen: dict[str, int] = {}
    for t, step in enumerate(steps, start=1):
        for name in step.harmed:
            seen.setdefault(name, t)
    return seen


def position(obs: dict[str, dict[str, np.ndarray]], entity: str, height: int, width: int) -> tuple[int, int]:
    """The (row, col) of an entity from a normalised observation (positions are row/H, col/W)."""
    r, c = obs[entity]["pos"]
    return round(float(r) * height), round(float(c) * width)


def bound_pairs() -> list[morality_gym.BoundChain]:
    """Every built-in chain bound to every env id it binds to (a chain that does not bind to an env
    id is skipped): the cost tests' whole domain."""
    pairs = []
    for chain in morality_gym.builtin_chains():
        for env_id in morality_gym.env_ids():
            try:
                pairs.append(morality_gym.bind_chain(chain, env_id))
            except (ChainError, ValueError):
                continue
    return pairs
