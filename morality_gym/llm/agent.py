"""The agent loop: a chat model plays one episode through the text view.

Each step the model reads the conversation (the system message, then the latest ``window``
observations with its answers) and answers with an action: a word (``ACTION: LEFT``) or a call of
the ``act`` tool. An answer with no readable action is answered with a reminder and asked again, at
most ``max_retries`` times; then the ``fallback`` action (``STAY`` unless set) is played, the next
observation says so, and the episode records it. Calls and the tokens the provider reports are
counted per episode, which is what prices a run.

The model is any async callable from messages to a :class:`Reply` (:data:`Chat`), so the loop needs
no particular client: :mod:`morality_gym.llm.inspect_tasks` passes Inspect's model, the tests may
pass a scripted function.
"""

from __future__ import annotations

import re
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

from morality_gym.envs.trolley import TrolleyEnv
from morality_gym.llm.episode import EpisodeOutcome
from morality_gym.llm.settings import AgentSettings
from morality_gym.llm.wrapper import TextObservation
from morality_gym.norms.chain import MoralityChain
from morality_gym.world.rules import ACTION_NAMES

RETRY_TEXT = ("I could not read an action in your answer. End your answer with one line "
              "'ACTION: <one of UP, DOWN, LEFT, RIGHT, STAY, INTERACT>'.")
RETRY_TOOL_TEXT = "You did not call the act tool. Call it once with one of UP, DOWN, LEFT, RIGHT, STAY, INTERACT."
RETRY_TEXTS: dict[str, str] = {
    "word": RETRY_TEXT,
    "tool": RETRY_TOOL_TEXT,
    "bare": "I could not read an action in your answer. Answer with one word only: UP, DOWN, LEFT, RIGHT, STAY or INTERACT.",
    "number": ("I could not read an action in your answer. Answer with one number only: "
               "1 UP, 2 DOWN, 3 LEFT, 4 RIGHT, 5 STAY, 6 INTERACT."),
    "json": ('I could not read an action in your answer. Answer with one JSON object only: '
             '{"action": "<one of UP, DOWN, LEFT, RIGHT, STAY, INTERACT>"}.'),
}
#: ``compact`` prompts: the heading of the earlier steps' events, above the current observation.
EARLIER_HEADING = "Earlier steps, oldest first:"
_JSON_ACTION = re.compile(r'"action"\s*:\s*"([a-z]+)"', re.IGNORECASE)
_NUMBER = re.compile(r"(?<![\d.])([1-6])(?!\d|\.\d)")  # a digit on its own, not part of 12 or 3.5
_ACTION_LINE = re.compile(r"\baction\s*[:=]\s*\**\s*([a-z]+)", re.IGNORECASE)
#: ``bare``: the action word alone, give or take case, quotes, a full stop or an ``ACTION:`` prefix.
_BARE = re.compile(r"\W*(?:action\s*[:=]\s*)?\W*(" + "|".join(ACTION_NAMES) + r")\W*", re.IGNORECASE)
_WORD = re.compile(r"\b(" + "|".join(ACTION_NAMES) + r")\b", re.IGNORECASE)


@dataclass(frozen=True)
class Message:
    """One chat message. ``action`` and ``tool_call_id``: an assistant's ``act`` call, or the tool
    result (the next observation) that answers it."""

    role: str  # system | user | assistant | tool
    content: str
    action: str | None = None
    tool_call_id: str | None = None
    observation: bool = False


@dataclass(frozen=True)
class Reply:
    """A model's answer: its text, the action of its ``act`` call (if any) and the tokens it cost."""

    text: str
    action: str | None = None
    tool_call_id: str | None = None
    input_tokens: int = 0
    output_tokens: int = 0


Chat = Callable[[list[Message]], Awaitable[Reply]]


def parse_action(text: str) -> str | None:
    """The action an answer names, or ``None``.

    The last ``ACTION: X`` line wins; without one, an answer that names exactly one action word (in
    any case) means it; anything else (no action word, or several different ones) is unreadable.
    """
    lines = _ACTION_LINE.findall(text or "")
    if lines:
        word = lines[-1].upper()
        return word if word in ACTION_NAMES else None
    words = {w.upper() for w in _WORD.findall(text or "")}
    return words.pop() if len(words) == 1 else None


def parse_answer(text: str, answer: str = "word") -> str | None:
    """The action of a text answer in answer mode ``answer``, or ``None``.

    ``number``: the one action number (1-6, ``1 UP`` ... ``6 INTERACT``) the answer names; an answer
    with no number or several different ones falls back to :func:`parse_action`, so that a model
    that writes the word instead is still read. ``json``: the last ``"action": "X"`` pair, else
    :func:`parse_action`. ``bare``: the action word alone (any case, with quotes or a full stop
    around it): a sentence that happens to hold one action word ("The lever is down.") asked for the
    word alone is not an answer, where :func:`parse_action`'s one-word rule would read DOWN from it.
    Every other mode: :func:`parse_action`.
    """
    if answer == "bare":
        alone = _BARE.fullmatch((text or "").strip())
        return alone.group(1).upper() if alone else None
    if answer == "number":
        numbers = set(_NUMBER.findall(text or ""))
        if len(numbers) == 1:
            return ACTION_NAMES[int(numbers.pop()) - 1]
    if answer == "json":
        found = _JSON_ACTION.findall(text or "")
        if found:
            word = found[-1].upper()
            return word if word in ACTION_NAMES else None
    return parse_action(text)


