"""The batched simulators' per-graph tables, kept on disk so that a fleet starts in seconds.

Why: a simulator gathers from one table row per (state, action) and one observation row per state
of every graph it runs (:mod:`.batched`, :mod:`.mixed`). Building them means enumerating each
graph's states in Python and encoding each state's observation: for the generalisation track's
Utility train pool (934 generated dilemmas, 559k states) minutes of a fleet's start, paid again by
every process that trains or resumes a learner. What comes out is a handful of numeric arrays, the
same every time for the same scenario, variant and code, so a process that is given a cache
folder (:class:`SimTables` via :func:`sim_tables`) keeps them there and later processes read them.

**Key.** One file per graph and observation, named by the SHA-256 of what determines its arrays:

* the scenario's content (:func:`scenario_digest`: every field the world is built from, not the
  file's path, so the same generated scenario in two cache folders is one entry) and the variant;
* the observation type, its dtype and whether flat observations are normalised;
* the SHA-256 of every source of the world layer (:func:`world_code_digest`: rules, layouts, graph
  enumeration, observation encoders), so any change of that code is a new key;
* :data:`FORMAT`, the layout of the file itself.

Overrides (a user's edited world) are never cached: they are not part of a scenario.

**Data, never code.** An entry is an uncompressed ``.npz`` of plain numeric arrays plus one array of
UTF-8 JSON (what it was built for, each array's SHA-256); it is read with ``allow_pickle=False``.

**Verified.** An entry is used only if its recorded key is the expected one, every array has the
recorded checksum, dtype and a shape consistent with the others, and every transition points at a
state of the graph. Anything else (a truncated file, a file renamed onto another key, an edited
array) is refused with a one-line :class:`TableCacheWarning` saying why, and the tables are built
again and the entry rewritten. As with :mod:`morality_gym.world.bounds_cache` the checksum catches
corruption and edits, not someone who recomputes it on purpose: the cache spares a computation
anyone can redo by deleting the folder.

**Atomic.** Entries are written with :func:`~morality_gym.clitools.write_atomically`: a crash
mid-write leaves the previous entry or none, never half of one that a later process trusts.

**Pruned by use.** Every change of the world code is a new key, so the entries of older code are
never read again; nothing deletes them on its own, since two checkouts (a long run pinned to an
older commit beside a newer one) may share a folder. A read touches its entry's modification
time, so it is the entry's last use: :func:`list_entries` tells the entries of this code from the
others', and :func:`prune` removes those unused for a number of days (``python -m runners.cache``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import time
import warnings
from collections.abc import Mapping
from functools import cache
from pathlib import Path
from typing import Any, Final, NamedTuple

import numpy as np

from morality_gym.clitools import OneLineWarning, write_atomically
from morality_gym.world.graph import N_ACTIONS
from morality_gym.world.layout import Scenario
from morality_gym.world.vocab import UTILITIES

#: The layout of an entry; a change makes every older entry a miss.
FORMAT: Final[int] = 1
#: Observation types worth caching: the grid's rows (5 KiB a state) would be larger than rebuilding them.
CACHED_OBS_TYPES: Final[tuple[str, ...]] = ("flat", "compact")
_ARRAYS: Final[tuple[str, ...]] = ("next", "reward", "events", "utility", "goal", "done", "obs")
_DTYPES: Final[dict[str, str]] = {"next": "int32", "reward": "float64", "events": "uint32", "utility": "int32",
                                  "goal": "bool", "done": "bool"}
_META: Final[str] = "meta_json"


class TableCacheWarning(OneLineWarning):
    """A table cache entry was refused (damaged, edited, another key's); its tables are built again."""


class SimTables(NamedTuple):
    """What a batched simulator gathers from for one graph: row ``s * 6 + a`` of the first five is
    action ``a`` in state ``s`` (:class:`~morality_gym.world.graph.GraphTables`), ``done`` and
    ``obs`` have one row per state (``obs``: the observation rows of the simulator's type)."""

    next: np.ndarray  # int32 [S*6]
    reward: np.ndarray  # float64 [S*6]
    events: np.ndarray  # uint32 [S*6]
    utility: np.ndarray  # int32 [S*6, len(UTILITIES)]
    goal: np.ndarray  # bool [S*6]
    done: np.ndarray  # bool [S]
    obs: np.ndarray  # [S, width]

    @property
    def n_states(self) -> int:
        return int(self.done.shape[0])


def _plain(value: Any) -> Any:
    """``value`` as JSON-ready data in one canonical form (sets and mappings sorted)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        items = [(json.dumps(_plain(k), sort_keys=True), _plain(v)) for k, v in value.items()]
        return {"mapping": sorted(items, key=lambda kv: kv[0])}
    if isinstance(value, (set, frozenset)):
        return {"set": sorted((_plain(v) for v in value), key=lambda v: json.dumps(v, sort_keys=True))}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, float):
        return {"float": value.hex()}  # exact, whatever repr does
    if value is None or isinstance(value, (str, int, bool)):
        return value
    raise TypeError(f"scenario_digest: no canonical form for a {type(value).__name__}")


def scenario_digest(scenario: Scenario) -> str:
    """SHA-256 of everything a world is built from in ``scenario`` (its ``source`` path and
    ``summary`` text are left out: they change no state, reward or observation)."""
    fields = {f.name: _plain(getattr(scenario, f.name)) for f in dataclasses.fields(scenario)
              if f.name not in ("source", "summary")}
    return hashlib.sha256(json.dumps(fields, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


@cache
def world_code_digest() -> str:
    """SHA-256 of every source file of the world layer (what a layout's graph and observations come from)."""
    folder = Path(__file__).resolve().parent.parent / "world"
    digest = hashlib.sha256()
    for path in sorted(folder.glob("*.py")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def entry_key(scenario: Scenario, variant: str, obs_type: str, dtype: Any, normalise: bool) -> str:
    """The SHA-256 naming one graph's entry (module docstring)."""
    what = {"format": FORMAT, "world_code": world_code_digest(), "scenario": scenario_digest(scenario),
            "variant": variant, "obs_type": obs_type, "obs_dtype": np.dtype(dtype).str, "normalise": bool(normalise)}
    return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()


def _array_digest(array: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(array).view(np.uint8).reshape(-1).data).hexdigest()


def _refuse(path: Path, why: str) -> None:
    warnings.warn_explicit(f"refused this table cache entry ({why}); building the tables again",
                           TableCacheWarning, str(path), 1)


def read_entry(path: Path, key: str, obs_dtype: Any) -> SimTables | None:
    """The tables in ``path`` if it is a sound entry for ``key`` (module docstring), else ``None``
    (a refusal, not a miss, is said on one line)."""
    if not path.is_file():
        return None
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as npz:  # our handle: closed on a bad zip too
            meta = json.loads(bytes(npz[_META]).decode())
            arrays = {name: npz[name] for name in _ARRAYS}
    except Exception as exc:  # noqa: BLE001 - any unreadable file is refused, whatever numpy or zipfile raises
        _refuse(path, f"not a readable table file: {type(exc).__name__}: {exc}")
        return None
    why = _unsound(meta, arrays, key, np.dtype(obs_dtype))
    if why:
        _refuse(path, why)
        return None
    for array in arrays.values():
        array.setflags(write=False)
    _touch(path)
    return SimTables(**arrays)


def _touch(path: Path) -> None:
    """Mark the entry used now (its modification time is its last use, :func:`prune`); a
    read-only cache folder is still read."""
    try:
        os.utime(path)
    except OSError:
        pass


def _unsound(meta: Any, arrays: dict[str, np.ndarray], key: str, obs_dtype: np.dtype) -> str:
    """Why an entry must not be used ("" when it may): first its record, then its arrays."""
    return _record_problem(meta, arrays, key) or _array_problem(arrays, obs_dtype)


def _record_problem(meta: Any, arrays: dict[str, np.ndarray], key: str) -> str:
    """Why the entry's record disqualifies it: another format, another key, arrays off their checksums."""
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        return f"it is not a format-{FORMAT} entry"
    if meta.get("key") != key:
        return f"it records the key {str(meta.get('key'))[:16]}..., its name says {key[:16]}...: a renamed file"
    sums = meta.get("sha256")
    if not isinstance(sums, dict) or any(sums.get(n) != _array_digest(a) for n, a in arrays.items()):
        return "its arrays do not match their checksums: edited or damaged"
    return ""


def _array_problem(arrays: dict[str, np.ndarray], obs_dtype: np.dtype) -> str:
    """Why the (checksummed) arrays cannot be a simulator's tables: dtypes, shapes, transitions out of range.

    A checksum only says the file is what was written; an entry written by another version of the
    code could still hold tables this one would index out of bounds."""
    for name, dtype in {**_DTYPES, "obs": obs_dtype.str}.items():
        if arrays[name].dtype != np.dtype(dtype):
            return f"its {name} array is {arrays[name].dtype}, expected {np.dtype(dtype)}"
    n = arrays["done"].shape[0]
    rows = n * N_ACTIONS
    shapes = {"next": (rows,), "reward": (rows,), "events": (rows,), "utility": (rows, len(UTILITIES)),
              "goal": (rows,), "done": (n,)}
    for name, shape in shapes.items():
        if arrays[name].shape != shape:
            return f"its {name} array has shape {arrays[name].shape}, expected {shape} for {n} states"
    if arrays["obs"].ndim != 2 or arrays["obs"].shape[0] != n:
        return f"its obs array has shape {arrays['obs'].shape}, expected ({n}, width)"
    if n == 0 or arrays["next"].min() < 0 or arrays["next"].max() >= n:
        return f"a transition leads outside its {n} states"
    return ""


def write_entry(path: Path, key: str, env_id: str, tables: SimTables) -> Path:
    """Write ``tables`` as the entry ``path`` for ``key`` (atomically)."""
    arrays = {name: np.ascontiguousarray(getattr(tables, name)) for name in _ARRAYS}
    meta = {"format": FORMAT, "key": key, "env_id": env_id, "n_states": tables.n_states,
            "world_code": world_code_digest(), "sha256": {name: _array_digest(a) for name, a in arrays.items()}}
    buffer = io.BytesIO()
    np.savez(buffer, allow_pickle=False, **arrays, **{_META: np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)})
    return write_atomically(path, lambda fh: fh.write(buffer.getbuffer()))


@dataclasses.dataclass(frozen=True)
class CacheEntry:
    """One file of a table cache folder, as :func:`list_entries` sees it without checking its arrays."""

    path: Path
    size: int  # bytes
    last_used: float  # seconds since the epoch (the file's modification time)
    env_id: str | None  # None: the file's record cannot be read
    #: Whether this code's world wrote it: True, False, or None when its record does not say (an
    #: entry written before records carried it, or an unreadable file).
    this_code: bool | None


def list_entries(folder: Path) -> list[CacheEntry]:
    """Every entry of a table cache ``folder`` (and every temporary file a killed writer left),
    oldest use first. Only each file's small JSON record is read."""
    found = []
    for path in sorted(folder.glob("*.npz")) + sorted(folder.glob(".*.tmp")):
        try:
            stat = path.stat()
        except OSError:
            continue  # removed meanwhile
        meta = _read_record(path) if path.suffix == ".npz" else None
        code = meta.get("world_code") if isinstance(meta, dict) else None
        found.append(CacheEntry(path, stat.st_size, stat.st_mtime, meta.get("env_id") if isinstance(meta, dict) else None,
                                None if code is None else code == world_code_digest()))
    return sorted(found, key=lambda e: e.last_used)


def _read_record(path: Path) -> Any:
    """An entry's JSON record, or None if the file has none that can be read."""
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as npz:
            return json.loads(bytes(npz[_META]).decode())
    except Exception:  # noqa: BLE001 - a damaged file is listed as such, whatever numpy or zipfile raises
        return None


def prune(folder: Path, unused_days: float, now: float | None = None) -> list[CacheEntry]:
    """Remove the entries of ``folder`` not used for more than ``unused_days`` days; returns them.

    By use, not by code: an entry of an older world code may still be read by a checkout of that
    code sharing the folder, and one that is not will age out. A process reading an entry while it
    is removed has it open already or finds none and builds the tables again."""
    if unused_days < 0:
        raise ValueError(f"unused_days must be >= 0, got {unused_days}")
    cutoff = (time.time() if now is None else now) - unused_days * 86400
    removed = []
    for entry in list_entries(folder):
        if entry.last_used < cutoff:
            try:
                entry.path.unlink()
            except FileNotFoundError:
                continue
            removed.append(entry)
    return removed

