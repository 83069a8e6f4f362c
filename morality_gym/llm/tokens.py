"""How many tokens the text view costs, to price a run before paying for it.

A provider reports the tokens it bills (the agent loop counts those). Before a run, and offline,
only an estimate exists: :func:`estimate_tokens` uses the usual rule of thumb of four characters
per token for English text with OpenAI-style tokenizers. The map rows (``#..P..G``) tokenize worse
than prose, so treat the estimate as a lower bound of about 10-30%; Inspect's own count needs the
``o200k_base`` tokenizer file, a download.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from morality_gym.envs.trolley import TrolleyEnv
from morality_gym.evaluation.oracle import oracle
from morality_gym.llm.settings import AgentSettings
from morality_gym.llm.wrapper import TextObservation
from morality_gym.norms.chain import MoralityChain

CHARS_PER_TOKEN = 4


def estimate_tokens(text: str) -> int:
    """Rule-of-thumb token count of ``text`` (at least 1 for non-empty text)."""
    return math.ceil(len(text) / CHARS_PER_TOKEN) if text else 0


@dataclass(frozen=True)
class ViewCost:
    """The size of one env's text view along one episode."""

    env_id: str
    system_chars: int
    view_chars: int  # one observation, on average over the episode
    steps: int
    episode_input_tokens: int  # what the model reads over the episode, with the settings' window
    episode_calls: int


def view_cost(env_id: str, chain: MoralityChain, settings: AgentSettings, actions: list[int] | None = None) -> ViewCost:
    """Characters and estimated input tokens of an episode that plays ``actions`` (default: the
    oracle's best sequence for ``chain``, a short, successful episode), one call per step."""
    env = TextObservation(TrolleyEnv(env_id, max_steps=settings.max_steps), settings.framing, chain)
    system = env.system_prompt(settings.answer)
    obs, _ = env.reset()
    views = [obs]
    for a in actions if actions is not None else oracle(env_id, chain).best.actions:
        obs, _, terminated, truncated, _ = env.step(a)
        views.append(obs)
        if terminated or truncated:
            break
    steps = len(views) - 1
    answer = len("ACTION: INTERACT")
    tokens = 0
    for t in range(steps):  # call t reads the system message and the window of views and answers up to it
        first = 0 if settings.window is None else max(0, t + 1 - settings.window)
        shown = views[first : t + 1]
        tokens += estimate_tokens(system) + sum(estimate_tokens(v) for v in shown) + (len(shown) - 1) * math.ceil(answer / CHARS_PER_TOKEN)
    return ViewCost(env_id, len(system), round(sum(map(len, views)) / len(views)), steps, tokens, steps)
