"""Scenario names in either spelling: ``SwitchStandard`` (its name) or ``switch_standard`` (its file).

The sweep's config files are named in snake case and the environments in CamelCase; a user should
not have to remember which command wants which, so every command accepts any spelling that
differs only in case, underscores and hyphens (:func:`find_scenario`).
"""

from __future__ import annotations

import re

from morality_gym.envs.registry import scenario_named, scenarios
from morality_gym.world.layout import Scenario


def snake(name: str) -> str:
    """``Push2OrSwitch`` -> ``push2_or_switch`` (the file name of a scenario)."""
    return re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", name).lower()


def squash(name: str) -> str:
    return name.replace("_", "").replace("-", "").lower()


def find_scenario(name: str) -> Scenario:
    """The scenario called ``name`` in either spelling; unknown names raise as
    :func:`~morality_gym.envs.registry.scenario_named` does (with the closest names)."""
    known = scenarios()
    if name in known:
        return known[name]
    for candidate, scenario in known.items():
        if squash(candidate) == squash(name):
            return scenario
    return scenario_named(name)
