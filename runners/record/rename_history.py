"""The changes of the recorded run configuration that renamed vocabulary and nothing else.

A run's id is the hash of its recorded config (:mod:`morality_gym.results.identity`), so renaming a key of the
config (not a number, not what runs) gives every run a new id: a results directory written before
the rename is not found by a sweep at the new code, which then plans every run again, and the
leaderboard shows the old runs as superseded. Each :class:`Migration` below is one such rename, as
data: a pure function from the config as the old code wrote it to the config the new code writes
(and back, for the model sidecar ``model.json`` too), with the commit that made the change and why.
:mod:`runners.migrate` applies them, in this order, to the runs of a results directory.

A migration must only rename: :func:`vocabulary_only` checks, run by run, that the only leaves of
the config that differ are the ones the migration declares (``touches``) and that they are strings,
so no number, flag or list can change on the way; and its ``backward`` must give the old config
back exactly, so nothing is lost. ``check`` says whether the result is a config the current code
can run (the class of a learner can be imported). Append a migration here whenever a change of the
run config renames without changing the numbers (and say so in the commit); a change that does
change numbers must not be migrated: its runs are different runs.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from morality_gym.baselines.specs import LEGACY_IMPLEMENTATIONS, LearnerSpec, SpecError
from morality_gym.baselines.targets import TargetError, learner_trains

Config = dict[str, Any]


@dataclass(frozen=True)
class Migration:
    """One rename of the run config's vocabulary (see the module docstring)."""

    name: str
    commit: str  # the commit that made the change (the first whose runs need no migration)
    why: str
    applies: Callable[[Config], bool]  # the config is as the code before ``commit`` wrote it
    forward: Callable[[Config], Config]  # old config -> new config (pure: the argument is not changed)
    backward: Callable[[Config], Config]  # new config -> old config (its exact inverse)
    touches: frozenset[str]  # dotted paths of the only leaves that may differ (all strings)
    sidecar_forward: Callable[[Config], Config] | None = None  # model.json, old -> new
    sidecar_backward: Callable[[Config], Config] | None = None
    sidecar_touches: frozenset[str] = field(default_factory=frozenset)
    check: Callable[[Config], str | None] = lambda config: None  # None, or why the result cannot run now


def _rename(mapping: Mapping[str, Any], old: str, new: str, value: Any) -> dict[str, Any]:
    """``mapping`` with key ``old`` replaced by ``new`` (holding ``value``) at the same position, so
    a file whose keys are not sorted (model.json) comes out as the new code writes it."""
    return {(new if k == old else k): (value if k == old else v) for k, v in mapping.items()}


# ------------------------------------------------------------------ c0db801: learners by _target_
_TARGET_TO_IMPLEMENTATION = {target: name for name, target in LEGACY_IMPLEMENTATIONS.items()}


def _has_implementation(algo: Any) -> bool:
    return isinstance(algo, dict) and algo.get("implementation") in LEGACY_IMPLEMENTATIONS and "target" not in algo


def _algo_to_target(algo: dict[str, Any]) -> dict[str, Any]:
    return _rename(algo, "implementation", "target", LEGACY_IMPLEMENTATIONS[algo["implementation"]])


def _algo_to_implementation(algo: dict[str, Any]) -> dict[str, Any]:
    return _rename(algo, "target", "implementation", _TARGET_TO_IMPLEMENTATION[algo["target"]])


def _target_forward(config: Config) -> Config:
    return {**copy.deepcopy(config), "algo": _algo_to_target(copy.deepcopy(config["algo"]))}


def _target_backward(config: Config) -> Config:
    return {**copy.deepcopy(config), "algo": _algo_to_implementation(copy.deepcopy(config["algo"]))}


def _sidecar_forward(meta: Config) -> Config:
    meta = copy.deepcopy(meta)
    if "implementation" in meta and "target" not in meta:
        meta = _rename(meta, "implementation", "target", LEGACY_IMPLEMENTATIONS[meta["implementation"]])
    if _has_implementation(meta.get("spec")):
        meta["spec"] = _algo_to_target(meta["spec"])
    return meta


def _sidecar_backward(meta: Config) -> Config:
    meta = copy.deepcopy(meta)
    if meta.get("target") in _TARGET_TO_IMPLEMENTATION:
        meta = _rename(meta, "target", "implementation", _TARGET_TO_IMPLEMENTATION[meta["target"]])
    if isinstance(meta.get("spec"), dict) and meta["spec"].get("target") in _TARGET_TO_IMPLEMENTATION:
        meta["spec"] = _algo_to_implementation(meta["spec"])
    return meta


def _learner_runs_now(config: Config) -> str | None:
    """The migrated learner spec is one the current code builds (its class imports)."""
    algo = dict(config["algo"])
    for key in ("return_bounds", "net_arch"):
        if isinstance(algo.get(key), list):
            algo[key] = tuple(algo[key])
    try:
        spec = LearnerSpec(**algo)
        trains = learner_trains(spec.target)
    except (SpecError, TargetError, TypeError, ImportError) as exc:
        return f"the migrated learner spec does not build at this code ({type(exc).__name__}: {exc})"
    if not trains and int(config.get("budget", 0)) != 0:
        return f"{spec.target} does not train but the run has budget {config['budget']}"
    return None


