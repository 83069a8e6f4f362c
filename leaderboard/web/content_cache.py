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
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

import pandas as pd

from leaderboard.web.cache_codec import CacheFormatError, NotEncodable, decode, encode_exact
from morality_gym.clitools import write_atomically

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
    """Write ``data`` to ``path`` atomically (a killed build never leaves half a file). Not fsynced
    (``durable=False``): the cache and the pages are rebuilt from the results, and the site writes
    thousands of them."""
    write_atomically(path, lambda fh: fh.write(data), durable=False)


def read_index(path: Path) -> dict[str, str]:
    """A ``{file name: input digest}`` index; empty when absent or unreadable (everything is redrawn)."""
    try:
        body = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return {str(k): str(v) for k, v in body.items()} if isinstance(body, dict) else {}


def write_index(path: Path, index: dict[str, str]) -> None:
    atomic_write(path, json.dumps(dict(sorted(index.items())), indent=0).encode("utf-8"))


def frame_digest(frame: pd.DataFrame | None) -> str:
    """A digest of a DataFrame's content: column names, dtypes and values in order (``None``: absent).

    Object columns are hashed by the ``repr`` of each value, so list-valued cells (a run's relevant
    norms) count too; pandas' own row hash covers the rest."""
    if frame is None:
        return "none"
    parts: list[str | bytes] = [str(frame.shape)]
    for name in frame.columns:
        column = frame[name]
        parts += [str(name), str(column.dtype)]
        values = column.map(repr) if column.dtype == object else column
        parts.append(pd.util.hash_pandas_object(values, index=False).to_numpy().tobytes())
    return digest(parts)


def cached_outputs(path: Path, key: str, produce: Callable[[], T], files_of: Callable[[T], Iterable[Path]]) -> tuple[T, bool]:
    """``produce()``, which writes files and describes them, or the description stored at ``path`` when
    it was produced under the same ``key`` and every file it lists still has the bytes it had then.

    For figures drawn by matplotlib (drawing them costs seconds, checking them milliseconds) and for
    results that are no files (``files_of`` gives nothing: the bootstrap statistics). One entry per
    ``path``: a cache per input would grow with every sweep."""
    stored = _load(path)
    if stored is not None and stored.get("key") == key \
            and all(_file_digest(Path(p)) == d for p, d in stored.get("files", {}).items()):
        return stored["value"], True
    value = produce()
    files = {str(p): _file_digest(Path(p)) for p in files_of(value)}
    try:
        body = {"key": key, "value": encode_exact(value), "files": files}
    except NotEncodable:
        path.unlink(missing_ok=True)  # not cached: an older entry must not stand in for this value
        return value, False
    atomic_write(path, json.dumps(body, allow_nan=False, separators=(",", ":")).encode("utf-8"))
    return value, False


def _load(path: Path) -> dict[str, Any] | None:
    """The entry stored at ``path``, or None when it is absent, damaged or not one :func:`cached_outputs` wrote.

    JSON read by :func:`~leaderboard.web.cache_codec.decode`, which builds only plain data and the
    build's own result types: a file placed in a results directory by someone else can at worst
    make the build compute again, never run code."""
    try:
        body = json.loads(path.read_bytes())
        if not isinstance(body, dict) or not isinstance(body.get("key"), str) or not isinstance(body.get("files"), dict):
            return None
        return {"key": body["key"], "value": decode(body.get("value")), "files": body["files"]}
    except (OSError, ValueError, RecursionError, CacheFormatError):  # absent, damaged or outdated: produced again
        return None


def _file_digest(path: Path) -> str:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return "missing"
