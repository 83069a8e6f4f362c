"""``python -m runners.migrate RESULTS_DIR [--dry-run]``: bring old runs to the current run ids.

When a change renames the vocabulary of the recorded run config without changing what runs (the
list is :data:`runners.record.rename_history.MIGRATIONS`), every run id changes, because an id is the hash of
the config. A results directory written before the change would be planned again from scratch by a
sweep, and the leaderboard would show its runs as superseded. This command rewrites such runs
under their new ids, so that the work already done counts again.

For each run ``runs/<id>.parquet`` whose stored config hashes to its id and which a migration
applies to, the config is migrated (:func:`runners.record.rename_history.migrate_config` checks that only
vocabulary changes and that the inverse gives the old config back). Then the run is written again
under the new id: its row (``run_id``, ``config``, ``model_path``, ``gif_path``; every other value
as it was), ``.learn``/``.updates`` side files (``run_id``), its artifacts directory (the model's
``model.json`` through the same migrations, every other file byte for byte) and its MLflow mirror
(the old one is deleted and the run mirrored again, if it was mirrored). The sweep manifests get
the new ids and configuration keys, also for planned runs that have no result yet whenever another
run of the same configuration has one (the rebuilt config must hash to the planned id). A manifest
named after its plan hash is renamed with it, so a sweep of the same selection finds its own.

Safety, because a results directory is worth days of compute:

* the new files are written first (each atomically, the row last), the old ones removed after;
* every run is recorded in ``<results>/migrations/journal.jsonl`` before it starts and when it is
  done, so a migration killed half-way finishes cleanly when started again;
* it refuses to start while a sweep holds run locks in the directory (``runs/.locks``) or another
  migration runs, and holds each run's lock (old and new id) while it moves the run;
* a run whose new id already has a different result (it was run again at the new code) is left
  alone and reported as a duplicate, never overwritten; a run that fails a check is left alone with
  the reason;
* a second migration finds nothing to do; ``--dry-run`` prints the table and writes nothing.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import json
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from morality_gym.clitools import OneLineParser, UserError, add_debug_flag, run_cli, write_atomically
from morality_gym.clitools import console as make_console
from morality_gym.results.identity import PER_RUN_KEYS, PROVENANCE_KEY, config_key, run_identity
from morality_gym.results.manifest import manifests_dir, plan_hash
from morality_gym.results.recording import RunLock
from morality_gym.results.schema import (
    atomic_write_table,
    learn_path,
    read_jsonl,
    run_files,
    run_path,
    runs_dir,
    updates_path,
)
from runners.record.mlflow_mirror import Tracker, TrackingError, check_reachable, marker_path, tracking_lock
from runners.record.rename_history import (
    MIGRATIONS,
    Migration,
    MigrationError,
    migrate_config,
    migrate_sidecar,
    unmigrate_config,
)

JOURNAL_DIR = "migrations"
JOURNAL = "journal.jsonl"
STAGING_PREFIX = ".migrating-"
#: The columns of a run row that name the run (rewritten); every other value is kept as it is.
RENAMED_COLUMNS = ("run_id", "config", "model_path", "gif_path")

Step = Callable[[str], None]


class MigrateError(UserError):
    """The directory cannot be migrated now (not a results directory, in use); exit code 2."""


@dataclass
class RunMove:
    """What happens to one run: its old and new id, and why (``status``, ``reason``)."""

    old_id: str
    new_id: str | None
    status: str  # migrate | resume | duplicate | left | current | migrated
    reason: str = ""
    learner: str = ""
    env_id: str = ""
    protocol: str = ""
    migrations: list[str] = field(default_factory=list)
    old_config: dict[str, Any] | None = None
    new_config: dict[str, Any] | None = None


@dataclass
class Report:
    moves: list[RunMove]
    manifests: list[tuple[str, str, int]]  # (old name, new name, entries changed)
    seconds: float = 0.0

    def count(self, status: str) -> int:
        return sum(m.status == status for m in self.moves)


# ------------------------------------------------------------------ locks and journal
def held_run_locks(results: Path) -> list[str]:
    """Run ids whose lock (``runs/.locks/<id>.lock``) a live process holds (a sweep at work)."""
    held = []
    directory = runs_dir(results) / ".locks"
    for path in sorted(directory.glob("*.lock")) if directory.is_dir() else []:
        try:
            fh = open(path)  # noqa: SIM115 - closed by the `with fh` below; only a failed open skips the file
        except OSError:
            continue
        with fh:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
                fcntl.flock(fh, fcntl.LOCK_UN)
            except BlockingIOError:
                held.append(path.stem)
    return held


@contextlib.contextmanager
def migration_lock(results: Path) -> Iterator[None]:
    """One migration per directory at a time."""
    directory = results / JOURNAL_DIR
    directory.mkdir(parents=True, exist_ok=True)
    with open(directory / ".lock", "a+") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise MigrateError(f"{results}: another migration is running on this directory; wait for it to end") from None
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


@contextlib.contextmanager
def run_locks(results: Path, *run_ids: str) -> Iterator[None]:
    """The sweep's own per-run locks, so no sweep executes a run while it is being moved."""
    locks = []
    try:
        for rid in run_ids:
            lock = RunLock(results, rid)
            if not lock.acquire():
                raise MigrateError(f"{results}: run {rid} is being executed by a sweep that started meanwhile; "
                                   "let it finish, then migrate again (what is done so far is kept)")
            locks.append(lock)
        yield
    finally:
        for lock in reversed(locks):
            lock.release()