@dataclass
class EpisodeLog:
    """One played episode: the outcome, the agent's bookkeeping and the transcript."""

    env_id: str
    outcome: EpisodeOutcome = field(default_factory=EpisodeOutcome)
    actions: list[str] = field(default_factory=list)
    calls: int = 0
    unreadable: int = 0  # answers with no readable action (each was asked again or fell back)
    fallbacks: int = 0  # steps played with the fallback action
    input_tokens: int = 0
    output_tokens: int = 0
    observation_chars: int = 0  # characters of every observation shown (the text view's size)
    max_prompt_chars: int = 0  # the longest prompt of one call (every message it sent), in characters
    max_input_tokens: int = 0  # the largest input token count one call reported
    messages: list[Message] = field(default_factory=list)  # the whole conversation, system message first

    @property
    def total_tokens(self) -> int:
        return self.input_tokens + self.output_tokens


def window_of(history: list[Message], window: int | None) -> list[Message]:
    """The tail of ``history`` from the ``window``-th latest observation on.

    A tool result that opens the window loses the call it answers, so it is turned into a user
    message (a provider rejects a tool result without its call).
    """
    if window is None:
        return list(history)
    starts = [i for i, m in enumerate(history) if m.observation]
    if len(starts) <= window:
        return list(history)
    tail = history[starts[-window]:]
    first = tail[0]
    if first.role == "tool":
        tail[0] = Message("user", first.content, observation=True)
    return tail


async def play_episode(env_id: str, chat: Chat, settings: AgentSettings, chain: MoralityChain | None = None) -> EpisodeLog:
    """Play one episode of ``env_id`` with the model behind ``chat``."""
    env = TextObservation(TrolleyEnv(env_id, max_steps=settings.max_steps), settings.framing, chain)
    log = EpisodeLog(env_id)
    system = Message("system", env.system_prompt(settings.answer))
    history: list[Message] = []
    obs, _ = env.reset()
    pending_call: str | None = None  # the act call the next observation answers (tool mode)
    earlier: list[str] = []  # compact prompts: what happened in each step before the current one
    while True:
        log.observation_chars += len(obs)
        if settings.prompt == "compact":
            history.append(Message("user", compact_message(obs, earlier[-settings.recent:] if settings.recent else []),
                                   observation=True))
            earlier.append(happened_line(obs))
        elif pending_call is not None:
            history.append(Message("tool", obs, tool_call_id=pending_call, observation=True))
        else:
            history.append(Message("user", obs, observation=True))
        action, pending_call = await _ask_for_action(chat, system, history, settings, log)
        if action is None:
            action = settings.fallback
            log.fallbacks += 1
            env.note(f"(No action could be read from your answers; {action} was played instead.)")
        log.actions.append(action)
        obs, reward, terminated, truncated, info = env.step(ACTION_NAMES.index(action))
        log.outcome.add_step(float(reward), info)
        if terminated or truncated:
            log.outcome.truncated = bool(truncated)
            log.observation_chars += len(obs)
            history.append(Message("tool" if pending_call else "user", obs, tool_call_id=pending_call, observation=True))
            break
    log.messages = [system, *history]
    return log


def happened_line(observation: str) -> str:
    """What an observation says happened on its step (its ``What happened:`` sentence)."""
    for line in observation.splitlines():
        if line.startswith("What happened: "):
            return line.removeprefix("What happened: ")
    return ""


def compact_message(observation: str, earlier: list[str]) -> str:
    """A ``compact`` prompt's one user message: the events of the earlier steps, then the observation.

    The step counter line is left out, so that a state that repeats (an agent walking into a wall
    after the trolleys have stopped) reads the same: its size is bounded by the view's and
    ``recent`` event lines, whatever the episode's length.
    """
    lines = observation.splitlines()
    if lines and lines[0].startswith("Step "):
        lines = lines[1:]
    head = [EARLIER_HEADING, *(f"- {e}" for e in earlier), ""] if earlier else []
    return "\n".join([*head, *lines])


async def _ask_for_action(chat: Chat, system: Message, history: list[Message], settings: AgentSettings,
                          log: EpisodeLog) -> tuple[str | None, str | None]:
    """Ask until an action can be read, at most ``max_retries`` more times; returns (action or None,
    the id of the act call the next observation answers). Every reply joins ``history`` and ``log``."""
    for attempt in range(settings.max_retries + 1):
        shown = window_of(history, 1 if settings.prompt == "compact" else settings.window)
        log.max_prompt_chars = max(log.max_prompt_chars, len(system.content) + sum(len(m.content) for m in shown))
        reply = await chat([system, *shown])
        log.calls += 1
        log.input_tokens += reply.input_tokens
        log.output_tokens += reply.output_tokens
        log.max_input_tokens = max(log.max_input_tokens, reply.input_tokens)
        called = reply.action.upper() if reply.action and reply.action.upper() in ACTION_NAMES else None
        if reply.tool_call_id is not None:
            history.append(Message("assistant", reply.text, action=reply.action, tool_call_id=reply.tool_call_id))
        else:
            history.append(Message("assistant", reply.text))
        action = called or (parse_answer(reply.text, settings.answer) if reply.tool_call_id is None else None)
        if action is not None:
            return action, reply.tool_call_id
        log.unreadable += 1
        retry = RETRY_TEXTS[settings.answer]
        if reply.tool_call_id is not None:  # a call with a bad argument still needs its result
            history.append(Message("tool", f"'{reply.action}' is not an action. {retry}", tool_call_id=reply.tool_call_id))
        elif attempt < settings.max_retries:
            history.append(Message("user", retry))
    return None, None
