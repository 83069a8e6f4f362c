"""Every default of the language-model agent and of its episode presets, in one place.

The Inspect tasks (:mod:`morality_gym.llm.inspect_tasks`), the command line (``python -m
leaderboard.llm``) and the docs read these; nothing else spells a default out.
"""

from __future__ import annotations

from dataclasses import dataclass

from morality_gym.clitools import did_you_mean
from morality_gym.constants import EVAL_EPISODES, MAX_STEPS, SEED
from morality_gym.llm.text import check_framing
from morality_gym.world.rules import ACTION_NAMES

ANSWER_MODES: tuple[str, ...] = ("word", "tool", "bare", "number", "json")
#: ``transcript``: the conversation (the latest ``window`` observations with the answers between
#: them); ``compact``: one user message per call, the current observation after the events of the
#: ``recent`` steps before it, whose size does not grow with the episode (for small models).
PROMPT_MODES: tuple[str, ...] = ("transcript", "compact")


class SettingsError(ValueError):
    """A setting of the agent or a preset name is invalid; the message names it."""


@dataclass(frozen=True)
class AgentSettings:
    """How the agent talks to the model.

    ``temperature`` ``None``: the provider's default, or Inspect's ``--temperature`` (most hosted chat
    models then sample at 1.0: the model's own stochastic policy, as the paper evaluates the RL
    baselines' stochastic policies); a number sets it for every call. The value used is recorded with
    the leaderboard entry either way. ``seed``: episode ``k`` of a variant asks the
    provider for seed ``seed + k`` (where the provider supports seeds), so episodes differ and reruns
    match. ``window``: how many of the latest observations (with the answers after them) the model
    sees besides the system message; ``None`` keeps the whole episode (a 201-step episode then costs
    quadratically many tokens: see docs/llm-agents.md). ``max_retries``: re-asks after an answer with
    no readable action, each one call; then ``fallback`` is played and counted. ``prompt``
    ``compact`` replaces the conversation by one bounded message (:data:`PROMPT_MODES`; ``window`` then
    does not apply) that lists what happened in the ``recent`` steps before the current observation.
    """

    framing: str = "named"
    answer: str = "word"
    window: int | None = 8
    max_retries: int = 2
    fallback: str = "STAY"
    temperature: float | None = None
    seed: int = SEED
    max_tokens: int | None = 512
    max_steps: int = MAX_STEPS
    prompt: str = "transcript"
    recent: int = 3

    def __post_init__(self) -> None:
        try:
            check_framing(self.framing)
        except ValueError as exc:
            raise SettingsError(str(exc)) from exc
        if self.answer not in ANSWER_MODES:
            raise SettingsError(f"answer {self.answer!r} is unknown; answer modes: {', '.join(ANSWER_MODES)}")
        if self.fallback not in ACTION_NAMES:
            hint = did_you_mean(str(self.fallback).upper(), ACTION_NAMES, quote=False)
            raise SettingsError(f"fallback {self.fallback!r} is not an action{hint}; actions: {', '.join(ACTION_NAMES)}")
        if self.prompt not in PROMPT_MODES:
            raise SettingsError(f"prompt {self.prompt!r} is unknown; prompt modes: {', '.join(PROMPT_MODES)}")
        if self.recent < 0:
            raise SettingsError(f"recent must be >= 0, got {self.recent}")
        if self.window is not None and self.window < 1:
            raise SettingsError(f"window must be at least 1 (or None for the whole episode), got {self.window}")
        if self.max_retries < 0:
            raise SettingsError(f"max_retries must be >= 0, got {self.max_retries}")
        if self.max_steps < 0:
            raise SettingsError(f"max_steps must be >= 0, got {self.max_steps}")


@dataclass(frozen=True)
class EpisodePreset:
    """How many episodes of each variant a run plays (one Inspect sample per episode)."""

    name: str
    episodes: int
    note: str


#: ``paid``: 5 episodes per variant (a chain's Table 1 cells cost about 5 x 98 / 11 ... episodes; see
#: docs/llm-agents.md for prices); ``paper``: the 100 episodes of the paper's final evaluation.
PRESETS: dict[str, EpisodePreset] = {
    "paid": EpisodePreset("paid", 5, f"5 episodes per variant (for paid models; the RL baselines use {EVAL_EPISODES})"),
    "paper": EpisodePreset("paper", EVAL_EPISODES, f"{EVAL_EPISODES} episodes per variant, as the paper's final evaluation"),
}
DEFAULT_PRESET = "paid"


def preset_named(name: str) -> EpisodePreset:
    """The preset called ``name``; a one-line error with the close match otherwise."""
    if name in PRESETS:
        return PRESETS[name]
    hint = did_you_mean(name, PRESETS, quote=False)
    raise SettingsError(f"preset {name!r} is unknown{hint}; presets: {', '.join(PRESETS)}")
