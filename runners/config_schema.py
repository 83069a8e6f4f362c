"""The sweep's typed configuration: frozen dataclasses, registered as Hydra structured configs.

Hydra composes ``conf/`` over these schemas, so a misspelt key or a value of the wrong type fails
while the configuration is composed (:func:`runners.sweep.compose_check` turns Hydra's message
into one line with the closest valid key). Each default is defined once:

* a default every option of a group shares is a field default here (or, for learners and
  protocols, in :class:`~morality_gym.baselines.specs.LearnerSpec` /
  :class:`~morality_gym.baselines.specs.ProtocolSpec`);
* an option's own values are in its file (``conf/algo/ppo.yaml``, ``conf/preset/smoke.yaml``),
  which states only what differs from the field defaults.

``conf/config.yaml`` starts its defaults list with ``sweep_schema`` (:class:`Sweep`), which types
every group: ``algo`` is a mapping of algo names to :class:`AlgoFile`, so a user's algo file found
on the search path is checked exactly like a built-in one, with no line to add to it. The two
launchers differ in their keys, so each launcher file names its own schema
(``defaults: [/schema/launcher/<name>@_here_, _self_]``).

What a type cannot say (ranges, one setting against another, hyper-parameters against the
learner's class, chain coverage) is checked by :mod:`runners.config` after composition.
"""

from __future__ import annotations

import dataclasses
import functools
import re
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from morality_gym.baselines import typed
from morality_gym.baselines.specs import CONF_DIR, LearnerSpec, ProtocolSpec, RandomReplay
from morality_gym.clitools import did_you_mean
from morality_gym.constants import BETA, MAX_STEPS
from morality_gym.norms.chain import parse_chain
from morality_gym.norms.metric import BoundChain, bind_chain
from runners.identity import config_key, run_id_of
from runners.results_schema import SCHEMA_VERSION


@dataclass(frozen=True)
class PlanningOverride:
    """Some of :class:`Planning`'s values, replaced under one protocol (unset: the algo's own)."""

    steps_per_s: float | None = None
    update_share: float | None = None
    overhead_s: float | None = None
    fleet_speedup: float | None = None


@dataclass(frozen=True)
class Planning:
    """The sweep plan's time estimate for one learner (never part of a run's identity).

    ``steps_per_s``: training steps per second with the algo file's own settings, one thread;
    ``update_share``: the part of a step's time that is gradient work (scales with the epochs);
    ``overhead_s``: what every run pays regardless of its budget; ``fleet_speedup``: the fleet
    engine's measured gain at K >= 12 over single runs (1: no gain assumed). The defaults are a
    guess for a learner nobody measured; each built-in algo file states its fitted values.
    """

    steps_per_s: float = 2000.0
    update_share: float = 1.0
    overhead_s: float = 1.0
    fleet_speedup: float = 1.0
    protocols: Mapping[str, PlanningOverride] = field(default_factory=dict)


@dataclass(frozen=True)
class SweepOverheads:
    """What a sweep pays once, besides its runs, for the plan's time estimate (never part of a run's identity).

    The per-learner :class:`Planning` prices the runs (its ``overhead_s`` is what each run pays);
    a smoke sweep's runs take seconds, and its estimate was 2-8x below the wall time because these
    once-per-sweep costs were left out. ``new_store_s``: creating the MLflow store of a new results
    directory (its SQLite schema migrations, before the first run); ``worker_start_s``: the
    workers starting (imports of torch and SB3; they start in parallel). Mirroring runs into MLflow
    happens in the sweep's process while the workers train, so it is not added. Measured on this
    2-core machine on 2026-11-25 while another sweep ran (load 2.3-3.1): 7.2-8.0 s and 1.85-1.94 s.
    """

    new_store_s: float = 7.5
    worker_start_s: float = 1.9

    def seconds(self, n_runs: int, *, new_store: bool, mlflow: bool) -> float:
        """The overhead of a sweep with ``n_runs`` runs to do (nothing when none is left)."""
        if n_runs == 0:
            return 0.0
        return self.worker_start_s + (self.new_store_s if new_store and mlflow else 0.0)


