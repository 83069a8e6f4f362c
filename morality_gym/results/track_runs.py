"""A generalisation-track run's files: their names, the record every run of a command shares, and the check of a done run.

``runners.track`` writes these runs and ``leaderboard.track``, ``leaderboard.track_release`` and
``leaderboard.llm_track`` read or add to them. The names and the record live here, below both, so
that reading a track's results loads neither the trainer nor torch (the site build imported
``runners.track`` for two file names, and with it SB3 and torch: seconds on every build).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from morality_gym.clitools import UserError
from morality_gym.generalisation.sets import EvalSet
from morality_gym.generator.grammar import GRAMMAR_VERSION
from morality_gym.generator.splits import split_manifest

#: A run's record, written last: a run directory that has one is done.
RESULT = "result.json"
#: One row per evaluated (env id, chain) pair: exact metric, oracle bounds, Random's metric, scores.
PAIRS = "pairs.parquet"
#: The record's format; a change that old readers would misread raises it.
FORMAT = 1


class TrackError(UserError):
    """A results directory whose done runs disagree with the command (budget, splits)."""


def run_name(learner: str, seed: int | None, submitted: bool = False, chain: str | None = None, version: int = 1) -> str:
    """``<learner>-s<seed>``; a chain's track prefixes the chain (``Utility-ppo-s41``), on v2 splits
    with the version (``Utility-v2-ppo-s41``)."""
    name = f"{learner}-{'submitted' if submitted else 'sexact' if seed is None else f's{seed}'}"
    return name if chain is None else f"{chain}-{name}" if version == 1 else f"{chain}-v{version}-{name}"


def expected_record(budget: int, sets: dict[str, EvalSet], chain: str | None = None, version: int = 1) -> dict[str, Any]:
    """What every run of this command must agree on (``chain``: None for the mixed track)."""
    return {"format": FORMAT, "train_split": "train", "train_digest": split_manifest("train").digest,
            "grammar_version": GRAMMAR_VERSION, "chain": chain, **({"split_version": version} if version != 1 else {}),
            "sets": {name: s.source for name, s in sets.items()}}


def check_done(record: dict[str, Any], expected: dict[str, Any], budget: int, path: Path) -> None:
    """Refuse a done run that the command would mix with its own: other splits, sets or budget.

    Skipping it silently would put runs of two experiments in one table."""
    for key, value in expected.items():
        if record.get(key) != value:
            raise TrackError(f"{path}: its {key} is {record.get(key)!r}, this command's {value!r}. Fix: use another "
                             "--out, or delete that run to redo it")
    if record["learner"] != "random" and not record.get("submitted") and record.get("budget") != budget:
        raise TrackError(f"{path}: trained for {record.get('budget')} steps, this command asks {budget}. Fix: use "
                         "another --out, or the same --budget")
