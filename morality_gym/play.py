"""``python -m morality_gym play ENV_ID [--policy P]``: play a dilemma yourself, or watch an agent.

Playing an environment by hand is the quickest way to understand a scenario (and to check that
it does what its description says), so every step prints what an agent would receive: the
picture, the reward, the running return, the step's norm events and who has stopped.

Keys: ``w a s d`` (or the arrow keys) move, space or ``.`` waits, ``e`` interacts (pull the
adjacent levers, push the adjacent pushable groups), ``r`` restarts, ``q`` quits, ``?`` helps.
On a terminal single key presses are read (cbreak mode, always restored); otherwise one line is
read at a time and every character in it is a key, so that tests and scripts can drive a game
through a pipe (``printf 'ed\\n' | python -m morality_gym play ...``).

With ``--policy`` (anything ``eval --policy`` takes: ``random``, a saved model, ``file.py:function``
or ``module:function``, see :mod:`morality_gym.baselines.policy_ref`) the agent plays instead: the same
per-step output, ``--delay`` seconds apart, for ``--episodes`` episodes; ``--render out.gif``
writes the episodes as GIFs instead (``record_episode``), ``--render window`` also shows them in a
window. Probabilities are sampled with a generator seeded by ``--seed``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import sys
import termios
import time
import tty
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from morality_gym.baselines.io import ModelError
from morality_gym.baselines.policy_ref import PolicyError, load_policy, probe
from morality_gym.clitools import non_negative_int, one_line, positive_int
from morality_gym.constants import MAX_STEPS
from morality_gym.envs.registry import UnknownEnvError
from morality_gym.envs.trolley import InvalidActionError, TrolleyEnv
from morality_gym.evaluation.gif import record_episode
from morality_gym.evaluation.policies import PolicyFailure, step_actor
from morality_gym.render.ansi import render_ansi
from morality_gym.world.rules import ACTION_NAMES, DOWN, FOUND, HARMED, INTERACT, LEFT, RIGHT, STAY, UP
from morality_gym.world.vocab import EVENTS

QUIT, RESTART, HELP = "quit", "restart", "help"

#: Key -> action number or command. Arrow keys arrive as escape sequences, see _tokens().
KEYS: dict[str, int | str] = {
    "w": UP,
    "a": LEFT,
    "s": DOWN,
    "d": RIGHT,
    " ": STAY,
    ".": STAY,
    "e": INTERACT,
    "r": RESTART,
    "q": QUIT,
    "?": HELP,
    "\x03": QUIT,  # Ctrl-C / Ctrl-D as raw bytes, in case the terminal delivers them as keys
    "\x04": QUIT,
}
_ARROWS = {"A": UP, "B": DOWN, "C": RIGHT, "D": LEFT}

HELP_TEXT = """\
keys: w/up  a/left  s/down  d/right  move     space or .  stay     e  interact (levers, push)
      r  restart     q  quit     ?  this help
picture: P agent (X harmed)  T trolley (t stopped)  h a r human/animal/robot group
         (H A R: pushable, x: harmed)  G landmark  / lever  < > ^ v rails (a switch shows its setting)  # wall"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``play`` sub-command's arguments (the main CLI owns the parser)."""
    parser.add_argument("env_id", help="environment id, e.g. SwitchStandard-HumanA-v1 (see morality_gym.list_envs())")
    parser.add_argument(
        "--max-steps",
        type=int,  # a negative one is refused by the env, with its message (exit 2)
        default=MAX_STEPS,
        help=f"truncate the episode on step max_steps + 1, as the environment does (default: {MAX_STEPS})",
    )
    parser.add_argument(
        "--policy",
        default=None,
        help="watch an agent instead of playing: 'random', a saved model (model.zip), path/to/file.py:function "
             "or package.module:function (a callable obs -> action or 6 probabilities)",
    )
    parser.add_argument("--episodes", type=_positive_int, default=1, help="with --policy: episodes to watch (default 1)")
    parser.add_argument(
        "--delay",
        type=_delay,
        default=DEFAULT_DELAY,
        help=f"with --policy: seconds between steps in the terminal (default {DEFAULT_DELAY}; 0 = no pause)",
    )
    parser.add_argument("--seed", type=non_negative_int, default=None, help="with --policy: seed of the action sampling")
    parser.add_argument(
        "--render",
        default=None,
        metavar="OUT.gif|window",
        help="with --policy: write each episode to a GIF (OUT.gif; OUT-2.gif, ... for more episodes) "
             "or also show it in a window ('window')",
    )
    parser.add_argument(
        "--allow-other-env",
        action="store_true",
        help="with a saved model: watch it on another variant than the one it was trained on",
    )
    parser.add_argument(
        "--no-colour",
        "--no-color",
        dest="no_colour",
        action="store_true",
        help="plain ASCII picture without ANSI colours",
    )