def _algo_file_fields() -> list[tuple[str, Any, Any]]:
    """:class:`LearnerSpec`'s fields as an algo file spells them: the class is ``_target_``;
    ``name`` (default: the file's name) and ``label`` (default: the name) may be left out;
    ``protocol`` is set by a protocol, never by a file; plus the plan's ``planning``."""
    hints = typing.get_type_hints(LearnerSpec)
    out: list[tuple[str, Any, Any]] = [("_target_", str, dataclasses.field()),
                                       ("name", str | None, dataclasses.field(default=None)),
                                       ("label", str | None, dataclasses.field(default=None))]
    for f in dataclasses.fields(LearnerSpec):
        if f.name in ("name", "label", "target", "protocol"):
            continue
        default = (dataclasses.field(default=f.default) if f.default is not dataclasses.MISSING
                   else dataclasses.field(default_factory=f.default_factory))  # type: ignore[arg-type]
        out.append((f.name, hints[f.name], default))
    out.append(("planning", Planning, dataclasses.field(default_factory=Planning)))
    return out


#: An algo file (``conf/algo/<name>.yaml``): derived from :class:`LearnerSpec`, not a copy of it.
AlgoFile = dataclasses.make_dataclass("AlgoFile", _algo_file_fields(), frozen=True,
                                      namespace={"__module__": __name__, "__doc__": _algo_file_fields.__doc__})


@dataclass(frozen=True)
class Preset:
    """How much each run trains and evaluates (``conf/preset/<name>.yaml``).

    ``rollout_cap``: the most environment steps any learner collects per update (``n_steps`` x
    ``n_envs``); a learner whose rollout is longer gets ``n_steps = rollout_cap // n_envs``. It
    applies to every learner, a user's too, which ``algo_overrides`` (keyed by algo name) cannot.
    """

    name: str
    seeds: tuple[int, ...]
    budget: int
    eval_episodes: int
    learn_eval_every: int
    learn_eval_episodes: int
    budget_overrides: Mapping[str, int] = field(default_factory=dict)
    algo_overrides: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    rollout_cap: int | None = None

    def __post_init__(self) -> None:
        where = f"preset={self.name}"
        if not self.seeds:
            raise ValueError(f"{where}.seeds: expected a non-empty list of integers, got []")
        for key, minimum in (("budget", 0), ("eval_episodes", 1), ("learn_eval_every", 0), ("learn_eval_episodes", 1)):
            if getattr(self, key) < minimum:
                raise ValueError(f"{where}.{key}: expected an integer >= {minimum}, got {getattr(self, key)!r}")
        for seed in self.seeds:
            if seed < 0:
                raise ValueError(f"{where}.seeds: expected integers >= 0, got {seed!r}")
        for scenario, value in self.budget_overrides.items():
            if value < 0:
                raise ValueError(f"{where}.budget_overrides.{scenario}: expected an integer >= 0, got {value!r}")
        if self.rollout_cap is not None and self.rollout_cap < 1:
            raise ValueError(f"{where}.rollout_cap: expected an integer >= 1 or null, got {self.rollout_cap!r}")

    def budget_for(self, scenario: str) -> int:
        return int(self.budget_overrides.get(scenario, self.budget))


class PresetError(ValueError):
    """An unknown or invalid preset file; one line naming the file and the fix."""


def preset_names() -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / "preset").glob("*.yaml"))


def load_preset(name: str) -> Preset:
    """``conf/preset/<name>.yaml`` over the :class:`Preset` schema, checked as a sweep checks it:
    for readers that do not compose a sweep (``leaderboard.submit``, the leaderboard's seeds)."""
    path = CONF_DIR / "preset" / f"{name}.yaml"
    if not path.is_file():
        names = preset_names()
        hint = did_you_mean(name, names, n=3, quote=False)
        raise PresetError(f"no {path}{hint}; presets: {', '.join(names)}")
    try:
        values = yaml.safe_load(path.read_text()) or {}
        return typed.build(Preset, typed.merge(Preset, values, where=str(path)), where=str(path))
    except (OSError, yaml.YAMLError, typed.TypedConfigError, ValueError, TypeError) as exc:
        raise PresetError(f"{path}: {' '.join(str(exc).split())}") from exc


@dataclass(frozen=True)
class LocalLauncher:
    """Local CPU worker pool: one run per worker process, one torch thread per worker."""

    name: str = "local"
    workers: int | None = None  # null: the number of cores

    def __post_init__(self) -> None:
        if self.workers is not None and self.workers < 1:
            raise ValueError(f"launcher.workers: expected an integer >= 1 or null, got {self.workers!r}")


