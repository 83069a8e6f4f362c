"""What every command-line entry point of the project shares: one-line errors, ``--debug``, pipes.

A user who mistypes a path or a number should read one line that names the problem and the fix,
not a traceback; a traceback is for bugs, and for whoever asks for it. So every entry point
(``python -m morality_gym ...``, ``python -m runners.sweep``, ``python -m runners.table1``,
``python -m leaderboard.build``, ``python -m leaderboard.screenshot``) runs its body through
:func:`run_cli`:

* an exception of one of the entry point's *user error* classes prints ``error: <message>`` on
  one line and exits with :data:`EXIT_USAGE` (2);
* any other exception is a bug: it is re-raised (traceback, exit 1);
* ``--debug`` (argparse entry points) or ``MORALITY_GYM_DEBUG=1`` (all, including the Hydra ones)
  re-raises user errors too, so their traceback can be seen;
* a closed output pipe (``... | head``) ends the program quietly with exit code 141 (128 +
  SIGPIPE, what a shell reports for a program killed by SIGPIPE) instead of a ``BrokenPipeError``
  traceback. SIGPIPE itself is left ignored (Python's default), because the sweep talks to MLflow
  servers and SLURM over sockets, where a dead peer must be an exception, not a silent death.
"""

from __future__ import annotations

import argparse
import difflib
import math
import os
import sys
from collections.abc import Callable, Iterable, Sequence
from typing import Any, NoReturn

EXIT_USAGE = 2
EXIT_BROKEN_PIPE = 141
DEBUG_ENV = "MORALITY_GYM_DEBUG"


class UserError(Exception):
    """A mistake of the user (a bad path, value or file): reported on one line, exit code 2."""


def debug_enabled(argv: Sequence[str] | None = None) -> bool:
    """True when ``--debug`` is among ``argv`` or ``MORALITY_GYM_DEBUG`` is set to a true value."""
    if argv is not None and "--debug" in argv:
        return True
    return os.environ.get(DEBUG_ENV, "").strip().lower() in {"1", "true", "yes", "on"}


def one_line(exc: BaseException) -> str:
    """The exception's message on one line (continuation lines joined with ' | ')."""
    text = str(exc).strip() or type(exc).__name__
    if isinstance(exc, KeyError) and len(exc.args) == 1 and text == repr(exc.args[0]):
        text = str(exc.args[0])  # KeyError quotes its message
    return " | ".join(part.strip() for part in text.splitlines() if part.strip())


def silence_broken_pipe() -> None:
    """Point stdout (and stderr) at /dev/null, so the interpreter's final flush cannot fail again."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    for stream in (sys.stdout, sys.stderr):
        try:
            os.dup2(devnull, stream.fileno())
        except (OSError, ValueError, AttributeError):
            pass


def run_cli(body: Callable[[], int | None], user_errors: tuple[type[BaseException], ...] = (),
            argv: Sequence[str] | None = None) -> int:
    """Run ``body`` as an entry point and map what it raises to an exit status (module docstring)."""
    debug = debug_enabled(argv)
    try:
        return int(body() or 0)
    except BrokenPipeError:
        silence_broken_pipe()
        return EXIT_BROKEN_PIPE
    except (UserError, *user_errors) as exc:
        if debug:
            raise
        try:
            print(f"error: {one_line(exc)}", file=sys.stderr, flush=True)
        except BrokenPipeError:
            silence_broken_pipe()
            return EXIT_BROKEN_PIPE
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


def console(**kwargs: Any) -> Any:
    """A ``rich`` console whose closed pipe raises :class:`BrokenPipeError` for :func:`run_cli`.

    Rich's own answer to a closed pipe is ``SystemExit(1)``: ``... | head`` would then report a
    failure (exit 1) for output that was simply not read to the end.
    """
    from rich.console import Console  # rich waits: the command line starts without it

    class _PipeSafeConsole(Console):
        def on_broken_pipe(self) -> None:
            self.quiet = True
            raise BrokenPipeError("output pipe closed")

    return _PipeSafeConsole(**kwargs)


def version_text(prog: str) -> str:
    """What ``--version`` prints: the command and the installed package's version."""
    # importlib.metadata waits: the command line starts without it
    from importlib.metadata import PackageNotFoundError, version

    try:
        number = version("morality-gym")
    except PackageNotFoundError:
        number = "unknown (the package is not installed; pip install -e .)"
    return f"{prog} (morality-gym {number})"


def add_version_flag(parser: argparse.ArgumentParser) -> None:
    """``--version``: print :func:`version_text` and exit 0 (every entry point has it)."""
    parser.add_argument("--version", action="version", version=version_text(parser.prog))


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line (problem + where to look), exit code 2,
    and ``--version`` (sub-command parsers too: ``python -m morality_gym eval --version``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        add_version_flag(self)

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"error: {message} (see {self.prog} --help)\n")


def add_debug_flag(parser: argparse.ArgumentParser) -> None:
    """``--debug``: show the traceback of user errors too (same as MORALITY_GYM_DEBUG=1)."""
    parser.add_argument("--debug", action="store_true",
                        help=f"show tracebacks of user errors too (or set {DEBUG_ENV}=1)")


def duration(seconds: float) -> str:
    """``seconds`` as ``1h02m03s`` / ``2m03s`` (rounded to the second; ``–`` if not finite): the one
    way sweeps, plans and reports print a duration, so their figures read alike."""
    if not math.isfinite(seconds):
        return "–"
    minutes, secs = divmod(round(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h{minutes:02d}m{secs:02d}s" if hours else f"{minutes}m{secs:02d}s"


def _int_at_least(text: str, minimum: int, words: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {words}, got {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"must be {words}, got {value}")
    return value


def positive_int(text: str) -> int:
    """An argparse type: an integer >= 1."""
    return _int_at_least(text, 1, "a positive integer (1 or more)")


def non_negative_int(text: str) -> int:
    """An argparse type: an integer >= 0 (seeds: numpy refuses negative ones with a traceback)."""
    return _int_at_least(text, 0, "an integer >= 0")


def did_you_mean(word: object, choices: Iterable[object], n: int = 1, quote: bool = True) -> str:
    """`` (did you mean 'x'?)`` naming the ``n`` closest of ``choices`` to ``word`` (``difflib``'s
    ratio, its default cutoff), or ``""`` when none is close: the hint every error about an
    unknown name carries, written once so that all of them read alike. ``quote``: names as
    ``repr`` (keys, option values a user types in quotes) or bare (ids, norm and variant names)."""
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=n)
    if not close:
        return ""
    return f" (did you mean {', '.join(repr(c) if quote else c for c in close)}?)"
