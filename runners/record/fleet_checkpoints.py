"""Where a sweep keeps its fleets' training checkpoints, and which fleets have one.

A fleet of runs (:mod:`runners.execute.jobs`) checkpoints its training in the results directory
(:mod:`morality_gym.baselines.fleet.checkpoint`), so that a sweep resumed after a kill finishes
the fleet's training instead of starting it over. Each fleet has two files in
``<results>/checkpoints/``, named after a hash of its sorted run ids:

* ``fleet-<hash>.pt``: the training state (written by the fleet, atomically);
* ``fleet-<hash>.json``: the fleet's runs in its order, with their configs, plain JSON, written
  before training starts, so that planning (:func:`fleets_to_form`, :func:`runners.plan.fleets.make_jobs`)
  can form the same fleet again without loading torch, and a worker can build it again even when
  some of its runs were recorded before a kill (:func:`fleet_to_train`).

Both are removed once every run of the fleet is recorded, and at a sweep's start when every run
of a fleet is already finished ``ok`` (a fleet killed just after its last run was written).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from morality_gym.clitools import write_atomically
from morality_gym.results.recording import finished_status
from morality_gym.results.run_config import RunConfig

CHECKPOINTS_DIR = "checkpoints"


def checkpoints_dir(results_dir: str | Path) -> Path:
    return Path(results_dir) / CHECKPOINTS_DIR


def fleet_name(run_ids: Iterable[str]) -> str:
    """``fleet-<hash>``: the same name for the same runs, whatever their order."""
    digest = hashlib.sha256("\n".join(sorted(run_ids)).encode()).hexdigest()[:16]
    return f"fleet-{digest}"


def checkpoint_path(results_dir: str | Path, run_ids: Iterable[str]) -> Path:
    """The training checkpoint of the fleet of ``run_ids``."""
    return checkpoints_dir(results_dir) / f"{fleet_name(run_ids)}.pt"


Item = tuple[str, RunConfig]


@dataclass(frozen=True)
class RecordedFleet:
    """A fleet as its run list records it: its checkpoint's path and its runs (id, config) in order."""

    checkpoint: Path
    runs: tuple[Item, ...]

    @property
    def ids(self) -> frozenset[str]:
        return frozenset(run_id for run_id, _ in self.runs)


def _runs_path(checkpoint: Path) -> Path:
    return checkpoint.with_suffix(".json")


def write_fleet_runs(results_dir: str | Path, runs: Sequence[Item]) -> Path:
    """Record the fleet's runs (in its order, with their configs) next to its checkpoint,
    atomically; returns the checkpoint's path."""
    path = checkpoint_path(results_dir, [run_id for run_id, _ in runs])
    text = json.dumps({"runs": [[run_id, config.to_json()] for run_id, config in runs]}, sort_keys=True)
    write_atomically(_runs_path(path), lambda fh: fh.write(text.encode("utf-8")))
    return path


def remove_fleet(checkpoint: Path) -> None:
    """Delete a fleet's checkpoint, the temporary file a kill may have left, and its run list."""
    for path in (checkpoint, checkpoint.with_name(checkpoint.name + ".tmp"), _runs_path(checkpoint)):
        path.unlink(missing_ok=True)


def recorded_fleets(results_dir: str | Path) -> list[RecordedFleet]:
    """Every fleet with a run list in ``results_dir`` (an unreadable list is skipped)."""
    directory = checkpoints_dir(results_dir)
    if not directory.is_dir():
        return []
    fleets = []
    for listing in sorted(directory.glob("fleet-*.json")):
        try:
            runs = tuple((str(run_id), RunConfig.from_json(config)) for run_id, config in json.loads(listing.read_text())["runs"])
        except (OSError, ValueError, KeyError, TypeError):
            continue
        fleets.append(RecordedFleet(listing.with_suffix(".pt"), runs))
    return fleets


def checkpointed_fleets(results_dir: str | Path) -> list[tuple[str, ...]]:
    """The sorted run ids of every fleet that has a training checkpoint in ``results_dir``."""
    return [tuple(sorted(f.ids)) for f in recorded_fleets(results_dir) if f.checkpoint.exists()]


def _recorded(results_dir: Path, run_ids: Iterable[str]) -> bool:
    return all(finished_status(results_dir, run_id) is not None for run_id in run_ids)


def fleets_to_form(results_dir: str | Path, todo: Iterable[str]) -> list[tuple[str, ...]]:
    """The runs still to do of each checkpointed fleet whose other runs are all recorded (a fleet
    killed while it recorded its runs after training): the fleets planning forms again
    (:func:`runners.plan.fleets.make_jobs`), so that they resume from their checkpoints."""
    todo = set(todo)
    out = []
    for fleet in recorded_fleets(results_dir):
        left = fleet.ids & todo
        if fleet.checkpoint.exists() and len(left) >= 2 and _recorded(Path(results_dir), fleet.ids - left):
            out.append(tuple(sorted(left)))
    return out


def fleet_to_train(results_dir: str | Path, mine: Sequence[Item]) -> list[Item]:
    """The runs to build the fleet of ``mine`` from: the runs of a checkpointed fleet that holds
    exactly ``mine`` (in its order: the checkpoint fits only that order), or that holds ``mine``
    and runs already recorded (it was killed while recording them: its checkpoint holds the end of
    training, and only ``mine`` are recorded now); else ``mine`` itself."""
    ids = {run_id for run_id, _ in mine}
    for fleet in recorded_fleets(results_dir):
        if fleet.checkpoint.exists() and fleet.ids >= ids and _recorded(Path(results_dir), fleet.ids - ids):
            return list(fleet.runs)
    return list(mine)


def remove_stale(results_dir: str | Path) -> list[Path]:
    """Remove the checkpoints of fleets whose runs are all finished ``ok`` (nothing left to resume);
    returns the checkpoints removed."""
    removed = []
    for fleet in recorded_fleets(results_dir):
        if all(finished_status(Path(results_dir), run_id) == "ok" for run_id in fleet.ids):
            remove_fleet(fleet.checkpoint)
            removed.append(fleet.checkpoint)
    return removed