def journal_path(results: Path) -> Path:
    return results / JOURNAL_DIR / JOURNAL


def read_journal(results: Path) -> list[dict[str, Any]]:
    """The journal's entries (a torn last line, from a kill while writing it, is ignored)."""
    return read_jsonl(journal_path(results))


def _journal(results: Path, **entry: Any) -> None:
    path = journal_path(results)
    path.parent.mkdir(parents=True, exist_ok=True)
    entry = {"at": datetime.now(UTC).isoformat(timespec="seconds"), **entry}
    with open(path, "a") as fh:
        fh.write(json.dumps(entry, sort_keys=True) + "\n")
        fh.flush()
        os.fsync(fh.fileno())


def pending_runs(journal: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Runs begun and not done (a killed migration), by old id."""
    pending: dict[str, dict[str, Any]] = {}
    for entry in journal:
        if entry.get("event") == "begin":
            pending[str(entry["old"])] = entry
        elif entry.get("event") == "done":
            pending.pop(str(entry["old"]), None)
    return pending


# ------------------------------------------------------------------ planning
def _renamed_path(value: Any, old_id: str, new_id: str) -> Any:
    prefix = f"runs/{old_id}/"
    return f"runs/{new_id}/{value[len(prefix):]}" if isinstance(value, str) and value.startswith(prefix) else value


def new_row(row: dict[str, Any], old_id: str, new_id: str, new_config: dict[str, Any]) -> dict[str, Any]:
    """The run row under its new id: only :data:`RENAMED_COLUMNS` change."""
    return {**row, "run_id": new_id, "config": json.dumps(new_config, sort_keys=True),
            "model_path": _renamed_path(row.get("model_path"), old_id, new_id),
            "gif_path": _renamed_path(row.get("gif_path"), old_id, new_id)}


def _read_row(path: Path) -> tuple[pa.Table, dict[str, Any]]:
    table = pq.read_table(path)
    if table.num_rows != 1:
        raise ValueError(f"a run file holds one row, this one {table.num_rows}")
    return table, table.to_pylist()[0]


def decide(results: Path, path: Path) -> RunMove:
    """What to do with the run of ``path`` (reads only)."""
    old_id = path.stem
    try:
        _, row = _read_row(path)
        config = json.loads(row["config"])
    except (pa.ArrowException, OSError, ValueError, KeyError, TypeError) as exc:
        return RunMove(old_id, None, "left", f"unreadable ({type(exc).__name__}: {str(exc)[:120]}); a sweep moves it to runs/.quarantine")
    move = RunMove(old_id, None, "left", learner=str(row.get("learner") or ""), env_id=str(row.get("env_id") or ""),
                   protocol=str(row.get("protocol") or ""), old_config=config)
    move.reason = _not_a_sweeps_row(row, config, old_id)
    if move.reason:
        return move
    try:
        new_config, applied = migrate_config(config)
    except MigrationError as exc:
        move.reason = str(exc)
        return move
    if not applied:
        move.status, move.new_id = "current", old_id
        return move
    move.new_config, move.migrations = new_config, [m.name for m in applied]
    move.new_id = run_identity(new_config)
    move.status, move.reason = _against_target(results, row, old_id, move.new_id, new_config)
    return move


def _not_a_sweeps_row(row: dict[str, Any], config: Any, old_id: str) -> str:
    """Why the row is not one a sweep wrote for this file (so it cannot be migrated safely), or ""."""
    if not isinstance(config, dict):
        return "its config column is not a JSON object"
    if row.get("run_id") != old_id:
        return f"its row says run_id {row.get('run_id')!r}, not the file's name"
    if json.dumps(config, sort_keys=True) != row["config"]:
        return "its config column is not the canonical JSON a sweep writes"
    if run_identity(config) != old_id:
        return "its stored config does not hash to its run id (written by other hashing, or edited)"
    return ""


def _against_target(results: Path, row: dict[str, Any], old_id: str, new_id: str,
                    new_config: dict[str, Any]) -> tuple[str, str]:
    """``(status, reason)`` of a run to migrate, by what its new file holds: nothing (``migrate``),
    this very row rewritten by a stopped migration (``resume``), or another result (``duplicate``)."""
    target = run_path(results, new_id)
    if not target.exists():
        return "migrate", ""
    try:
        _, existing = _read_row(target)
    except (pa.ArrowException, OSError, ValueError) as exc:
        return "duplicate", f"runs/{new_id}.parquet exists but is unreadable ({type(exc).__name__})"
    if existing == new_row(row, old_id, new_id, new_config):
        return "resume", "copied by a migration that was stopped; the old files are removed now"
    return "duplicate", (f"runs/{new_id}.parquet already holds a result of this configuration (run again at the "
                         "current code); the old run is kept as it is and reported superseded")


def plan_moves(results: Path, journal: list[dict[str, Any]]) -> list[RunMove]:
    """Every run's move: the runs on disk, plus runs a killed migration left half removed."""
    moves = [decide(results, path) for path in run_files(results)]
    on_disk = {m.old_id for m in moves}
    for old_id, entry in pending_runs(journal).items():
        if old_id in on_disk:
            continue  # its old row is still there: decided above (migrate or resume)
        new_id = str(entry["new"])
        status = "resume" if run_path(results, new_id).is_file() else "left"
        reason = ("copied by a migration that was stopped after removing its old row; its remaining old files are removed now"
                  if status == "resume" else f"journal: begun towards {new_id}, but neither runs/{old_id}.parquet nor "
                  f"runs/{new_id}.parquet exists; its remaining files are left as they are")
        moves.append(RunMove(old_id, new_id, status, reason, learner=str(entry.get("learner", "")),
                             env_id=str(entry.get("env_id", "")), protocol=str(entry.get("protocol", "")),
                             migrations=list(entry.get("migrations", []))))
    return moves


# ------------------------------------------------------------------ moving one run
def _fsync_file(path: Path) -> None:
    with open(path, "rb") as fh:
        os.fsync(fh.fileno())


def _replace_column(table: pa.Table, name: str, value: Any) -> pa.Table:
    index = table.schema.get_field_index(name)
    field_ = table.schema.field(index)
    return table.set_column(index, field_, pa.array([value] * table.num_rows, type=field_.type))


def _copy_artifacts(results: Path, move: RunMove, applied: list[Migration], step: Step) -> None:
    """``runs/<old>/`` to ``runs/<new>/`` through a staging directory renamed into place (the model
    sidecar migrated, every other file byte for byte)."""
    source = runs_dir(results) / move.old_id
    if not source.is_dir():
        return
    assert move.new_id is not None
    staging = runs_dir(results) / f"{STAGING_PREFIX}{move.new_id}"
    target = runs_dir(results) / move.new_id
    if staging.exists():
        shutil.rmtree(staging)  # left by a killed migration
    staging.mkdir()
    for item in sorted(source.rglob("*")):
        out = staging / item.relative_to(source)
        if item.is_dir():
            out.mkdir(parents=True, exist_ok=True)
            continue
        out.parent.mkdir(parents=True, exist_ok=True)
        text = None
        if item.suffix == ".json":
            try:
                meta = json.loads(item.read_text())
            except (OSError, ValueError):
                meta = None
            if isinstance(meta, dict):
                migrated = migrate_sidecar(meta, applied)
                if migrated != meta:
                    text = json.dumps(migrated, indent=1)  # as Learner.save writes it
        if text is None:
            shutil.copy2(item, out)
        else:
            out.write_text(text)
            shutil.copystat(item, out)
        _fsync_file(out)
    if target.exists():
        shutil.rmtree(target)  # an earlier copy of ours, or artifacts of a killed run with no result
    os.replace(staging, target)
    step(f"runs/{move.new_id}/")


def _mirror(results: Path, tracker: Any, move: RunMove, step: Step) -> None:
    """Replace the MLflow mirror of the old id by one of the new id (only if it was mirrored)."""
    old_marker = marker_path(results, move.old_id)
    if not old_marker.is_file() or tracker is None:
        return
    with tracking_lock(results):
        for old in tracker.client.search_runs([tracker.experiment_id], filter_string=f"tags.run_id = '{move.old_id}'"):
            tracker.client.delete_run(old.info.run_id)
    step(f"mlflow: deleted the mirror of {move.old_id}")
    assert move.new_id is not None
    tracker.sync(move.new_id)
    step(f"mlflow: mirrored {move.new_id}")


def _remove_old(results: Path, move: RunMove, step: Step) -> None:
    """The old files, the row first (from then on the old run no longer exists for anyone)."""
    for path in (run_path(results, move.old_id), learn_path(results, move.old_id), updates_path(results, move.old_id)):
        if path.exists():
            path.unlink()
            step(f"removed {path.relative_to(results)}")
    artifacts = runs_dir(results) / move.old_id
    if artifacts.is_dir():
        shutil.rmtree(artifacts)
        step(f"removed runs/{move.old_id}/")
    for path in (marker_path(results, move.old_id), runs_dir(results) / ".locks" / f"{move.old_id}.lock"):
        if path.exists():
            path.unlink()
            step(f"removed {path.relative_to(results)}")


def move_run(results: Path, move: RunMove, tracker: Any, step: Step) -> None:
    """Write the run under its new id, then remove the old one (see the module docstring)."""
    assert move.new_id is not None
    applied = [m for m in MIGRATIONS if m.name in move.migrations]
    with run_locks(results, move.old_id, move.new_id):
        _journal(results, event="begin", old=move.old_id, new=move.new_id, migrations=move.migrations,
                 learner=move.learner, env_id=move.env_id, protocol=move.protocol)
        step(f"journal: begin {move.old_id}")
        old_main = run_path(results, move.old_id)
        if old_main.is_file():  # else a killed migration removed it after the copy was complete
            table, row = _read_row(old_main)
            _copy_artifacts(results, move, applied, step)
            for side in (updates_path, learn_path):
                if side(results, move.old_id).is_file():
                    side_table = pq.read_table(side(results, move.old_id))
                    atomic_write_table(_replace_column(side_table, "run_id", move.new_id), side(results, move.new_id))
                    step(f"wrote {side(results, move.new_id).relative_to(results)}")
            assert move.new_config is not None
            values = new_row(row, move.old_id, move.new_id, move.new_config)
            for column in RENAMED_COLUMNS:
                table = _replace_column(table, column, values[column])
            atomic_write_table(table, run_path(results, move.new_id))  # the row last: now the new run exists
            step(f"wrote runs/{move.new_id}.parquet")
        _mirror(results, tracker, move, step)
        _remove_old(results, move, step)
        _journal(results, event="done", old=move.old_id, new=move.new_id)
        step(f"journal: done {move.old_id}")
    move.status = "migrated"


# ------------------------------------------------------------------ manifests
def _templates(results: Path, moves: list[RunMove], journal: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Old configs without their per-run keys, by old configuration key (to rebuild planned runs)."""
    out: dict[str, dict[str, Any]] = {}

    def add(config: dict[str, Any] | None) -> None:
        if isinstance(config, dict):
            base = {k: v for k, v in config.items() if k != PROVENANCE_KEY}
            out.setdefault(config_key(base), base)

    for move in moves:
        add(move.old_config)
    by_name = {m.name: m for m in MIGRATIONS}
    for entry in journal:
        if entry.get("event") != "begin":
            continue
        try:
            config = json.loads(pq.read_table(run_path(results, str(entry["new"])), columns=["config"]).column(0)[0].as_py())
            applied = [by_name[n] for n in entry.get("migrations", [])]
        except (pa.ArrowException, OSError, ValueError, KeyError):
            continue
        add(unmigrate_config(config, applied))
    return out


def _new_entry(entry: dict[str, Any], ids: dict[str, str], new_keys: dict[str, str],
               templates: dict[str, dict[str, Any]]) -> dict[str, Any] | None:
    """A manifest entry under the current ids, or None if it is current or cannot be rebuilt."""
    rid = str(entry.get("run_id"))
    rebuilt = _rebuild(entry, rid, _candidates(entry, rid, ids, templates))
    if rebuilt is False:
        return None
    new_id, new_key = rebuilt or (ids.get(rid), None)
    if new_id is None:
        return None
    new_key = new_key or new_keys.get(new_id)
    out = {**entry, "run_id": new_id}
    if "config_key" in entry and new_key:
        out["config_key"] = new_key
    return out


def _candidates(entry: dict[str, Any], rid: str, ids: dict[str, str],
                templates: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """The templates that may rebuild the entry's config: the one of its ``config_key``, else (for
    an id no run file moved) every template of its preset, algo, protocol and chain."""
    if entry.get("config_key") in templates:
        return [templates[entry["config_key"]]]
    if rid in ids:
        return []
    return [t for t in templates.values()
            if t.get("preset") == entry.get("preset") and (t.get("algo") or {}).get("name") == entry.get("algo")
            and (t.get("protocol") or {}).get("name") == entry.get("protocol")
            and (t.get("chain") or {}).get("name") == entry.get("chain")]


def _rebuild(entry: dict[str, Any], rid: str, candidates: list[dict[str, Any]]) -> tuple[str, str] | bool | None:
    """``(new id, new config key)`` from the first candidate whose config, with the entry's per-run
    keys, has the entry's id; False when that config cannot be migrated or needs no migration (the
    entry stays as it is); None when no candidate has the entry's id."""
    for template in candidates:
        config = {**template, **{k: entry.get(k) for k in PER_RUN_KEYS}}
        if run_identity(config) != rid:
            continue
        try:
            migrated, applied = migrate_config(config)
        except MigrationError:
            return False
        if not applied:
            return False
        return run_identity(migrated), config_key(migrated)
    return None


