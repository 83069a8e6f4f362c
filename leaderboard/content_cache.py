"""Build outputs kept between builds under ``<out>/cache``, keyed by a digest of their inputs.

Why content keys rather than modification times: a release's tables, a results directory copied
with new times, or a rebuilt checkout change times without changing a number, and an edit that
keeps the time (``cp -p``, a restored backup) changes numbers without changing it. A digest of
everything an output is computed from (the input data, the parameters, and the source code that
computes it) is only equal when the output would be, so reusing a cached output gives the same
bytes as computing it afresh, which ``tests/test_site_reproducible.py`` holds the build to.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")


def digest(parts: Iterable[str | bytes]) -> str:
    """SHA-256 of ``parts``, each length-prefixed (so ``("ab", "c")`` and ``("a", "bc")`` differ)."""
    h = hashlib.sha256()
    for part in parts:
        data = part.encode("utf-8") if isinstance(part, str) else part
        h.update(len(data).to_bytes(8, "little"))
        h.update(data)
    return h.hexdigest()


def source_digest(*modules: Any) -> str:
    """A digest of the source files of ``modules`` (a code change invalidates what they computed)."""
    return digest(Path(m.__file__).read_bytes() for m in modules)


def atomic_write(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary sibling (a killed build never leaves half a file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def read_index(path: Path) -> dict[str, str]:
    """A ``{file name: input digest}`` index; empty when absent or unreadable (everything is redrawn)."""
    try:
        body = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return {str(k): str(v) for k, v in body.items()} if isinstance(body, dict) else {}


def write_index(path: Path, index: dict[str, str]) -> None:
    atomic_write(path, json.dumps(dict(sorted(index.items())), indent=0).encode("utf-8"))


def cached(directory: Path, key: str, compute: Callable[[], T]) -> tuple[T, bool]:
    """``compute()``, or its pickled result stored under ``directory/<key>.pickle``; and whether it was cached.

    Only the latest entry is kept (older ones are removed on a miss): a cache per build input
    would grow with every sweep. An unreadable entry is recomputed.
    """
    path = directory / f"{key}.pickle"
    if path.is_file():
        try:
            with open(path, "rb") as fh:
                return pickle.load(fh), True
        except Exception:  # noqa: BLE001 - a damaged or outdated entry is recomputed, never fatal
            path.unlink(missing_ok=True)
    value = compute()
    if directory.is_dir():
        for old in directory.glob("*.pickle"):
            old.unlink(missing_ok=True)
    atomic_write(path, pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
    return value, False