#: Seconds between two watched steps: slow enough to follow, fast enough not to bore.
DEFAULT_DELAY = 0.3
WINDOW = "window"


def _positive_int(text: str) -> int:
    return positive_int(text)


def _delay(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number of seconds >= 0, got {text!r}")
    return value


# ---------------------------------------------------------------------------------------- input
def _tokens(text: str) -> Iterator[int | str]:
    """Commands in ``text``: known keys, arrow escape sequences, and the unknown keys as text."""
    i = 0
    while i < len(text):
        ch = text[i]
        if ch == "\x1b" and i + 2 < len(text) and text[i + 1] in "[O" and text[i + 2] in _ARROWS:
            yield _ARROWS[text[i + 2]]
            i += 3
            continue
        lowered = ch.lower()
        yield KEYS.get(lowered, ch)
        i += 1


def _line_commands(stdin: TextIO) -> Iterator[int | str]:
    """Pipe mode: one line at a time, every character a key (the newline is not a key)."""
    for line in stdin:
        yield from _tokens(line.rstrip("\r\n"))


@contextlib.contextmanager
def _cbreak(stdin: TextIO) -> Iterator[None]:
    """Single key presses without echo; the terminal settings are restored however we leave."""
    fd = stdin.fileno()
    saved = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd, termios.TCSANOW)  # TCSANOW keeps keys typed ahead (TCSAFLUSH drops them)
        yield
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def _key_commands(stdin: TextIO) -> Iterator[int | str]:
    """Terminal mode: read key presses as they come, with arrow keys decoded."""
    fd = stdin.fileno()
    while True:
        data = os.read(fd, 1)
        if not data:
            return
        if data == b"\x1b":  # maybe an arrow key: its bytes follow immediately
            while select.select([fd], [], [], 0.05)[0] and len(data) < 3:
                data += os.read(fd, 1)
        yield from _tokens(data.decode("utf-8", errors="replace"))


# ---------------------------------------------------------------------------------------- the game
@dataclass
class Episode:
    """What happened so far in the current episode (for the summary)."""

    steps: int = 0
    total: float = 0.0
    events: set[str] = field(default_factory=set)
    harm: dict[str, int] = field(default_factory=lambda: {"human": 0, "animal": 0, "robot": 0})
    over: bool = False
    ending: str = ""


def _in_vocabulary_order(names: Any) -> list[str]:
    """Event names in the order of the vocabulary (stable and readable, unlike set order)."""
    order = {name: i for i, name in enumerate(EVENTS)}
    return sorted(names, key=lambda n: (order.get(n, len(order)), n))


def _format_events(norm_events: dict[str, Any]) -> list[str]:
    """Only the non-empty categories, names sorted in vocabulary order."""
    lines = []
    for category in ("action", "outcome", "causal"):
        names = _in_vocabulary_order(norm_events[category])
        if names:
            lines.append(f"  {category + ':':9}{', '.join(names)}")
    if norm_events["utility"]:
        values = ", ".join(f"{k}={v}" for k, v in norm_events["utility"].items())
        lines.append(f"  {'utility:':9}{values}")
    return lines or ["  no norm events"]


def _format_statuses(statuses: dict[str, bool]) -> str:
    return ", ".join(f"{name} {'stopped' if stopped else 'active'}" for name, stopped in statuses.items())


def _ending(env: Any, terminated: bool, truncated: bool) -> str:
    flags = env.state[1]
    agent = "the agent reached the landmark" if flags & FOUND else "the agent was harmed" if flags & HARMED else ""
    if truncated and not terminated:
        return f"truncated after {env.elapsed_steps} steps" + (f" ({agent})" if agent else "")
    return "terminated: " + (agent or "everything stopped")


