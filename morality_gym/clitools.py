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
* a full disk (``ENOSPC``, a quota, or torch's ``RuntimeError`` for a short write) is one line
  naming the path and the free space left there (:class:`DiskFullError`), exit 2, wherever it was
  raised: the writes it interrupted were atomic, so what was written before stays valid;
* a read-only directory (``PermissionError``) is one line naming the file, exit 2;
* SIGTERM ends the command after its clean-ups ran (temporary files removed), with one line and
  exit status 143;
* a closed output pipe (``... | head``) ends the program quietly with exit code 141 (128 +
  SIGPIPE, what a shell reports for a program killed by SIGPIPE) instead of a ``BrokenPipeError``
  traceback. SIGPIPE itself is left ignored (Python's default), because the sweep talks to MLflow
  servers and SLURM over sockets, where a dead peer must be an exception, not a silent death.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import errno
import math
import os
import shutil
import signal
import sys
import threading
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, NoReturn

EXIT_USAGE = 2
EXIT_BROKEN_PIPE = 141
DEBUG_ENV = "MORALITY_GYM_DEBUG"


class OneLineWarning(UserWarning):
    """A warning shown as the one line ``<file>: <Category>: <why, what happens>`` (the package sets
    the format, :mod:`morality_gym.envs.registry`): issued with ``warnings.warn_explicit`` naming the
    file it is about, not the source line that noticed it."""


class UserError(Exception):
    """A mistake of the user (a bad path, value or file): reported on one line, exit code 2."""


class DiskFullError(UserError):
    """A write failed because the file system is full: the message names the path and the free space.

    A user error, not a bug: the fix is to free space (or write elsewhere) and run the same command
    again. Every writer of the project writes to a temporary name and renames it into place, so
    the interrupted write left nothing half-written and the results written before are intact."""


#: ``errno`` values that mean "no room": a full file system, or a user's quota.
_FULL_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}
#: What libraries that do not raise ``OSError`` say on a full disk: torch's zip writer
#: (``RuntimeError: ... unexpected pos``, a short write), SQLite (through SQLAlchemy/MLflow).
_FULL_WORDS = ("no space left on device", "unexpected pos", "database or disk is full", "disk quota exceeded")


def is_disk_full(exc: BaseException | None) -> bool:
    """True when ``exc`` (or an exception it was raised from) says the file system is full."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, DiskFullError):
            return True
        if isinstance(exc, OSError) and exc.errno in _FULL_ERRNOS:
            return True
        if isinstance(exc, (OSError, RuntimeError)) and any(word in str(exc).lower() for word in _FULL_WORDS):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


def free_space(path: str | os.PathLike[str]) -> str:
    """The free space of the file system that holds ``path`` (its nearest existing ancestor), in words."""
    probe = Path(path).absolute()
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    try:
        free = shutil.disk_usage(probe).free
    except OSError:
        return "free space unknown"
    for unit in ("bytes", "KiB", "MiB", "GiB"):
        if free < 1024 or unit == "GiB":
            return f"{free} bytes free" if unit == "bytes" else f"{free:.1f} {unit} free"
        free /= 1024
    return "free space unknown"  # pragma: no cover - the loop always returns


def disk_full_error(path: str | os.PathLike[str] | None, exc: BaseException | None = None) -> DiskFullError:
    """The one-line :class:`DiskFullError` for a write of ``path`` that ``exc`` interrupted (the
    file the OS names in ``exc`` wins; with neither, the current directory's free space is told)."""
    if isinstance(exc, DiskFullError):
        return exc
    # the destination: shutil's copies name the source as filename and the destination as filename2
    filename = getattr(exc, "filename2", None) or getattr(exc, "filename", None)
    where = Path(filename) if isinstance(filename, (str, os.PathLike)) and filename else None
    where = where or (Path(path) if path is not None else None)
    what = f"cannot write {where} ({free_space(where)})" if where is not None else \
        f"a write failed (no path reported; {free_space(os.getcwd())} in {os.getcwd()})"
    return DiskFullError(f"disk full: {what}; free some space there (or write elsewhere) and run the same command "
                         "again: what was written before is intact")


@contextlib.contextmanager
def writing(path: str | os.PathLike[str]) -> Iterator[None]:
    """Turn a full disk met inside the block into :func:`disk_full_error` for ``path``."""
    try:
        yield
    except DiskFullError:
        raise
    except (OSError, RuntimeError) as exc:
        if is_disk_full(exc):
            raise disk_full_error(path, exc) from exc
        raise


def umask() -> int:
    """This process's umask, read without changing it (``os.umask`` can only swap it, which would
    race with another thread creating a file meanwhile)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    old = os.umask(0o022)
    os.umask(old)
    return old


def public_mode(directory: bool = False) -> int:
    """The mode ``open()`` (or ``mkdir``) gives a new file (directory) under the umask, as ``cp`` would.

    ``tempfile.mkstemp`` and ``mkdtemp`` create 0600 and 0700 so that no other user can race for a
    temporary name; renamed into place, the file keeps that mode, and a site or a results directory
    built through them could not be served by a web server running as another user."""
    return (0o777 if directory else 0o666) & ~umask()


def write_atomically(path: str | os.PathLike[str], write: Callable[[Any], None], *, durable: bool = True) -> Path:
    """Call ``write(binary file)`` on a temporary file beside ``path`` and rename it over ``path``:
    a kill or a full disk at any moment leaves the previous file or the new one, never half of one,
    and no temporary file (a full disk raises :class:`DiskFullError`).

    This is the project's one atomic writer (Parquet tables, JSON caches, manifests, site pages,
    GIFs). The temporary name (``.<name>.<pid>.<random>.tmp``, hidden) is in the same directory, so
    the rename is atomic, and unique per call, so threads of one process writing the same file never
    share one. It is opened with ``"xb"`` so the file gets the umask's permissions, as ``cp`` would
    give, not mkstemp's 0600 (which a web server running as another user could not read).

    ``durable=False`` skips the fsync before the rename: the rename is still atomic for other
    processes, but a power cut may lose the newest content. Only rebuildable outputs (the site's
    thousands of pages, rebuilt from the results) should take it, where a per-file fsync would cost
    more than the rebuild it saves."""
    target = Path(path)
    with writing(target):
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(f".{target.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp")
        try:
            with open(tmp, "xb") as fh:
                write(fh)
                if durable:
                    fh.flush()
                    os.fsync(fh.fileno())
            os.replace(tmp, target)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
    return target


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


#: How many SIGINTs (Ctrl-C) this process received since :func:`run_cli` began counting them.
_SIGINTS = [0]


def sigints() -> int:
    """How many Ctrl-Cs reached this process: a ``KeyboardInterrupt`` raised while the count
    did not change came from code (a user's policy), not from the user at the terminal."""
    return _SIGINTS[0]


def _count_sigint(signum: int, frame: Any) -> None:
    _SIGINTS[0] += 1
    signal.default_int_handler(signum, frame)  # raises KeyboardInterrupt, as Python's own handler


def _count_sigints() -> None:
    """Count Ctrl-Cs (main thread only; a handler the program set is kept)."""
    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _count_sigint)


def run_cli(body: Callable[[], int | None], user_errors: tuple[type[BaseException], ...] = (),
            argv: Sequence[str] | None = None) -> int:
    """Run ``body`` as an entry point and map what it raises to an exit status (module docstring)."""
    debug = debug_enabled(argv)
    _stop_on_sigterm()
    _count_sigints()
    try:
        return int(body() or 0)
    except BrokenPipeError:
        silence_broken_pipe()
        return EXIT_BROKEN_PIPE
    except (UserError, *user_errors) as exc:
        if debug:
            raise
        return _report(exc)
    except PermissionError as exc:  # a read-only directory: the environment's to fix, not a bug
        if debug:
            raise
        where = getattr(exc, "filename2", None) or exc.filename or "a file"
        return _report(UserError(f"cannot write {where} ({exc.strerror or 'permission denied'}): the directory is "
                                 "read-only for this user; choose a writable one"))
    except (OSError, RuntimeError) as exc:
        if debug or not is_disk_full(exc):
            raise
        return _report(disk_full_error(None, exc))
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print("stopped by SIGTERM: every file is written under a temporary name and renamed, so nothing half-written "
              "is left; run the same command again", file=sys.stderr, flush=True)
        return EXIT_TERMINATED


class Terminated(BaseException):
    """SIGTERM reached a command: raised where it runs, so that ``finally`` blocks and the
    clean-ups of temporary files (``except BaseException``) run before it ends (Python's default
    for SIGTERM ends the process at once and leaves them behind)."""


#: A command stopped by SIGTERM exits as a program killed by it would (128 + 15).
EXIT_TERMINATED = 143


def _terminate(signum: int, _frame: Any) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # one is enough: the clean-up must not be cut short
    raise Terminated(signum)


def _stop_on_sigterm() -> None:
    """SIGTERM raises :class:`Terminated` (main thread only; a handler the program set is kept)."""
    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _terminate)


def _report(exc: BaseException) -> int:
    """Print ``error: <one line>`` on stderr; :data:`EXIT_USAGE` (or the broken-pipe status)."""
    try:
        print(f"error: {one_line(exc)}", file=sys.stderr, flush=True)
    except BrokenPipeError:
        silence_broken_pipe()
        return EXIT_BROKEN_PIPE
    return EXIT_USAGE


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


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0 (a time limit in seconds)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds > 0, got {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be a number of seconds > 0, got {text}")
    return value


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
