"""Language-model agents on the MoralityGym dilemmas.

:mod:`.text` turns a world state into text (and back); :mod:`.wrapper` is the Gymnasium wrapper
whose observations are that text; :mod:`.agent` is the chat-model agent loop (retries, fallback,
token and call counts); :mod:`.settings` holds every default of the agent and the episode presets;
:mod:`.episode` scores one played episode with a morality chain; :mod:`.tokens` estimates what a run
costs. None of these import Inspect AI: :mod:`.inspect_tasks` (the ``llm`` extra) adapts them to
Inspect's tasks, solvers and scorers, and is therefore not imported here.
"""

from __future__ import annotations

from morality_gym.llm.agent import EpisodeLog, Message, Reply, parse_action, play_episode
from morality_gym.llm.episode import EpisodeOutcome, score_episode
from morality_gym.llm.settings import PRESETS, AgentSettings, EpisodePreset
from morality_gym.llm.text import FRAMINGS, parse_view, render_view, system_prompt, visible_state
from morality_gym.llm.tokens import estimate_tokens, view_cost
from morality_gym.llm.wrapper import TextObservation

__all__ = [
    "FRAMINGS",
    "PRESETS",
    "AgentSettings",
    "EpisodeLog",
    "EpisodeOutcome",
    "EpisodePreset",
    "Message",
    "Reply",
    "TextObservation",
    "estimate_tokens",
    "parse_action",
    "parse_view",
    "play_episode",
    "render_view",
    "score_episode",
    "system_prompt",
    "view_cost",
    "visible_state",
]