class Game:
    """One terminal session: an environment, the output stream and the current episode."""

    def __init__(self, env: Any, out: TextIO, colour: bool, watching: str | None = None) -> None:
        self.env = env
        self.out = out
        self.colour = colour
        self.watching = watching  # the policy reference when an agent plays, None for a person
        self.episode = Episode()

    def say(self, text: str = "") -> None:
        self.out.write(text + "\n")
        self.out.flush()

    def picture(self) -> None:
        self.out.write(render_ansi(self.env.world, self.env.state, colour=self.colour))

    def start(self) -> None:
        self.env.reset()
        self.episode = Episode()
        self.say(f"\n{self.env.env_id}: {self.env.scenario.summary}")
        if self.watching is None:
            self.say("keys: w a s d move, space wait, e interact, r restart, q quit, ? help")
        else:
            self.say(f"policy: {self.watching}")
        self.picture()
        if self.env.render_mode == WINDOW_MODE:
            self.env.render()

    def step(self, action: int) -> None:
        if self.episode.over:
            self.say("the episode is over: r to restart, q to quit")
            return
        _obs, reward, terminated, truncated, info = self.env.step(action)
        ep = self.episode
        ep.steps += 1
        ep.total += float(reward)
        ne = info["norm_events"]
        ep.events.update(ne["action"], ne["outcome"], ne["causal"])
        for kind in ep.harm:
            ep.harm[kind] += ne["utility"].get(f"n_{kind}_harm", 0)
        self.say(f"\nstep {ep.steps}: {ACTION_NAMES[action]}")
        self.picture()
        self.say(f"reward {float(reward):g}   return {ep.total:g}")
        for line in _format_events(ne):
            self.say(line)
        self.say(f"terminated={terminated} truncated={truncated}   ({_format_statuses(info['termination_statuses'])})")
        if self.env.render_mode == WINDOW_MODE:
            self.env.render()
        if terminated or truncated:
            ep.over = True
            ep.ending = _ending(self.env, terminated, truncated)
            self.summary()
            if self.watching is None:
                self.say("r to play again, q to quit")

    def summary(self) -> None:
        ep = self.episode
        self.say(f"\n=== episode summary: {ep.ending or 'unfinished'} ===")
        self.say(f"return {ep.total:g}   length {ep.steps} steps")
        events = _in_vocabulary_order(ep.events)
        self.say("events: " + (", ".join(events) if events else "none"))
        self.say("harm: " + ", ".join(f"{kind} {n}" for kind, n in ep.harm.items()))

    def play(self, commands: Iterator[int | str]) -> int:
        """Run commands until quit or the end of the input; returns the exit code."""
        self.start()
        for command in commands:
            if command == QUIT:
                break
            if command == HELP:
                self.say(HELP_TEXT)
            elif command == RESTART:
                if self.episode.steps and not self.episode.over:
                    self.summary()
                self.say("restarting")
                self.start()
            elif isinstance(command, int):
                self.step(command)
            elif command.isspace():
                continue  # tabs and the like in piped input
            else:
                self.say(f"unknown key {command!r} (? for help)")
        if self.episode.steps and not self.episode.over:
            self.summary()
        self.say("bye")
        return 0


WINDOW_MODE = "human"  # the env's render mode behind --render window


def watch(game: Game, act: Any, episodes: int, delay: float, sleep: Any = time.sleep) -> int:
    """Let ``act(flat_obs, state_id) -> action`` play ``episodes`` episodes, printing every step."""
    observations = game.env.graph.tables().obs
    for k in range(episodes):
        if episodes > 1:
            game.say(f"\n##### episode {k + 1} of {episodes}")
        game.start()
        while not game.episode.over:
            if delay:
                sleep(delay)
            sid = game.env.state_id
            game.step(act(observations[sid], sid))
    game.say("bye")
    return 0


def gif_paths(target: str, episodes: int) -> list[Path]:
    """``out.gif`` for one episode; ``out.gif``, ``out-2.gif``, ... for more."""
    path = Path(target)
    return [path] + [path.with_name(f"{path.stem}-{k}{path.suffix}") for k in range(2, episodes + 1)]