@dataclass(frozen=True)
class SlurmLauncher:
    """SLURM job arrays through submitit (one array task per run); the values in
    ``conf/launcher/slurm.yaml`` fit the project's single-node test cluster."""

    name: str = "slurm"
    partition: str = "debug"
    timeout_min: int = 60  # keep >= 5: submitit asks SLURM for a signal before the time limit
    cpus_per_task: int = 1  # must not exceed the CPUs of a node
    mem_gb: int = 2
    array_parallelism: int = 64  # how many array tasks may run at once
    folder: str | None = None  # submitit logs; null = <results_dir>/slurm/<sweep name>
    poll_s: float = 2.0

    def __post_init__(self) -> None:
        for key in ("timeout_min", "cpus_per_task", "mem_gb", "array_parallelism"):
            if getattr(self, key) < 1:
                raise ValueError(f"launcher.{key}: expected an integer >= 1, got {getattr(self, key)!r}")


LAUNCHERS: dict[str, type] = {"local": LocalLauncher, "slurm": SlurmLauncher}


@dataclass(frozen=True)
class ScenarioFile:
    """``conf/scenario/<name>.yaml``: the chains the paper ran on the scenario."""

    chains: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Experiment:
    """A fixed selection of (chain option, Scenario) pairs, e.g. ``experiment=table1``."""

    name: str
    pairs: list[list[str]]


#: The training engines of a sweep (:mod:`runners.jobs`).
ENGINES = ("fleet", "single")


@dataclass(frozen=True)
class Sweep:
    """The top level of ``conf/config.yaml``: the groups and every sweep-wide setting.

    ``variant``: variant names to keep (null: every variant); ``seed``: seeds (null: the preset's);
    ``beta``: the morality metric's resolution (every run of the paper used 0.1); ``max_steps``:
    env truncation on step max_steps + 1, as in the paper; ``results_dir``: Parquet runs, models,
    GIFs, manifests and the MLflow store; ``dry_run``: list the runs without running anything and
    without writing anything (no manifest; the results directory is not even created);
    ``plan_file``: where a dry run writes its plan as JSON, in the sweep manifest's format (null: nowhere),
    for scripts and tests that want the planned runs as data;
    ``retry_failed``: run again runs recorded as failed; ``mlflow``: mirror runs into MLflow;
    ``gif``: a GIF of one evaluation episode per run; ``progress_every_s``: when stderr is not a
    terminal (``nohup``, a SLURM batch log, CI), where the live bars draw nothing, a plain progress
    line at most this often (0: none); ``name``: the manifest's sweep name (null:
    derived from the selection); ``engine``: ``fleet`` trains the runs that differ only in variant,
    chain and seed together, up to ``fleet_size`` per fleet (the gain saturates by about 12,
    BENCHMARKS.md), ``single`` trains one run per process (:mod:`runners.jobs`); ``device``: where
    a fleet's networks and updates run (``cpu``, or ``cuda`` when torch sees a GPU; single runs and
    every run's evaluation stay on the CPU); ``checkpoint_every_s``: a fleet writes its training
    state to ``<results_dir>/checkpoints/`` at most every so many seconds (and when its training
    ends), and a sweep resumed after a kill continues the fleet from there, bit for bit, instead of
    training it again (0: no checkpoints). Like the other sweep-wide settings it is no part of any
    run's configuration or id.
    """

    scenario: Mapping[str, ScenarioFile] = field(default_factory=dict)
    chain: Mapping[str, Any] = field(default_factory=dict)
    algo: Mapping[str, AlgoFile] = field(default_factory=dict)  # type: ignore[valid-type]
    protocol: ProtocolSpec | None = None
    preset: Preset | None = None
    launcher: Any = None
    experiment: Experiment | None = None
    variant: Any = None
    seed: Any = None
    beta: float = BETA
    max_steps: int | None = MAX_STEPS
    results_dir: str = "results"
    dry_run: bool = False
    plan_file: str | None = None
    retry_failed: bool = True
    mlflow: bool = True
    gif: bool = True
    progress_every_s: float = 60.0
    name: str | None = None
    engine: str = "fleet"
    fleet_size: int = 36
    device: str = "cpu"
    checkpoint_every_s: float = 300.0