def _manifest_moves(results: Path, moves: list[RunMove], journal: list[dict[str, Any]]
                    ) -> list[tuple[Path, str, dict[str, Any], int]]:
    """``(old file, new name, new body, entries changed)`` of every manifest that names old ids."""
    ids, new_keys = _known_ids(moves, journal)
    templates = _templates(results, moves, journal)
    directory = manifests_dir(results)
    out = []
    for path in sorted(directory.glob("*.json")) if directory.is_dir() else []:
        body = _read_manifest(path)
        rewritten = _rewrite_manifest(path, body, ids, new_keys, templates) if body is not None else None
        if rewritten is not None:
            out.append(rewritten)
    return out


def _known_ids(moves: list[RunMove], journal: list[dict[str, Any]]) -> tuple[dict[str, str], dict[str, str]]:
    """Old id -> new id of every run moved (by the journal of an earlier, interrupted migration,
    and by this one), and new id -> its config key."""
    ids = {str(e["old"]): str(e["new"]) for e in journal if e.get("event") == "begin"}
    new_keys: dict[str, str] = {}
    for move in moves:
        if move.new_id and move.new_config is not None:
            ids[move.old_id] = move.new_id
            new_keys[move.new_id] = config_key({k: v for k, v in move.new_config.items() if k != PROVENANCE_KEY})
    return ids, new_keys


