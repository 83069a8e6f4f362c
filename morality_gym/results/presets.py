"""Presets (``conf/preset/<name>.yaml``): how much each run trains and evaluates, and which seeds make a cell whole.

A sweep composes a preset into its configuration (``runners.compose.schema.Sweep.preset``); readers
of results that compose nothing (the leaderboard's cells, ``leaderboard.submit``) read the same
file over the same schema here: :func:`load_preset`, and :func:`preset_seeds` for the seeds a
complete Table 1 cell has.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import yaml

from morality_gym.baselines import typed
from morality_gym.baselines.specs import CONF_DIR
from morality_gym.clitools import did_you_mean


@dataclass(frozen=True)
class Preset:
    """How much each run trains and evaluates (``conf/preset/<name>.yaml``).

    ``rollout_cap``: the most environment steps any learner collects per update (``n_steps`` x
    ``n_envs``); a learner whose rollout is longer gets ``n_steps = rollout_cap // n_envs``. It
    applies to every learner, a user's too, which ``algo_overrides`` (keyed by algo name) cannot.
    """

    name: str
    seeds: tuple[int, ...]
    budget: int
    eval_episodes: int
    learn_eval_every: int
    learn_eval_episodes: int
    budget_overrides: Mapping[str, int] = field(default_factory=dict)
    algo_overrides: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    rollout_cap: int | None = None

    def __post_init__(self) -> None:
        where = f"preset={self.name}"
        if not self.seeds:
            raise ValueError(f"{where}.seeds: expected a non-empty list of integers, got []")
        for key, minimum in (("budget", 0), ("eval_episodes", 1), ("learn_eval_every", 0), ("learn_eval_episodes", 1)):
            if getattr(self, key) < minimum:
                raise ValueError(f"{where}.{key}: expected an integer >= {minimum}, got {getattr(self, key)!r}")
        for seed in self.seeds:
            if seed < 0:
                raise ValueError(f"{where}.seeds: expected integers >= 0, got {seed!r}")
        for scenario, value in self.budget_overrides.items():
            if value < 0:
                raise ValueError(f"{where}.budget_overrides.{scenario}: expected an integer >= 0, got {value!r}")
        if self.rollout_cap is not None and self.rollout_cap < 1:
            raise ValueError(f"{where}.rollout_cap: expected an integer >= 1 or null, got {self.rollout_cap!r}")

    def budget_for(self, scenario: str) -> int:
        return int(self.budget_overrides.get(scenario, self.budget))


class PresetError(ValueError):
    """An unknown or invalid preset file; one line naming the file and the fix."""


def preset_names() -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / "preset").glob("*.yaml"))


def load_preset(name: str) -> Preset:
    """``conf/preset/<name>.yaml`` over the :class:`Preset` schema, checked as a sweep checks it:
    for readers that do not compose a sweep (``leaderboard.submit``, the leaderboard's seeds)."""
    path = CONF_DIR / "preset" / f"{name}.yaml"
    if not path.is_file():
        names = preset_names()
        hint = did_you_mean(name, names, n=3, quote=False)
        raise PresetError(f"no {path}{hint}; presets: {', '.join(names)}")
    try:
        values = yaml.safe_load(path.read_text()) or {}
        return typed.build(Preset, typed.merge(Preset, values, where=str(path)), where=str(path))
    except (OSError, yaml.YAMLError, typed.TypedConfigError, ValueError, TypeError) as exc:
        raise PresetError(f"{path}: {' '.join(str(exc).split())}") from exc


@cache
def preset_seeds(preset: str) -> tuple[int, ...] | None:
    """The seeds of ``conf/preset/<preset>.yaml`` (None if there is no such preset or it is invalid)."""
    try:
        return load_preset(preset).seeds
    except PresetError:
        return None
