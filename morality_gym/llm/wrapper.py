"""A Gymnasium wrapper whose observations are the text view (:mod:`morality_gym.llm.text`).

Why a wrapper and not an ``obs_type``: the text of a step says what *happened* in it (who moved,
who was pushed, who was hit), which needs the state before the step and the action; the env's
observation is a function of the state alone. The wrapper keeps that one previous state and leaves
the env's rewards, flags and ``info`` (norm events included) untouched, so the agent loop scores an
episode exactly as every other policy is scored.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
from gymnasium import spaces

from morality_gym.envs.trolley import TrolleyEnv
from morality_gym.llm.text import check_framing, render_view, system_prompt, what_happened
from morality_gym.norms.chain import MoralityChain

#: The longest views of the 98 envs are about 1,300 characters (Switch7); the space allows three times that.
MAX_VIEW_CHARS = 4096


class TextObservation(gym.Wrapper[str, int, Any, int]):
    """Observations as text: ``reset`` and ``step`` return :func:`~morality_gym.llm.text.render_view`."""

    def __init__(self, env: TrolleyEnv, framing: str = "named", chain: MoralityChain | None = None) -> None:
        super().__init__(env)
        self.framing = check_framing(framing)
        self.chain = chain
        self.trolley: TrolleyEnv = env
        self.observation_space = spaces.Text(max_length=MAX_VIEW_CHARS, charset=frozenset(map(chr, range(10, 127))))
        self._notes: list[str] = []

    @property
    def horizon(self) -> int | None:
        """The last step an episode can have (the env truncates on step ``max_steps + 1``)."""
        return None if self.trolley.max_steps is None else self.trolley.max_steps + 1

    def system_prompt(self, answer: str = "word") -> str:
        return system_prompt(self.trolley.world, self.framing, self.chain, answer)

    def note(self, sentence: str) -> None:
        """A sentence the next observation states first (the agent loop reports a fallback this way)."""
        self._notes.append(sentence)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[str, dict[str, Any]]:
        _, info = self.env.reset(seed=seed, options=options)
        self._notes = []
        return render_view(self.trolley.world, self.trolley.state, 0, self.horizon, self.framing), info

    def step(self, action: int) -> tuple[str, SupportsFloat, bool, bool, dict[str, Any]]:
        before = self.trolley.state
        _, reward, terminated, truncated, info = self.env.step(action)
        happened = [*self._notes, *what_happened(self.trolley.world, before, int(action), self.trolley.state, self.framing)]
        self._notes = []
        text = render_view(self.trolley.world, self.trolley.state, self.trolley.elapsed_steps, self.horizon, self.framing,
                           happened, ended=bool(terminated or truncated))
        return text, reward, terminated, truncated, info