def _read_manifest(path: Path) -> dict[str, Any] | None:
    """The manifest's body, or None when it is unreadable or not a manifest (it is left alone)."""
    try:
        body = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(body, dict) or not isinstance(body.get("runs"), list):
        return None
    return body


def _rewrite_manifest(path: Path, body: dict[str, Any], ids: dict[str, str], new_keys: dict[str, str],
                      templates: dict[str, dict[str, Any]]) -> tuple[Path, str, dict[str, Any], int] | None:
    """The manifest under the current ids, or None when none of its entries changes. A name that
    ends in the hash of its plan's ids gets the hash of the new ids."""
    entries, changed = [], 0
    for entry in body["runs"]:
        new = _new_entry(entry, ids, new_keys, templates) if isinstance(entry, dict) else None
        entries.append(new if new is not None else entry)
        changed += new is not None
    if not changed:
        return None
    name = path.stem
    old_ids = [str(e.get("run_id")) for e in body["runs"] if isinstance(e, dict)]
    suffix = f"-{plan_hash(old_ids)}"
    if name.endswith(suffix):
        name = name[: -len(suffix)] + f"-{plan_hash(str(e.get('run_id')) for e in entries if isinstance(e, dict))}"
    return path, name, {**body, "name": name if body.get("name") == path.stem else body.get("name"), "runs": entries}, changed


