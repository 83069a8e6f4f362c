"""The sweep's typed configuration: frozen dataclasses, registered as Hydra structured configs.

Hydra composes ``conf/`` over these schemas, so a misspelt key or a value of the wrong type fails
while the configuration is composed (:func:`runners.compose.command_line.compose_check` turns Hydra's message
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
learner's class, chain coverage) is checked by :mod:`runners.compose.sweep_config` after composition.
"""

from __future__ import annotations

import dataclasses
import re
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from morality_gym.baselines import typed
from morality_gym.baselines.specs import DEFAULT_UPDATE_ENGINE, LearnerSpec, ProtocolSpec
from morality_gym.constants import BETA, MAX_STEPS
from morality_gym.results.presets import Preset
from runners.plan.estimate import DeviceRate, Planning, PlanningOverride

#: The largest fleet a sweep forms when ``fleet_size`` is not given, by kind of device. On the CPU
#: the fleet's gain saturates by about 12 runs (BENCHMARKS.md), and 36 leaves room for a row's
#: variants and seeds; on a GPU a fleet's rate grows with its size (one process is bound by launching
#: kernels), and 336 is the largest size measured (docs/engines.md: the plan of the paper Table 1
#: with eight processes, 1h30m at 36, 39m at 336).
FLEET_SIZES: dict[str, int] = {"cpu": 36, "cuda": 336}


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


#: The training engines of a sweep (:mod:`runners.execute.jobs`).
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
    chain and seed together, up to ``fleet_size`` per fleet (null: :data:`FLEET_SIZES` for the
    device), ``single`` trains one run per process (:mod:`runners.execute.jobs`); ``device``: where
    a fleet's networks and updates run (``cpu``, or ``cuda`` when torch sees a GPU; single runs and
    every run's evaluation stay on the CPU); ``fleet_update``: how a fleet's minibatch updates run,
    ``eager`` (one PyTorch operation at a time, as every release was trained: reruns a release bit
    for bit) or ``compiled`` (``torch.compile``; other float order, so a release's runs are not
    rerun bit for bit; docs/engines.md), the default :data:`morality_gym.baselines.specs.DEFAULT_UPDATE_ENGINE`;
    ``checkpoint_every_s``: a fleet writes its training
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
    fleet_size: int | None = None
    device: str = "cpu"
    fleet_update: str = DEFAULT_UPDATE_ENGINE
    checkpoint_every_s: float = 300.0


#: The schema of a class by the name OmegaConf gives it in its messages (for the valid keys).
SCHEMAS: dict[str, type] = {cls.__name__: cls for cls in (AlgoFile, Planning, PlanningOverride, DeviceRate, Preset, LocalLauncher,
                                                          SlurmLauncher, ScenarioFile, Experiment, Sweep, ProtocolSpec,
                                                          LearnerSpec)}


def register() -> None:
    """Store the schemas in Hydra's ConfigStore (idempotent): ``sweep_schema`` for the primary
    config, ``schema/launcher/<name>`` for the launcher files."""
    # Hydra waits: importing runners.compose.schema must not load it
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    store.store(name="sweep_schema", node=typed.schema(Sweep), provider="morality_gym")
    for name, cls in LAUNCHERS.items():
        store.store(group="schema/launcher", name=name, node=typed.schema(cls), provider="morality_gym")


def composition_error(exc: BaseException, find: Callable[[str, str], Path | None] | None = None) -> str:
    """One line for an error Hydra raised while composing the sweep: the key, the file or command-line
    override it came from, what is wrong and, for an unknown key, the closest valid key.

    ``find(group, option)`` gives an option's file on the search path (``runners.compose.search_path.find_config``).
    """
    text = str(exc)
    lexer = re.search(r"LexerNoViableAltException: ([^=\s]+)=(.*?)\s+\^", text, re.DOTALL)
    if lexer:  # Hydra's grammar takes ASCII identifiers and a few symbols unquoted: say how to quote
        key, value = lexer.group(1), lexer.group(2)
        return (f"{key}: the value {value!r} has characters the command line cannot take unquoted (non-ASCII "
                f"letters, spaces, some symbols); quote it for Hydra inside shell quotes: \"{key}='{value}'\"")
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
