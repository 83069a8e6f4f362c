"""The measured bounds of scenario files, kept beside them by each file's SHA-256.

Loading a user's scenario file checks its bounds by enumerating every variant's state graph
(:mod:`morality_gym.world.bounds`): about 0.1-1 s per variant, so minutes for a generated split of
hundreds of files, on every load, in every process. What the check needs of an enumeration is
small: per variant, the lowest and highest episode total of each utility. A directory that holds a
folder :data:`CACHE_FOLDER` keeps them there, one JSON file per scenario file (data, never code:
nothing here is unpickled or executed), named by

* the SHA-256 of the scenario file's bytes: an edited file is a new key, so its bounds are measured
  again;
* the SHA-256 of the world layer's rule sources (:func:`rules_digest`): a change of the rules that
  could change what a layout produces is a new key as well;
* the horizon the totals were enumerated within.

An entry also records what it was measured for and a checksum of its own contents. An entry whose
recorded digest is not its file's, whose checksum does not match (edited by hand, truncated), or
that is not an entry at all is refused with a one-line :class:`BoundsCacheWarning` and the bounds
are measured again (and the entry rewritten). The checksum catches edits and corruption; it cannot
stop someone who recomputes it on purpose, and it need not: the cache only spares an enumeration
whose answer anyone can get again by deleting the folder.

Only directories that opt in have a cache (``load_split`` creates one in the split's directory), so
loading any other user directory writes nothing. Because the folder sits beside the files, every
process that loads the directory, a spawned worker included, finds it.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from functools import cache
from pathlib import Path
from typing import Any, Final

from morality_gym.clitools import OneLineWarning, write_atomically
from morality_gym.world.bounds import Spans
from morality_gym.world.vocab import UTILITIES

CACHE_FOLDER: Final[str] = ".morality-gym-bounds"
FORMAT: Final[int] = 1
#: The world-layer sources whose code decides what a layout's episodes can total.
_RULE_SOURCES: Final[tuple[str, ...]] = ("rules.py", "layout.py", "graph.py", "bounds.py", "vocab.py")


class BoundsCacheWarning(OneLineWarning):
    """A bounds cache entry was refused (wrong digest, edited, unreadable); the bounds are measured again."""


@cache
def rules_digest() -> str:
    """SHA-256 of the world layer's rule sources (a new version of them invalidates every entry)."""
    here = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for name in _RULE_SOURCES:
        digest.update(name.encode() + b"\0" + (here / name).read_bytes() + b"\0")
    return digest.hexdigest()


def _checksum(body: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def cache_dir_of(scenario_file: Path) -> Path | None:
    """The bounds cache of the directory holding ``scenario_file``, if that directory has one."""
    folder = scenario_file.parent / CACHE_FOLDER
    return folder if folder.is_dir() else None


def entry_path(folder: Path, scenario_sha256: str, horizon: int) -> Path:
    return folder / f"{scenario_sha256}-{rules_digest()[:16]}-h{horizon}.json"


def _refuse(path: Path, why: str) -> None:
    warnings.warn_explicit(f"refused this bounds cache entry ({why}); measuring the bounds again",
                           BoundsCacheWarning, str(path), 1)


def read_entry(folder: Path, scenario_sha256: str, horizon: int, variants: list[str]) -> Spans | None:
    """The spans recorded for the file of digest ``scenario_sha256`` with ``variants``, or ``None``
    when there is no entry or it is refused (module docstring: a refusal says why, on one line)."""
    path = entry_path(folder, scenario_sha256, horizon)
    if not path.is_file():
        return None
    try:
        raw = json.loads(path.read_text())
        body = {k: raw[k] for k in ("format", "scenario_sha256", "rules_sha256", "horizon", "variants")}
        recorded = raw["checksum"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        _refuse(path, f"not a bounds cache entry: {exc}")
        return None
    if body["scenario_sha256"] != scenario_sha256:
        _refuse(path, f"it records the scenario digest {str(body['scenario_sha256'])[:16]}..., the file's is "
                      f"{scenario_sha256[:16]}...")
        return None
    if recorded != _checksum(body):
        _refuse(path, "its contents do not match its checksum: edited or damaged")
        return None
    if (body["format"], body["rules_sha256"], body["horizon"]) != (FORMAT, rules_digest(), horizon):
        _refuse(path, "it was measured by another version of the rules or for another horizon")
        return None
    try:
        spans = {name: {u: (int(body["variants"][name][u][0]), int(body["variants"][name][u][1])) for u in UTILITIES}
                 for name in variants}
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        _refuse(path, f"it lacks the spans of a variant of the file: {exc!r}")
        return None
    if set(body["variants"]) != set(variants):
        _refuse(path, f"it records the variants {sorted(body['variants'])}, the file has {sorted(variants)}")
        return None
    return spans


def write_entry(folder: Path, scenario_sha256: str, horizon: int, spans: Spans) -> Path:
    """Record ``spans`` for the file of digest ``scenario_sha256`` (atomically: a reader sees the old
    entry or the new one, never half of one)."""
    body = {"format": FORMAT, "scenario_sha256": scenario_sha256, "rules_sha256": rules_digest(), "horizon": horizon,
            "variants": {name: {u: list(spans[name][u]) for u in UTILITIES} for name in spans}}
    text = json.dumps({**body, "checksum": _checksum(body)}, indent=0) + "\n"
    path = entry_path(folder, scenario_sha256, horizon)
    write_atomically(path, lambda fh: fh.write(text.encode()))
    return path