def _write_json(path: Path, body: dict[str, Any]) -> None:
    write_atomically(path, lambda fh: fh.write(json.dumps(body, indent=1).encode("utf-8")))


def move_manifest(results: Path, path: Path, name: str, body: dict[str, Any], step: Step) -> None:
    """Write the manifest under its new name, then remove the old file. A manifest already there
    under that name (the same selection launched at the current code) is kept as the base: a real
    launch wins over a dry run, then the latest launch; the earliest ``first_created_at`` is kept."""
    target = manifests_dir(results) / f"{name}.json"
    if target != path and target.is_file():
        try:
            existing = json.loads(target.read_text())
        except (OSError, ValueError):
            existing = None
        if isinstance(existing, dict):
            rank = lambda b: (not b.get("dry_run", False), str(b.get("created_at", "")))
            firsts = [str(b.get("first_created_at") or b.get("created_at") or "") for b in (existing, body)]
            base = existing if rank(existing) >= rank(body) else body
            body = {**base, "first_created_at": min(f for f in firsts if f) if any(firsts) else base.get("first_created_at")}
    _write_json(target, body)
    step(f"wrote manifests/{target.name}")
    if target != path:
        path.unlink()
        step(f"removed manifests/{path.name}")
    _journal(results, event="manifest", old=path.stem, new=name)


