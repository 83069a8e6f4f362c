"""Damaged result files: move them aside, say so, and let the run be planned again.

A run's Parquet file is written atomically, so a half-written file never appears under its name;
but a full disk, a copy that was cut short or a bad sector can still leave an unreadable
``runs/<run_id>.parquet``. A sweep that cannot read it must neither crash (it could never resume)
nor trust it, so the file is moved to ``runs/.quarantine/`` (never deleted: it may still be
rescued) with a line in ``runs/.quarantine/index.jsonl`` saying what, when and why. Without the
file the run counts as not done, so the sweep runs it again; its MLflow marker is moved aside
with it, so that the new result replaces the old mirror instead of being skipped as mirrored.

A file of another schema version (written by a newer morality-gym, say) is treated the same way:
moved aside with the reason ``schema version N, this code reads version M`` and its run planned
again (the one rule of :mod:`morality_gym.results.schema`; the leaderboard lists such a file as
unreadable). Only the main run file decides whether a run is done. An unreadable side file
(``<run_id>.learn.parquet``, ``<run_id>.updates.parquet``, any ``<run_id>.<kind>.parquet``) is moved
aside too, and the run stays done. Readers that must not write (the leaderboard) skip unreadable
files and list them instead (:func:`morality_gym.results.schema.read_runs` with ``skipped=``).
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from morality_gym.results.schema import read_jsonl, run_path, runs_dir, table_problem, version_problem

QUARANTINE = ".quarantine"
INDEX = "index.jsonl"
#: What pyarrow and the OS raise for a file that exists but cannot be read as Parquet.
READ_ERRORS = (pa.ArrowException, OSError, ValueError, EOFError)


@dataclass(frozen=True)
class Quarantined:
    """A file moved aside: where it was, where it is, and why."""

    source: Path
    target: Path
    reason: str

    def describe(self, results_dir: Path) -> str:
        def rel(p: Path) -> str:
            try:
                return str(p.relative_to(results_dir))
            except ValueError:
                return str(p)

        what = "the run is planned again" if is_main_run_file(self.source) else "the run itself stays done"
        return f"moved unreadable {rel(self.source)} to {rel(self.target)} ({self.reason}); {what}"


def quarantine_dir(results_dir: str | Path) -> Path:
    return runs_dir(results_dir) / QUARANTINE


def is_main_run_file(path: Path) -> bool:
    """``<run_id>.parquet`` (the run's result) rather than a side file ``<run_id>.<kind>.parquet``."""
    return path.suffix == ".parquet" and "." not in path.stem


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0][:200]}" if text else type(exc).__name__


def quarantine(results_dir: str | Path, path: Path, reason: str, announce: bool = True) -> Quarantined | None:
    """Move ``path`` (and, for a main run file, its MLflow marker) into ``runs/.quarantine/``.

    Returns None if the file is already gone (another process moved it first).
    """
    results_dir = Path(results_dir)
    directory = quarantine_dir(results_dir)
    directory.mkdir(parents=True, exist_ok=True)
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S%fZ")
    target = directory / path.name
    if target.exists():
        target = directory / f"{stamp}-{path.name}"
    try:
        os.replace(path, target)
    except FileNotFoundError:
        return None
    if is_main_run_file(path):
        marker = results_dir / "tracking" / f"{path.stem}.json"
        try:
            os.replace(marker, directory / f"{stamp}-{path.stem}.tracking.json")
        except FileNotFoundError:
            pass
    record = Quarantined(path, target, reason)
    entry = {"file": str(path.relative_to(results_dir)) if path.is_relative_to(results_dir) else str(path),
             "moved_to": str(target.relative_to(results_dir)), "reason": reason,
             "at": datetime.now(UTC).isoformat(timespec="seconds")}
    with open(directory / INDEX, "a") as fh:
        fh.write(json.dumps(entry) + "\n")
    if announce:
        print(record.describe(results_dir), file=sys.stderr, flush=True)
    return record


def read_table_or_quarantine(results_dir: str | Path, path: Path, columns: list[str] | None = None) -> pa.Table | None:
    """The Parquet table at ``path``; None if it does not exist or was unreadable or of another
    schema version (then moved aside: :func:`morality_gym.results.schema.version_problem`)."""
    if not path.is_file():
        return None
    try:
        main = is_main_run_file(path)
        # a main run file is read whole (one row): its consistency needs its metric, functions and id
        wanted = None if columns is None or main else list(dict.fromkeys([*columns, "schema_version"]))
        table = pq.read_table(path, columns=wanted)
        if main and table.num_rows != 1:
            raise ValueError(f"a run file holds one row, this one {table.num_rows}")
        problem = version_problem(table) or (table_problem(table, path) if main else None)
        if problem is not None:
            raise ValueError(problem)
        return table if columns is None else table.select(columns)
    except READ_ERRORS as exc:
        quarantine(results_dir, path, _first_line(exc))
        return None


def check_run_files(results_dir: str | Path, run_ids: list[str]) -> list[Quarantined]:
    """Read every existing file of these runs in full; move the unreadable ones aside (announced)."""
    results_dir = Path(results_dir)
    moved: list[Quarantined] = []
    directory = runs_dir(results_dir)
    if not directory.is_dir():
        return moved
    wanted = set(run_ids)
    for path in sorted(directory.glob("*.parquet")):
        if path.name.split(".", 1)[0] not in wanted:
            continue
        try:
            table = pq.read_table(path)
            if is_main_run_file(path) and (table.num_rows != 1 or "status" not in table.column_names):
                raise ValueError(f"a run file holds one row with a status, this one {table.num_rows} row(s) "
                                 f"and columns {table.column_names[:3]}...")
            problem = version_problem(table) or (table_problem(table, path) if is_main_run_file(path) else None)
            if problem is not None:
                raise ValueError(problem)
        except READ_ERRORS as exc:
            record = quarantine(results_dir, path, _first_line(exc), announce=False)
            if record is not None:
                moved.append(record)
    return moved


def quarantined_files(results_dir: str | Path) -> list[dict[str, str]]:
    """The entries of ``runs/.quarantine/index.jsonl`` (what sweeps moved aside, oldest first)."""
    return [{k: str(v) for k, v in entry.items()} for entry in read_jsonl(quarantine_dir(results_dir) / INDEX)]


__all__ = ["QUARANTINE", "Quarantined", "check_run_files", "quarantine", "quarantine_dir", "quarantined_files",
           "read_table_or_quarantine", "run_path"]
