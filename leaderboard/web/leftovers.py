"""Temporary directories that a killed build left beside its target: found and removed.

The site and a release are assembled in a hidden temporary directory beside their target
(``.<site>.build-XXXX``, ``.<site>.old-XXXX``, ``.<release>.create-XXXX``) and renamed into place,
so a kill at any moment leaves the old target or the new one, never half of one. But ``kill -9``
leaves the temporary directory itself (11-29 MB for a site), which nothing used to remove: it
piled up, and under ``make leaderboard`` it showed in ``git status``.

Builds may run concurrently (two builds of one site are allowed), so a directory is removed only
when no build is running there: every build holds a shared ``flock`` on the parent directory
while it works; the clean-up takes it exclusively, without waiting, and skips the clean-up when
another build holds it (the next build cleans up). The kernel releases the lock of a killed
process, so a crashed build never blocks the clean-up.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path


@contextlib.contextmanager
def building_in(parent: Path, leftover: Callable[[str], bool]) -> Iterator[list[Path]]:
    """Hold ``parent`` as a place where a build runs, after removing the hidden directories whose
    name ``leftover`` accepts, unless another build runs there; yields what was removed."""
    parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(parent, os.O_RDONLY)
    try:
        removed = _sweep(parent, leftover, fd)
        fcntl.flock(fd, fcntl.LOCK_SH)  # a build runs here (from exclusive, or waited for, to shared)
        yield removed
    finally:
        os.close(fd)  # releases the lock


def _sweep(parent: Path, leftover: Callable[[str], bool], fd: int) -> list[Path]:
    """Remove the leftovers if no other build holds ``parent`` (else none)."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return []  # another build is running: its temporary directory is not a leftover
    removed = []
    for path in sorted(parent.iterdir()):
        if path.name.startswith(".") and path.is_dir() and not path.is_symlink() and leftover(path.name):
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed


__all__ = ["building_in"]