# ------------------------------------------------------------------ the command
def check_directory(results: Path) -> None:
    if not results.is_dir():
        raise MigrateError(f"{results}: no such directory; give the results_dir of a sweep (it holds runs/)")
    if not runs_dir(results).is_dir():
        raise MigrateError(f"{results}: not a results directory (no runs/ in it); give the results_dir of a sweep")


def migrate(results: str | Path, dry_run: bool = False, on_step: Step | None = None, console: Any = None,
            progress: bool = True) -> Report:
    """Migrate every run of ``results`` (see the module docstring); ``on_step`` is called after each
    change on disk (tests stop the migration there, as a kill would)."""
    results = Path(results).resolve()
    check_directory(results)
    console = console or make_console(stderr=True)
    t0 = time.perf_counter()
    held = held_run_locks(results)
    if held:
        message = (f"{results}: a sweep is running here ({len(held)} run lock(s) held in runs/.locks, e.g. "
                   f"{', '.join(held[:3])}); let it finish or stop it, then migrate")
        if not dry_run:
            raise MigrateError(message)
        # one line, however long the path: a warning is grepped for, not read in a terminal only
        console.print(f"[yellow]warning:[/yellow] {escape(message)}", soft_wrap=True)
    if dry_run:
        journal = read_journal(results)
        moves = plan_moves(results, journal)
        manifests = _manifest_moves(results, moves, journal)
        return Report(moves, [(p.stem, n, c) for p, n, _, c in manifests], time.perf_counter() - t0)
    step = on_step or (lambda what: None)
    with migration_lock(results):
        journal = read_journal(results)
        moves = plan_moves(results, journal)
        todo = [m for m in moves if m.status in ("migrate", "resume")]
        tracker = _open_tracker(results, todo)
        _run_moves(results, todo, tracker, step, console, progress)
        journal = read_journal(results)
        manifests = _manifest_moves(results, moves, journal)
        for path, name, body, _ in manifests:
            move_manifest(results, path, name, body, step)
    return Report(moves, [(p.stem, n, c) for p, n, _, c in manifests], time.perf_counter() - t0)