@dataclass(frozen=True)
class RunConfig:
    """One run, fully resolved where the sweep's configuration is validated, and never changed after.

    ``algo`` is the learner's spec with everything applied (its algo file, the protocol, the
    preset's overrides and rollout cap, the command line: :func:`runners.config.learner_layers`);
    ``protocol`` is recorded whole because it is part of what the run is (and gives the random
    learner its own settings, :attr:`replay`); ``chain`` is the chain's full definition
    (``{"name", "norms": [[norm, modality], ...]}``), so that a changed chain is a new run.

    The object itself is what a worker receives (pickled as it is); its JSON form
    (:meth:`to_json`) is what its id hashes (:attr:`run_id`) and its Parquet row records, and
    :meth:`from_json` reads such a record back (a fleet's run list). Reading it by key
    (``run["algo"]["name"]``) reads that JSON form, as a recorded config reads.
    """

    env_id: str
    scenario: str
    variant: str
    chain: Mapping[str, Any]
    algo: LearnerSpec
    protocol: ProtocolSpec
    preset: str
    seed: int
    budget: int
    beta: float
    max_steps: int | None
    eval_episodes: int
    learn_eval_every: int
    learn_eval_episodes: int
    schema_version: int = SCHEMA_VERSION

    def to_json(self) -> dict[str, Any]:
        """The run config as plain data (JSON-ready): the dict the run id hashes and the Parquet
        row records. Tuples become lists, specs their field dicts (a fresh copy each call)."""
        return {f.name: plain(getattr(self, f.name)) for f in dataclasses.fields(self)}

    @functools.cached_property
    def _json(self) -> dict[str, Any]:
        return self.to_json()

    @functools.cached_property
    def run_id(self) -> str:
        """The run's content id (:func:`runners.identity.run_id_of` over :meth:`to_json`)."""
        return run_id_of(self._json)

    @property
    def config_key(self) -> str:
        """The id of the run's configuration within its Table 1 cell (:func:`runners.identity.config_key`)."""
        return config_key(self._json)

    def __getitem__(self, key: str) -> Any:
        return self._json[key]

    @property
    def replay(self) -> RandomReplay:
        """The random learner's own settings under the run's protocol (unused by every other learner)."""
        return self.protocol.random_replay()

    def bound_chain(self) -> BoundChain:
        """The run's chain bound to its env id."""
        chain = parse_chain({"name": self.chain["name"], "norms": [{"norm": n, "modality": m} for n, m in self.chain["norms"]]},
                            source=f"run config {self.chain['name']}")
        return bind_chain(chain, self.env_id, self.beta)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> RunConfig:
        """A recorded run config read back; it must give back exactly what was recorded (its id)."""
        run = typed.from_plain(cls, data)
        if run.to_json() != dict(data):
            raise ValueError(f"a recorded run config does not read back as written (schema {data.get('schema_version')!r})")
        return run


def plain(value: Any) -> Any:
    """``value`` as JSON-ready data: a dataclass as the dict of its fields, tuples as lists."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value


#: The schema of a class by the name OmegaConf gives it in its messages (for the valid keys).
SCHEMAS: dict[str, type] = {cls.__name__: cls for cls in (AlgoFile, Planning, PlanningOverride, Preset, LocalLauncher,
                                                          SlurmLauncher, ScenarioFile, Experiment, Sweep, ProtocolSpec,
                                                          LearnerSpec)}


def register() -> None:
    """Store the schemas in Hydra's ConfigStore (idempotent): ``sweep_schema`` for the primary
    config, ``schema/launcher/<name>`` for the launcher files."""
    # Hydra waits: importing runners.config_schema must not load it
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    store.store(name="sweep_schema", node=typed.schema(Sweep), provider="morality_gym")
    for name, cls in LAUNCHERS.items():
        store.store(group="schema/launcher", name=name, node=typed.schema(cls), provider="morality_gym")


def composition_error(exc: BaseException, find: Callable[[str, str], Path | None] | None = None) -> str:
    """One line for an error Hydra raised while composing the sweep: the key, the file or command-line
    override it came from, what is wrong and, for an unknown key, the closest valid key.

    ``find(group, option)`` gives an option's file on the search path (``runners.paths.find_config``).
    """
    text = str(exc)
    where = ""
    found = re.match(r"In '([^']+)'", text)
    if found:  # from a config file: name the file
        group, _, option = found.group(1).rpartition("/")
        path = find(group, option) if group and find is not None else None
        where = f"{group}={option}, {path}" if path else found.group(1)
    else:
        if re.match(r"(?:Could not override|Error merging override)", text):
            where = "command line"
    line = typed.explain(exc, where, SCHEMAS)
    package = re.match(r"^(algo|chain|scenario)\.([^.\s]+)[ :]", line)
    if package and "unknown key" not in line:  # a value where a whole file's mapping belongs
        group = package.group(1)
        return (f"{group}: a selected {group} file is missing its '# @package {group}.<file name>' first line "
                f"(its key {package.group(2)!r} landed at the top of the {group} group); add the line")
    return line
