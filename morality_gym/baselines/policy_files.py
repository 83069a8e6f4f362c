"""The files a policy named on a command line runs, and one digest over them.

Why: a submission is recognised by a digest of what it runs. When that was the entry ``.py``
file alone, a retrained weights file or an edited helper module beside it left the digest as it
was: the re-submission was "already present" and the old number stayed on the leaderboard. So a
policy's identity covers:

* its file, and every module it imports and every file it opens under the policy's *root* (the
  file's directory; for ``package.module:attr`` the top-level package's directory) while it is
  imported and while it answers its first observation (:func:`watching`: an audit hook on
  ``open`` and the modules that appeared in ``sys.modules``); or
* a declared directory (``--policy-dir``): every file under it, for a policy that reads files later
  than its first answer or outside what it imports.

Files are named in the digest by their path relative to the root, so a policy moved with its files
keeps its identity, and a policy of one file keeps the digest it had before its helpers counted.
"""

from __future__ import annotations

import functools
import hashlib
import os
import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: Directory names never part of a policy's files: caches of what is hashed anyway, and VCS data.
SKIPPED_DIRS = frozenset({"__pycache__", ".git", ".hg", ".svn", ".mypy_cache", ".pytest_cache", ".ruff_cache"})


@dataclass
class _Watch:
    root: Path
    seen: set[Path] = field(default_factory=set)


_ACTIVE: list[_Watch] = []
_INSTALLED: list[bool] = []


def _inside(path: Path, root: Path) -> bool:
    return path == root or root in path.parents


@functools.cache
def library_dirs() -> tuple[Path, ...]:
    """Where the Python installation and this project's own packages live: files there are the
    libraries a policy uses, not the policy (a policy file at the top of a checkout would otherwise
    count the virtual environment inside it, or MoralityGym itself)."""
    dirs = {Path(p) for p in (sys.prefix, sys.base_prefix, sys.exec_prefix)}
    dirs |= {Path(p) for p in sys.path if "site-packages" in p or "dist-packages" in p}
    project = Path(__file__).resolve().parents[2]  # the checkout (or site-packages) holding this package
    dirs |= {init.parent for init in project.glob("*/__init__.py")}  # its packages, this one among them
    return tuple(sorted({d.resolve() for d in dirs}))


def _keep(path: Path, root: Path) -> bool:
    """Whether ``path`` (resolved) is one of the policy's files under ``root``."""
    if not _inside(path, root):
        return False
    if any(_inside(path, lib) and not _inside(root, lib) for lib in library_dirs()):
        return False
    rel = path.relative_to(root).parts
    return not any(part in SKIPPED_DIRS for part in rel) and path.is_file()


def _record(watch: _Watch, raw: Any) -> None:
    try:
        path = Path(os.fsdecode(raw))
        path = (path if path.is_absolute() else Path.cwd() / path).resolve()
        if _keep(path, watch.root):
            watch.seen.add(path)
    except (OSError, TypeError, ValueError):
        return


def _audit(event: str, args: tuple[Any, ...]) -> None:
    """``sys.addaudithook``'s hook: record every file opened while a :func:`watching` block runs."""
    if event != "open" or not _ACTIVE or not args or isinstance(args[0], int) or args[0] is None:
        return
    for watch in _ACTIVE:
        _record(watch, args[0])


@contextmanager
def watching(root: Path) -> Iterator[set[Path]]:
    """The files under ``root`` opened or imported inside the block (filled when it ends).

    An audit hook cannot be removed, so one is installed once per process and does nothing
    outside a block."""
    if not _INSTALLED:
        sys.addaudithook(_audit)
        _INSTALLED.append(True)
    watch = _Watch(Path(root).resolve())
    before = set(sys.modules)
    _ACTIVE.append(watch)
    try:
        yield watch.seen
    finally:
        _ACTIVE.remove(watch)
        for name in set(sys.modules) - before:
            source = getattr(sys.modules.get(name), "__file__", None)
            if source:
                _record(watch, source)


def directory_files(directory: Path) -> list[Path]:
    """Every file under ``directory`` (resolved, sorted), caches and VCS data left out."""
    root = Path(directory).resolve()
    found = []
    for base, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if d not in SKIPPED_DIRS)
        found += [Path(base) / f for f in files]
    return sorted(p.resolve() for p in found if p.is_file())


def entry_name(path: Path, root: Path | None) -> str:
    """How ``path`` is named in the digest: relative to ``root`` when under it, else its bare name."""
    if root is not None and _inside(path, root) and path != root:
        return path.relative_to(root).as_posix()
    return path.name


def files_digest(files: Iterable[Path], root: Path | None) -> str:
    """SHA-256 over each file's name (:func:`entry_name`) and bytes, in the order given.

    One file: its name, a NUL and its bytes, the digest submissions had before their helpers
    counted (an unchanged one-file policy stays "already present"). Several: each file's bytes
    are length-prefixed too, so that no two sets of files run together into the same stream."""
    files = list(files)
    digest = hashlib.sha256()
    for path in files:
        data = path.read_bytes()
        digest.update(entry_name(path, root).encode() + b"\0")
        if len(files) > 1:
            digest.update(len(data).to_bytes(8, "little"))
        digest.update(data)
    return digest.hexdigest()


__all__ = ["directory_files", "entry_name", "files_digest", "watching"]
