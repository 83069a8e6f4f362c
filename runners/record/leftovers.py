"""Temporary files that a killed sweep left in a results directory: found and removed.

Every file of a run (its Parquet files, model, GIF) and every fleet checkpoint is written under a
temporary name and renamed into place, so a kill never leaves half a file under a real name. But
``kill -9`` (or a full disk before the clean-up ran) leaves the temporary file itself:
``runs/.<run_id>.parquet.XXXX.tmp``, ``runs/<run_id>/.model.zip.<pid>.tmp``,
``checkpoints/fleet-<hash>.pt.tmp``. Nothing reads them, but they take space (a checkpoint of a
paper fleet is megabytes) and nothing removed them.

A sweep removes them when it starts, but only those that no live process may still be writing:
a run's temporary files when its run lock (:class:`morality_gym.results.recording.RunLock`, released by the
kernel when its holder dies) is free, and a fleet's temporary checkpoint when the locks of all its
runs are free. Another sweep sharing the directory keeps what it is writing.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator
from pathlib import Path

from morality_gym.results.recording import RunLock
from morality_gym.results.schema import runs_dir
from runners.record.fleet_checkpoints import checkpoints_dir, recorded_fleets


@contextlib.contextmanager
def _free(results_dir: Path, run_ids: Iterable[str]) -> Iterator[bool]:
    """Hold the locks of ``run_ids`` if every one is free (True), else hold none (False)."""
    held: list[RunLock] = []
    try:
        for run_id in run_ids:
            lock = RunLock(results_dir, run_id)
            if not lock.acquire():
                yield False
                return
            held.append(lock)
        yield True
    finally:
        for lock in held:
            lock.release()


def _run_of(tmp: Path, runs: Path) -> str | None:
    """The run id a temporary file belongs to: ``runs/.<run_id>.<...>.tmp`` or ``runs/<run_id>/.<...>.tmp``."""
    if tmp.parent == runs:
        return tmp.name[1:].split(".", 1)[0] or None
    inside = tmp.parent.parent == runs and not tmp.parent.name.startswith(".")  # not .locks, .quarantine
    return tmp.parent.name if inside else None


def remove_leftovers(results_dir: str | Path) -> list[Path]:
    """Remove the temporary files of runs and fleets that no live process writes; returns them."""
    results_dir = Path(results_dir)
    removed: list[Path] = []
    runs = runs_dir(results_dir)
    candidates = [*runs.glob(".*.tmp"), *runs.glob("*/.*.tmp")] if runs.is_dir() else []
    for tmp in candidates:
        run_id = _run_of(tmp, runs)
        if run_id is None:
            continue
        with _free(results_dir, [run_id]) as free:
            if free:
                tmp.unlink(missing_ok=True)
                removed.append(tmp)
    fleets = {f.checkpoint.name + ".tmp": f for f in recorded_fleets(results_dir)}
    for tmp in sorted(checkpoints_dir(results_dir).glob("fleet-*.pt.tmp")):
        fleet = fleets.get(tmp.name)
        with _free(results_dir, sorted(fleet.ids) if fleet is not None else []) as free:
            if free:  # no run list: no fleet can be training (it is written before training starts)
                tmp.unlink(missing_ok=True)
                removed.append(tmp)
    return removed


__all__ = ["remove_leftovers"]