def record(args: argparse.Namespace, loaded: Any, out: TextIO) -> int:
    """``--render OUT.gif``: each episode to a GIF, with a one-line summary of it."""
    for k, path in enumerate(gif_paths(args.render, args.episodes)):
        seed = None if args.seed is None else args.seed + k
        # max_steps + 1 frames at most: the env truncates on step max_steps + 1.
        summary = record_episode(args.env_id, loaded.policy, path, max_steps=args.max_steps + 1, seed=seed,
                                 env_kwargs={"max_steps": args.max_steps})
        ending = "terminated" if summary["terminated"] else "truncated" if summary["truncated"] else "stopped"
        events = ", ".join(summary["events"]) or "none"
        out.write(f"{summary['path']}: {summary['steps']} steps, return {summary['return']:g}, {ending}; events: {events}\n")
        out.flush()
    return 0


def _error(err: TextIO, exc: BaseException) -> int:
    err.write(f"morality_gym play: error: {one_line(exc)}\n")
    err.flush()
    return 2


def run(
    args: argparse.Namespace, stdin: TextIO = sys.stdin, stdout: TextIO = sys.stdout, stderr: TextIO | None = None
) -> int:
    """Play ``args.env_id``; returns the exit code (2 for an unknown id or bad arguments).

    ``stderr`` defaults to ``sys.stderr`` at call time (so pytest's capture sees it).
    """
    err = stderr if stderr is not None else sys.stderr
    policy = getattr(args, "policy", None)
    render = getattr(args, "render", None)
    problem = _render_problem(policy, render)
    if problem:
        return _error(err, ValueError(problem))
    try:
        env = TrolleyEnv(args.env_id, max_steps=args.max_steps,
                         render_mode=WINDOW_MODE if render == WINDOW else None)
    except (UnknownEnvError, ValueError, TypeError) as exc:
        return _error(err, exc)
    loaded = None
    if policy is not None:

        try:
            loaded = load_policy(policy, [env.env_id], getattr(args, "allow_other_env", False))
            probe(loaded, env.env_id)
            if render not in (None, WINDOW):
                env.close()
                return record(args, loaded, stdout)
        except (PolicyError, ModelError, InvalidActionError, PolicyFailure, OSError) as exc:
            env.close()
            return _error(err, exc)
    colour = not getattr(args, "no_colour", False) and _isatty(stdout)
    game = Game(env, stdout, colour, watching=None if loaded is None else loaded.ref)
    try:
        return _play_or_watch(game, loaded, args, stdin, err)
    except KeyboardInterrupt:
        game.say("\ninterrupted")
        return 130
    finally:
        env.close()


def _render_problem(policy: str | None, render: str | None) -> str:
    """Why ``--render`` cannot be used as given ("" when it can)."""
    if policy is None and render is not None:
        return "--render needs --policy (a person plays in the terminal)"
    if render is not None and render != WINDOW and not render.lower().endswith(".gif"):
        return f"--render {render}: give a file name ending in .gif, or 'window'"
    return ""


def _play_or_watch(game: Game, loaded: Any, args: argparse.Namespace, stdin: TextIO, err: TextIO) -> int:
    """Watch the loaded policy play, else let a person play: key by key on a terminal, else line by line."""
    if loaded is not None:
        try:
            return watch(game, step_actor(loaded.policy, np.random.default_rng(args.seed)), args.episodes, args.delay)
        except (InvalidActionError, PolicyFailure) as exc:  # the policy failed at some step of an episode
            return _error(err, exc)
    if _isatty(stdin) and _HAS_TERMIOS:
        with _cbreak(stdin):
            return game.play(_key_commands(stdin))
    return game.play(_line_commands(stdin))


try:  # single key presses need POSIX terminal control; elsewhere keys are read line by line
    import termios as _termios  # noqa: F401

    _HAS_TERMIOS = True
except ImportError:  # pragma: no cover - Windows
    _HAS_TERMIOS = False


def _isatty(stream: Any) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


__all__ = ["DEFAULT_DELAY", "HELP_TEXT", "KEYS", "add_arguments", "gif_paths", "run", "watch"]