def _open_tracker(results: Path, todo: list[RunMove]) -> Any:
    """The MLflow mirror, only if a run to move was mirrored (a broken store stops before any change)."""
    if not any(marker_path(results, m.old_id).is_file() for m in todo):
        return None

    try:
        check_reachable(results)
        return Tracker(results)
    except TrackingError as exc:
        raise MigrateError(f"runs of {results} are mirrored in MLflow, which must be updated with them: {exc}") from exc


def _run_moves(results: Path, todo: list[RunMove], tracker: Any, step: Step, console: Any, show: bool) -> None:
    if not todo:
        return

    columns = (TextColumn("migrating"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn())
    with Progress(*columns, console=console, transient=True, disable=not show) as bar:
        task = bar.add_task("runs", total=len(todo))
        for move in todo:
            move_run(results, move, tracker, step)
            bar.advance(task)


STATUS_TEXT = {"migrated": "migrated", "migrate": "to migrate", "resume": "to finish", "duplicate": "duplicate (left)",
               "left": "left", "current": "current"}


def print_report(report: Report, dry_run: bool, out: Any) -> None:
    """What was (or, with ``dry_run``, would be) done: a table of the runs not already current,
    a line per manifest rewritten, and a line of counts."""
    shown = [m for m in report.moves if m.status != "current"]
    if shown:
        out.print(_runs_table(shown, dry_run))
    for old, new, changed in report.manifests:
        verb = "would be rewritten" if dry_run else "rewritten"
        out.print(f"manifest {old}: {changed} planned run(s) {verb}" + (f", renamed {new}" if new != old else ""))
    out.print(_summary_line(report, dry_run))
    if not dry_run and not report.count("migrated") and not report.manifests:
        out.print("nothing to do: every run is at the current ids")


def _summary_line(report: Report, dry_run: bool) -> str:
    """How many runs had each status, and how long it took (or that it was a dry run)."""
    counts = {s: report.count(s) for s in STATUS_TEXT if report.count(s)}
    summary = ", ".join(f"{n} {STATUS_TEXT[s]}" for s, n in counts.items()) or "no runs"
    verb = "dry run" if dry_run else f"done in {report.seconds:.1f} s"
    return f"{len(report.moves)} run(s): {summary}; {verb}" + ("; nothing was written" if dry_run else "")


def _runs_table(shown: list[RunMove], dry_run: bool) -> Any:

    table = Table(title="runs" + (" (dry run: nothing written)" if dry_run else ""))
    for column in ("old id", "new id", "learner", "env", "status", "why"):
        table.add_column(column, overflow="fold", no_wrap=column != "why")
    for m in sorted(shown, key=lambda m: (m.status, m.learner, m.env_id, m.old_id)):
        why = m.reason or ", ".join(m.migrations)
        table.add_row(m.old_id, m.new_id or "-", m.learner, m.env_id, STATUS_TEXT.get(m.status, m.status), why)
    return table


def build_parser() -> argparse.ArgumentParser:
    """The command's parser, apart from parsing: the docs' command-line reference is generated from it."""
    parser = OneLineParser(prog="python -m runners.migrate", description=(
        "Rewrite the runs of a results directory written before a change of the run config's vocabulary "
        f"({', '.join(f'{m.name} ({m.commit})' for m in MIGRATIONS)}) under the ids the current code gives them."))
    parser.add_argument("results_dir", type=Path, help="the results directory of a sweep (holds runs/)")
    parser.add_argument("--dry-run", action="store_true", help="print what would be done; write nothing")
    add_debug_flag(parser)
    return parser


def parse_args(argv: list[str]) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)

    def body() -> int:
        args = parse_args(argv)
        report = migrate(args.results_dir, dry_run=args.dry_run)
        print_report(report, args.dry_run, make_console(width=None if sys.stdout.isatty() else 200))
        return 0

    return run_cli(body, (), argv)


if __name__ == "__main__":
    sys.exit(main())
