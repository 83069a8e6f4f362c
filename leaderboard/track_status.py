"""Whether a chain's track is done: which of its learners' numbers may be shown unmarked.

Why one place: ``releases/track-v1`` (:mod:`leaderboard.track_release`) records the status of every
(track, learner), and the Generalisation page (:mod:`leaderboard.track`) marks every number of a
learner whose runs are not all done, whether it reads a release or a results directory. A result
of 2 seeds at one rollout must never look like the release's answer.

A chain's track (``Utility-v2``, ...) is complete for a trained learner when it has at least
:data:`REQUIRED_SEEDS` finished runs, each trained for at least the required budget (the one its
learning curve chose; :data:`REQUIRED_BUDGET` unless a release records another), and its learning
curve (``curves/<track>-<learner>.csv``) exists. Random is exact: one run. A learner of
:data:`TRACK_LEARNERS` with no run is listed as missing. Submitted entries (a user's policy, a
language model) are not part of the release's requirement; a language model scored on a sample of
the pairs is marked as a sample wherever it is shown (:func:`entry_marks`).
"""

from __future__ import annotations

import csv
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from morality_gym.generalisation.sets import TRACK_CHAINS

#: The learners every chain's track of the release holds (``runners.track --learners``).
TRACK_LEARNERS = ("random", "ppo", "ppo_shaped", "ppo_lag", "cpo")
#: The chains' tracks a release holds: Utility's and DualProcess's, on the v2 splits (issue 44 item 1).
TRACKS = tuple(f"{chain}-v2" for chain in TRACK_CHAINS)
#: Seeds per trained learner and chain (issue 44: 5 seeds, 41-45).
REQUIRED_SEEDS = 5
#: Steps per run below which a learner is incomplete: issue 44's floor (at least 10M env steps per
#: run), until the learning curves choose a larger one (a release records the one it was built for).
REQUIRED_BUDGET = 10_000_000
#: The columns of a learning curve (``benchmarks.track_curve`` and the track's fleets write them).
CURVE_FIELDS = ("learner", "chain", "seed", "steps", "mean_range_score", "cpu_seconds")
CURVES_DIR = "curves"


@dataclass(frozen=True)
class Requirement:
    """What a complete chain's track holds (recorded in a release's manifest)."""

    seeds: int = REQUIRED_SEEDS
    budget: int = REQUIRED_BUDGET
    learners: tuple[str, ...] = TRACK_LEARNERS
    tracks: tuple[str, ...] = TRACKS

    def as_dict(self) -> dict[str, Any]:
        return {"seeds": self.seeds, "budget": self.budget, "learners": list(self.learners), "tracks": list(self.tracks)}

    @classmethod
    def from_dict(cls, body: Mapping[str, Any] | None) -> Requirement:
        if not body:
            return cls()
        return cls(int(body["seeds"]), int(body["budget"]), tuple(body["learners"]), tuple(body["tracks"]))


def curve_name(track: str, learner: str) -> str:
    """``curves/<track>-<learner>.csv``: where a fleet writes a learner's curve (``Utility-v2-ppo.csv``)."""
    return f"{CURVES_DIR}/{track}-{learner}.csv"


class CurveError(ValueError):
    """A learning-curve file that cannot be read; one line naming the file and what is wrong."""


def read_curve(path: Path) -> list[dict[str, Any]]:
    """The rows of a curve CSV, typed; a wrong header or a non-number is a :class:`CurveError`."""
    try:
        with path.open(newline="") as fh:
            reader = csv.DictReader(fh)
            if tuple(reader.fieldnames or ()) != CURVE_FIELDS:
                raise CurveError(f"{path}: columns {reader.fieldnames}, a learning curve has {list(CURVE_FIELDS)}")
            rows = []
            for line, row in enumerate(reader, start=2):
                try:
                    rows.append({"learner": row["learner"], "chain": row["chain"], "seed": int(row["seed"]),
                                 "steps": int(row["steps"]), "mean_range_score": float(row["mean_range_score"]),
                                 "cpu_seconds": float(row["cpu_seconds"])})
                except (TypeError, ValueError) as exc:
                    raise CurveError(f"{path}, line {line}: not a number where one is expected ({exc})") from exc
    except OSError as exc:
        raise CurveError(f"{path}: cannot read the learning curve ({exc.strerror or exc})") from exc
    return rows


def chain_tracks(records: Iterable[Mapping[str, Any]]) -> list[str]:
    """The chains' tracks the runs belong to (``Utility-v2``), in first-seen order; not the mixed one."""
    out: dict[str, None] = {}
    for record in records:
        if record.get("chain"):
            version = record.get("split_version", 1)
            out[record["chain"] if version == 1 else f"{record['chain']}-v{version}"] = None
    return list(out)


def learner_status(track: str, learner: str, records: list[Mapping[str, Any]], curve_exists: bool,
                   need: Requirement) -> list[str]:
    """Why ``learner``'s numbers on ``track`` are incomplete (empty: complete). ``records``: the
    learner's finished runs on that track."""
    if not records:
        return ["no run"]
    if learner == "random":
        return []
    reasons = []
    seeds = sorted({r["seed"] for r in records})
    if len(seeds) < need.seeds:
        reasons.append(f"{len(seeds)} of {need.seeds} seeds")
    short = sorted({int(r.get("budget") or 0) for r in records if int(r.get("budget") or 0) < need.budget})
    if short:
        reasons.append(f"budget {', '.join(f'{b:,}' for b in short)} steps, below the {need.budget:,} required")
    failed = [str(r["seed"]) for r in records if r.get("failed")]
    if failed:
        reasons.append(f"seed {', '.join(failed)} failed")
    if not curve_exists:
        reasons.append("no learning curve")
    return reasons


def status(records: list[Mapping[str, Any]], curves: Iterable[str], need: Requirement) -> dict[str, dict[str, list[str]]]:
    """track -> learner -> reasons it is incomplete, for every track of the requirement (one without
    a run: every learner ``no run``) and every chain's track the runs hold, and every learner of the
    requirement or with a trained run (submitted entries are left out: :func:`entry_marks`)."""
    have = set(curves)
    out: dict[str, dict[str, list[str]]] = {}
    for track in dict.fromkeys([*need.tracks, *chain_tracks(records)]):
        mine = [r for r in records if r.get("chain") and _track_of(r) == track and not r.get("submitted")]
        learners = list(dict.fromkeys([*need.learners, *(r["learner"] for r in mine)]))
        out[track] = {lr: learner_status(track, lr, [r for r in mine if r["learner"] == lr],
                                         curve_name(track, lr) in have, need) for lr in learners}
    return out


def _track_of(record: Mapping[str, Any]) -> str:
    version = record.get("split_version", 1)
    return str(record["chain"]) if version == 1 else f"{record['chain']}-v{version}"


def entry_marks(record: Mapping[str, Any]) -> str:
    """The mark every number of a submitted entry carries: a sample of the pairs says so."""
    sample = record.get("sample")
    if sample:
        return f"sample: {sample['pairs']} of {sample['of']} pairs"
    return ""