LEARNER_TARGET = Migration(
    name="learner-target",
    commit="c0db801",
    why="learners are named by their class (_target_ in conf/algo/*.yaml, 'target' in the spec) instead of "
        "a short 'implementation' out of a fixed table; same classes, same hyper-parameters, same numbers",
    applies=lambda config: _has_implementation(config.get("algo")),
    forward=_target_forward,
    backward=_target_backward,
    touches=frozenset({"algo.implementation", "algo.target"}),
    sidecar_forward=_sidecar_forward,
    sidecar_backward=_sidecar_backward,
    sidecar_touches=frozenset({"implementation", "target", "spec.implementation", "spec.target"}),
    check=_learner_runs_now,
)

# ------------------------------------------------------------------ 40d6126: submitted runs name no learner class
#: What leaderboard.submit wrote as the algo of a submitted policy's run before 40d6126 (history).
_SUBMITTED = "submitted"


def _is_old_submission(config: Config) -> bool:
    algo = config.get("algo")
    return isinstance(algo, dict) and algo.get("name") == _SUBMITTED and algo.get("implementation") == _SUBMITTED


def _submitted_forward(config: Config) -> Config:
    config = copy.deepcopy(config)
    config["algo"] = {k: v for k, v in config["algo"].items() if k != "implementation"}
    return config


def _submitted_backward(config: Config) -> Config:
    config = copy.deepcopy(config)
    config["algo"] = {**config["algo"], "implementation": _SUBMITTED}
    return config


SUBMITTED_NO_IMPLEMENTATION = Migration(
    name="submitted-no-implementation",
    commit="40d6126",
    why="a submitted policy's run names no learner class, so its algo no longer carries "
        "'implementation: submitted' (the vocabulary of c0db801); the policy and its evaluation are unchanged",
    applies=_is_old_submission,
    forward=_submitted_forward,
    backward=_submitted_backward,
    touches=frozenset({"algo.implementation"}),
)

#: Every migration, oldest first; :mod:`runners.migrate` applies them in this order.
MIGRATIONS: tuple[Migration, ...] = (LEARNER_TARGET, SUBMITTED_NO_IMPLEMENTATION)


# ------------------------------------------------------------------ the invariants
def leaves(value: Any, prefix: str = "") -> dict[str, Any]:
    """Every leaf of nested dicts by dotted path (lists are leaves: compared whole)."""
    if isinstance(value, dict):
        out: dict[str, Any] = {}
        for key, item in value.items():
            out.update(leaves(item, f"{prefix}.{key}" if prefix else str(key)))
        return out
    return {prefix: value}


def vocabulary_only(old: Config, new: Config, touches: frozenset[str]) -> str | None:
    """None if ``new`` differs from ``old`` only in string leaves at ``touches``; else what differs.

    Types count (``1`` and ``1.0`` and ``True`` are three different values), so no number, flag or
    list can change unnoticed.
    """
    a, b = leaves(old), leaves(new)
    changed = sorted(p for p in a.keys() | b.keys()
                     if p not in a or p not in b or type(a[p]) is not type(b[p]) or a[p] != b[p])
    outside = [p for p in changed if p not in touches]
    if outside:
        return f"the migration changes {', '.join(outside[:5])} (only {', '.join(sorted(touches))} may change)"
    not_text = [p for p in changed if not isinstance(a.get(p, ""), str) or not isinstance(b.get(p, ""), str)]
    if not_text:
        return f"the migration changes non-text values at {', '.join(not_text)}"
    return None


class MigrationError(ValueError):
    """A config cannot be migrated safely; the message says which rule it breaks."""


def migrate_config(config: Config) -> tuple[Config, list[Migration]]:
    """``config`` brought to the current vocabulary, and the migrations applied (in order).

    Raises :class:`MigrationError` when a migration would change more than vocabulary, is not
    undone exactly by its inverse, or leaves a config the current code cannot run.
    """
    applied: list[Migration] = []
    current = config
    for migration in MIGRATIONS:
        if not migration.applies(current):
            continue
        try:
            new = migration.forward(current)
        except (KeyError, TypeError, ValueError) as exc:
            raise MigrationError(f"{migration.name}: cannot apply ({type(exc).__name__}: {exc})") from exc
        problem = vocabulary_only(current, new, migration.touches)
        if problem is None and migration.backward(new) != current:
            problem = "its inverse does not give the old config back"
        if problem is None:
            problem = migration.check(new)
        if problem is not None:
            raise MigrationError(f"{migration.name}: {problem}")
        applied.append(migration)
        current = new
    return current, applied


def migrate_sidecar(meta: Config, applied: list[Migration]) -> Config:
    """A model sidecar (``model.json``) through the sidecar part of the migrations its run took."""
    current = meta
    for migration in applied:
        if migration.sidecar_forward is None:
            continue
        new = migration.sidecar_forward(current)
        problem = vocabulary_only(current, new, migration.sidecar_touches)
        if problem is None and migration.sidecar_backward is not None and migration.sidecar_backward(new) != current:
            problem = "its inverse does not give the old model.json back"
        if problem is not None:
            raise MigrationError(f"{migration.name} (model.json): {problem}")
        current = new
    return current


def unmigrate_config(config: Config, applied: list[Migration]) -> Config:
    """The inverse of :func:`migrate_config` for the migrations ``applied`` (used to rebuild an old
    directory in tests and to prove that nothing is lost)."""
    for migration in reversed(applied):
        config = migration.backward(config)
    return config


def unmigrate_sidecar(meta: Config, applied: list[Migration]) -> Config:
    for migration in reversed(applied):
        if migration.sidecar_backward is not None:
            meta = migration.sidecar_backward(meta)
    return meta
