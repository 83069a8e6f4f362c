"""Resolve a composed sweep configuration into a :class:`SweepConfig`, before anything runs.

Hydra composes ``conf/`` over the typed schemas of :mod:`runners.compose.schema`, so unknown keys and
wrong types have already failed at composition. What is left here is what a type cannot say:
ranges (in the schemas' ``__post_init__``), one setting against another (a variant of the
selected scenarios, a budget that trains nothing, a protocol or preset naming an algo that does
not exist), hyper-parameters against the learner's class, chain coverage. :func:`validate` runs one
small builder or check per config group; each raises :class:`ConfigError` naming the key, where it
came from and the valid choices. Nothing here looks beyond the configuration: whether the results
directory can be written and MLflow or SLURM answer is :mod:`runners.launch.preflight`'s question, asked
by the sweep once the configuration is valid. Nothing is written and no run starts unless the
whole sweep is valid.
"""

from __future__ import annotations

import dataclasses
import inspect
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import DictConfig, ListConfig, OmegaConf

from morality_gym.baselines import typed
from morality_gym.baselines.device import CPU, Device
from morality_gym.baselines.hparams import algorithm_class, validate_learner
from morality_gym.baselines.specs import (
    ALGO_FILE_EXTRAS,
    DEFAULT_UPDATE_ENGINE,
    UPDATE_ENGINES,
    LearnerSpec,
    ProtocolSpec,
    SpecError,
    check_keys,
    training_steps,
)
from morality_gym.baselines.targets import learner_trains
from morality_gym.clitools import did_you_mean
from morality_gym.constants import MAX_STEPS
from morality_gym.envs.registry import scenarios as all_scenarios
from morality_gym.evaluation.horizon import truncation_problem
from morality_gym.norms.chain import ChainError, MoralityChain, check_name_collision, get_chain, parse_chain
from morality_gym.norms.metric import bind_chain
from runners.compose.schema import ENGINES, FLEET_SIZES, LAUNCHERS, Preset, Sweep, register
from runners.compose.search_path import config_roots, find_config, group_options
from runners.plan.estimate import LearnerRates, PlanningError, learner_rates, planning_where

register()  # the schemas conf/config.yaml names (sweep_schema, schema/launcher/*): Hydra needs them stored


class ConfigError(ValueError):
    """An invalid sweep setting; the message says which key, where, and what is valid."""


def _hint(word: str, choices: list[str]) -> str:
    return did_you_mean(word, choices)


def _int(where: str, value: Any, minimum: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"{where}: expected an integer >= {minimum}, got {value!r}")
    return value


def _one_or_list(value: Any) -> list[Any]:
    """A setting typed ``Any`` in the schema (``seed``, ``variant``: one value or a list) as a list.

    The command line gives a scalar of whatever type Hydra parsed (``seed=abc`` a string,
    ``seed=1.5`` a float, ``variant=1`` an int): each element is checked by the caller, so a wrong
    type is a configuration error naming the key, never a crash in the conversion.
    """
    if isinstance(value, (ListConfig, list, tuple)):
        return list(OmegaConf.to_container(value) if isinstance(value, ListConfig) else value)
    if isinstance(value, DictConfig):
        return [OmegaConf.to_container(value)]
    return [value]


@dataclass(frozen=True)
class AlgoChoice:
    """A selected learner: its resolved spec, and its planning rates for the plan's estimate
    (:mod:`runners.plan.estimate`; never part of a run's identity)."""

    spec: LearnerSpec
    rates: LearnerRates


@dataclass(frozen=True)
class SweepConfig:
    """A validated sweep: what to run and how."""

    pairs: tuple[tuple[MoralityChain, str], ...]  # (chain, scenario)
    variants: tuple[str, ...] | None
    seeds: tuple[int, ...]
    algos: tuple[AlgoChoice, ...]
    protocol: ProtocolSpec
    preset: Preset
    launcher: Mapping[str, Any]
    beta: float
    max_steps: int | None
    results_dir: Path
    dry_run: bool
    retry_failed: bool
    mlflow: bool
    gif: bool
    name: str
    engine: str  # fleet | single (runners/plan/fleets.py; default: runners.compose.schema.Sweep)
    fleet_size: int  # most runs trained together in one fleet
    device: Device = CPU  # where fleets train, resolved once (morality_gym.baselines.device)
    fleet_update: str = Sweep.fleet_update  # a fleet's update engine: eager (reruns the releases) | compiled
    progress_every_s: float = Sweep.progress_every_s  # plain progress lines when stderr is not a terminal
    checkpoint_every_s: float = Sweep.checkpoint_every_s  # how often a fleet checkpoints its training; 0: never
    chain_files: Mapping[str, str] = field(default_factory=dict)  # chain name -> config option name
    warnings: tuple[str, ...] = ()  # shown with the plan: valid, but probably not what the user meant
    results_dir_setting: str = ""  # results_dir as written in the configuration, for messages about it
    plan_file: Path | None = None  # where a dry run writes its plan (runners.compose.schema.Sweep)


def _load_chain(option: str, node: Any) -> MoralityChain:
    where = f"chain={option} (conf/chain/{option}.yaml)"
    if not isinstance(node, Mapping):
        raise ConfigError(f"{where}: expected a mapping with 'ref' or a chain (name + norms)")
    if "ref" in node:
        if set(node) != {"ref"}:
            raise ConfigError(f"{where}: 'ref' must be the only key, got {sorted(node)}")
        try:
            return get_chain(str(node["ref"]))
        except ChainError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
    try:
        chain = parse_chain(dict(node), source=where)
        check_name_collision(chain)
        return chain
    except ChainError as exc:
        raise ConfigError(str(exc)) from exc


def _check_distinct_chains(chains: Mapping[str, MoralityChain]) -> None:
    """Two selected chains with one name must be one chain (results are labelled by the name)."""
    seen: dict[str, tuple[str, MoralityChain]] = {}
    for option, chain in chains.items():
        other = seen.get(chain.name)
        if other is not None and other[1].content != chain.content:
            raise ConfigError(f"chain={other[0]} and chain={option} are both named {chain.name!r} but have different norms; "
                              "give one of them another name")
        seen.setdefault(chain.name, (option, chain))


def _group(cfg: DictConfig, key: str) -> dict[str, Any]:
    node = cfg.get(key)
    if node is None:
        return {}
    data = OmegaConf.to_container(node, resolve=True)
    if not isinstance(data, dict):
        raise ConfigError(f"{key}: expected config-group selections, got {data!r}")
    return data


def _scenario_chains() -> dict[str, list[str]]:
    """Each scenario's chains (a sweep for a chain covers the scenarios that list it), from every
    scenario file on the search path (selected or not; a user's file replaces conf/'s of the same name)."""
    out: dict[str, list[str]] = {}
    files = {}
    for root in reversed(config_roots()):
        files.update({p.name: p for p in (root / "scenario").glob("*.yaml")})
    for path in sorted(files.values()):
        text = path.read_text()
        first = text.splitlines()[0] if text else ""
        if not first.startswith("# @package scenario."):
            raise ConfigError(f"{path}: must start with '# @package scenario.<ScenarioName>'")
        name = first.split("scenario.", 1)[1].strip()
        out[name] = list((yaml.safe_load(text) or {}).get("chains", []))
    return out


def load_algo_file(name: str) -> tuple[Path, dict[str, Any]]:
    """An algorithm's config file (found on the sweep's search path) and its values."""
    path = find_config("algo", name)
    if path is None:
        valid = group_options("algo")
        raise ConfigError(f"algo={name}: no algo/{name}.yaml on the config search path{_hint(name, valid)}; "
                          f"valid: {', '.join(valid)}")
    return path, yaml.safe_load(path.read_text()) or {}


def _check_hparam_types(where: str, spec: LearnerSpec, defaults: LearnerSpec) -> None:
    for key, value in spec.hparams.items():
        default = defaults.hparams.get(key)
        if isinstance(default, bool):
            ok = isinstance(value, bool)
        elif isinstance(default, int):
            ok = isinstance(value, int) and not isinstance(value, bool)
        elif isinstance(default, float):
            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        else:
            ok = True
        if not ok:
            raise ConfigError(f"{where}: hparams.{key}={value!r} has the wrong type (expected {type(default).__name__}, like {default!r})")


def _typed(cls: type, node: Any, where: str) -> Any:
    """The frozen ``cls`` from a (composed) node; a value its ``__post_init__`` refuses is a ConfigError."""
    try:
        return typed.build(cls, typed.merge(cls, node, where=where), where=where)
    except (typed.TypedConfigError, SpecError, ValueError) as exc:
        raise ConfigError(str(exc)) from exc


def _n_steps(spec: LearnerSpec) -> int | None:
    """The learner's steps per env per rollout: its ``hparams.n_steps``, else its class's default
    (None for a class that takes no ``n_steps``, e.g. an off-policy one or the random baseline)."""
    if "n_steps" in spec.hparams:
        return int(spec.hparams["n_steps"])
    try:
        parameter = inspect.signature(algorithm_class(spec.target)).parameters.get("n_steps")
    except (SpecError, ValueError, TypeError):
        return None
    return parameter.default if parameter is not None and isinstance(parameter.default, int) else None


def _cap_rollout(spec: LearnerSpec, cap: int, where: str) -> LearnerSpec:
    """``spec`` with ``n_steps`` lowered so that one rollout (``n_steps`` x ``n_envs``) is at most ``cap``."""
    n_steps = _n_steps(spec)
    if n_steps is None or n_steps * spec.n_envs <= cap:
        return spec
    try:
        if not learner_trains(spec.target):
            return spec
    except ValueError:
        return spec  # a class that cannot be imported: validate_learner names it, with the fix
    return spec.with_overrides({"hparams": {"n_steps": max(1, cap // spec.n_envs)}}, where=where)


def _rollout_warning(spec: LearnerSpec, preset: Preset, pairs: list[tuple[MoralityChain, str]]) -> str | None:
    """A warning if one rollout of the learner is longer than the smallest budget of the sweep: it
    then trains a whole rollout (SB3's accounting) or nothing at all (``floor``), not the budget."""
    n_steps = _n_steps(spec)
    if n_steps is None or not learner_trains(spec.target) or not pairs:
        return None
    budget = min(preset.budget_for(scenario) for _, scenario in pairs)
    rollout = n_steps * spec.n_envs
    if rollout <= budget:
        return None
    return (f"algo={spec.name}: one rollout is n_steps x n_envs = {n_steps} x {spec.n_envs} = {rollout} steps, more than "
            f"the budget of {budget} steps of preset={preset.name}, so a run trains {training_steps(spec, budget)} steps; "
            f"set preset.rollout_cap={budget} or algo.{spec.name}.hparams.n_steps")


def command_line_settings(overrides: Sequence[str], option: str) -> dict[str, Any]:
    """What the command line sets under ``algo.<option>``, as a nested mapping
    (``algo.ppo.hparams.n_steps=64`` -> ``{"hparams": {"n_steps": 64}}``), read from the overrides
    themselves with Hydra's parser (so the values are typed as Hydra types them). Deletions
    (``~algo...``) set nothing; the plan's ``planning`` is no learner setting."""
    out: dict[str, Any] = {}
    for override in OverridesParser.create().parse_overrides(list(overrides)):
        path = override.key_or_group.split(".")
        if path[:2] != ["algo", option] or override.is_delete() or len(path) < 3 or path[2] in ALGO_FILE_EXTRAS:
            continue
        node = out
        for key in path[2:-1]:
            node = node.setdefault(key, {})
        node[path[-1]] = override.value()
    return out


#: One layer of a learner's settings: where its values come from (for messages) and what it does
#: to the spec of the layers below it (the first layer builds the spec).
Layer = tuple[str, Callable[[Any], LearnerSpec]]


def learner_layers(option: str, where: str, file_values: Mapping[str, Any], command_line: Mapping[str, Any],
                   preset: Preset, protocol: ProtocolSpec) -> list[Layer]:
    """The precedence of a learner's settings, written once, lowest first: :class:`LearnerSpec`'s
    defaults < its algo file < the protocol's overrides for it (and the protocol's stamp) < the
    preset's ``algo_overrides`` for it < the preset's ``rollout_cap`` < the command line
    (``algo.<option>.*=``). Any class works (``_target_``); nothing here knows the baselines."""
    name = command_line.get("name") or file_values.get("name") or option
    preset_override = preset.algo_overrides.get(option)
    cap = preset.rollout_cap
    given = {k: v for k, v in command_line.items() if not (k in ("name", "label") and v is None)}
    at_preset = f"preset={preset.name}.algo_overrides.{option}"
    at_cap = f"preset={preset.name}.rollout_cap"
    return [
        (where, lambda _: LearnerSpec.from_mapping(file_values, name, where=where)),
        (f"protocol={protocol.name}", protocol.apply),
        (at_preset, lambda spec: spec.with_overrides(preset_override, where=at_preset) if preset_override else spec),
        (at_cap, lambda spec: _cap_rollout(spec, cap, where=at_cap) if cap is not None else spec),
        (where, lambda spec: spec.with_overrides(given, where=where) if given else spec),
    ]


def _algo(option: str, node: Mapping[str, Any], preset: Preset, protocol: ProtocolSpec,
          overrides: Sequence[str]) -> AlgoChoice:
    """The learner of ``algo=<option>`` resolved through :func:`learner_layers`, checked against its
    class, with its planning rates."""
    path, file_node = load_algo_file(option)
    where = f"algo={option} ({path})"
    file_values = {k: v for k, v in file_node.items() if k not in ALGO_FILE_EXTRAS}
    layers = learner_layers(option, where, file_values, command_line_settings(overrides, option), preset, protocol)
    try:
        base = layers[0][1](None)
        spec = base
        for _, layer in layers[1:]:
            spec = layer(spec)
    except SpecError as exc:
        raise ConfigError(f"{where}: {exc}" if where not in str(exc) else str(exc)) from exc
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    _check_hparam_types(where, spec, base)
    try:
        validate_learner(spec)  # keys against the algorithm class, values against sane ranges
    except SpecError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    try:
        rates = learner_rates(planning_where(where, option, overrides), dict(node.get("planning") or {}), file_values, spec,
                              protocol.name)
    except PlanningError as exc:
        raise ConfigError(str(exc)) from exc
    return AlgoChoice(spec, rates)


def _preset(node: Any) -> Preset:
    """The typed preset; ranges and scenario names (what the schema's types cannot say) checked."""
    preset = _typed(Preset, node, where=f"preset={(node or {}).get('name', '?')}")
    known = all_scenarios()
    for scenario in preset.budget_overrides:
        if scenario not in known:
            raise ConfigError(f"preset={preset.name}.budget_overrides: unknown scenario {scenario!r}{_hint(scenario, list(known))}")
    return preset


def results_path(value: Any) -> Path:
    """The results directory as an absolute path (relative to where the sweep was started).

    Only the setting is checked here; whether the directory can be written is a question about the
    machine, answered by :func:`runners.launch.preflight.check_results_dir` just before the sweep runs.
    """
    if not isinstance(value, str) or not value:
        raise ConfigError(f"results_dir: expected a path, got {value!r}")
    path = Path(value).expanduser()
    if not path.is_absolute():
        path = Path(os.environ.get("MORALITY_GYM_ORIGINAL_CWD", os.getcwd())) / path
    return path


def _without_hydra(cfg: DictConfig) -> DictConfig:
    """``cfg`` without its ``hydra`` node. A configuration composed with ``return_hydra_config=True``
    (as the sweep composes it) carries its search path there, which
    :func:`runners.compose.search_path.config_roots` must see while the groups are resolved, so it is made current."""
    if "hydra" not in cfg:
        return cfg
    HydraConfig.instance().set_config(cfg)
    return OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"])


def _preset_with_algos(node: Any, algo_options: list[str]) -> Preset:
    """The preset (:func:`_preset`), whose ``algo_overrides`` may only name existing algos."""
    preset = _preset(node)
    for algo_name in preset.algo_overrides:
        if algo_name not in algo_options:
            raise ConfigError(f"preset={preset.name}.algo_overrides: unknown algo {algo_name!r}{_hint(algo_name, algo_options)}")
    return preset


def _chains(selection: Mapping[str, Any]) -> dict[str, MoralityChain]:
    """The selected chains by config option; at least one, and no two different ones of one name."""
    if not selection:
        raise ConfigError("chain: select at least one chain, e.g. chain=utility")
    chains: dict[str, MoralityChain] = {}
    for option, node in selection.items():
        if isinstance(node, Mapping) and ("ref" in node or "norms" in node) and option in ("ref", "norms", "name"):
            raise ConfigError("chain: a chain file is missing its '# @package chain.<file name>' first line")
        chains[option] = _load_chain(option, node)
    _check_distinct_chains(chains)
    return chains


def _algo_selection(selection: Mapping[str, Any], algo_options: list[str]) -> Mapping[str, Any]:
    """The selected algo nodes by option; at least one, each from a file with its package line."""
    if not selection:
        raise ConfigError("algo: select at least one algorithm, e.g. algo=ppo")
    for option, node in selection.items():
        if not isinstance(node, Mapping) or option not in algo_options:
            raise ConfigError(f"algo: a selected algo file is missing its '# @package algo.<file name>' first line "
                              f"(its key {option!r} landed at the top of the algo group); add the line")
    return selection


def _protocol(node: Any, algo_options: list[str]) -> ProtocolSpec:
    """The protocol, built from its composed node (Hydra typed it over :class:`ProtocolSpec`'s
    schema), whose ``learner_overrides`` may only name existing algos."""
    if node is None:
        raise ConfigError("protocol: select a protocol, e.g. protocol=paper")
    where = f"protocol={node.get('name', '?')}"
    try:
        check_keys(where, node, typed.valid_keys(ProtocolSpec))  # a key added with +protocol.<key>=
        protocol = typed.build(ProtocolSpec, node, where=where)
    except (SpecError, typed.TypedConfigError) as exc:
        raise ConfigError(f"protocol: {exc}") from exc
    for algo_name in protocol.learner_overrides:
        if algo_name not in algo_options:
            raise ConfigError(f"protocol={protocol.name}.learner_overrides: unknown algo {algo_name!r}"
                              f"{_hint(str(algo_name), algo_options)}; keys are algo names, valid: {', '.join(algo_options)}")
    return protocol


def _scenario_selection(selection: Mapping[str, Any], known: Mapping[str, Any]) -> Mapping[str, Any]:
    """The scenarios chosen with ``scenario=...`` (empty: each chain's scenarios of the paper)."""
    for name in selection:
        if name not in known:
            raise ConfigError(f"scenario: unknown scenario {name!r}{_hint(name, list(known))}; valid: {', '.join(known)}")
    return selection


def _experiment_pairs(experiment: Mapping[str, Any], chains: Mapping[str, MoralityChain],
                      scen_sel: Mapping[str, Any], known: Mapping[str, Any]) -> list[tuple[MoralityChain, str]]:
    """An experiment's fixed (chain, scenario) pairs, narrowed by ``chain=`` and ``scenario=``."""
    raw_pairs = experiment.get("pairs")
    if not isinstance(raw_pairs, list) or not raw_pairs:
        raise ConfigError(f"experiment={experiment.get('name')}: 'pairs' must be a list of [chain, Scenario]")
    pairs: list[tuple[MoralityChain, str]] = []
    for item in raw_pairs:
        if not isinstance(item, list) or len(item) != 2:
            raise ConfigError(f"experiment.pairs: expected [chain, Scenario], got {item!r}")
        option, scenario = item
        if option not in chains:
            continue  # narrowed away by chain=...
        if scenario not in known:
            raise ConfigError(f"experiment.pairs: unknown scenario {scenario!r}{_hint(scenario, list(known))}")
        if scen_sel and scenario not in scen_sel:
            continue
        pairs.append((chains[option], scenario))
    return pairs


def _chain_pairs(chains: Mapping[str, MoralityChain], scen_sel: Mapping[str, Any],
                 paper_chains: Mapping[str, list[str]]) -> list[tuple[MoralityChain, str]]:
    """Each chain on the chosen scenarios, or on the scenarios of the paper that list it."""
    pairs: list[tuple[MoralityChain, str]] = []
    for option, chain in chains.items():
        targets = list(scen_sel) if scen_sel else [s for s, cs in paper_chains.items() if option in cs]
        if not targets:
            raise ConfigError(
                f"chain={option}: no scenario of the paper uses this chain; choose scenarios, e.g. 'scenario=[push_or_switch]'"
            )
        pairs.extend((chain, s) for s in targets)
    return pairs


def _variants(value: Any, pairs: list[tuple[MoralityChain, str]], known: Mapping[str, Any]) -> list[str] | None:
    """The variants to keep (None: every variant), each a variant of some selected scenario."""
    if value is None:
        return None
    variants = _one_or_list(value)
    if not variants or not all(isinstance(v, (str, int)) and not isinstance(v, bool) for v in variants):
        raise ConfigError(f"variant: expected a variant name or a list of them, e.g. 'variant=[HumanA]', got {variants!r}")
    variants = [str(v) for v in variants]  # variant=1 is parsed as a number; the check below names the valid ones
    for v in variants:
        if not any(v in known[s].variants for _, s in pairs):
            valid = sorted({vv for _, s in pairs for vv in known[s].variants})
            raise ConfigError(f"variant: {v!r} is not a variant of the selected scenarios{_hint(v, valid)}; valid: {', '.join(valid)}")
    return variants


def _check_coverage(pairs: list[tuple[MoralityChain, str]], variants: list[str] | None, known: Mapping[str, Any]) -> None:
    """Every env the sweep will run must be scorable by its chain. The variant filter applies
    first, so a chain that only fits some variants can be swept on those."""
    for chain, scenario in pairs:
        for variant in known[scenario].variants:
            if variants is not None and variant not in variants:
                continue
            env_id = known[scenario].env_id(variant)
            try:
                bind_chain(chain, env_id, 0.1)
            except (ChainError, ValueError) as exc:
                raise ConfigError(f"chain {chain.name} cannot score {env_id}: {exc}; "
                                  "choose the variants it can score with variant=[...]") from exc


def _check_max_steps(pairs: list[tuple[MoralityChain, str]], variants: list[str] | None, known: Mapping[str, Any],
                     beta: float, max_steps: int | None) -> None:
    """A ``max_steps`` too short to score every env of the sweep by its chain is refused before
    anything trains (:func:`morality_gym.evaluation.horizon.truncation_problem`); the default,
    under which the variants' bounds were measured, needs no check."""
    if max_steps == MAX_STEPS:
        return
    for chain, scenario in pairs:
        for variant in known[scenario].variants:
            if variants is not None and variant not in variants:
                continue
            problem = truncation_problem(bind_chain(chain, known[scenario].env_id(variant), beta), max_steps)
            if problem is not None:
                raise ConfigError(problem)


def _seeds(value: Any, preset: Preset) -> tuple[int, ...]:
    """``seed=`` (one or a list), else the preset's seeds."""
    if value is None:
        return tuple(preset.seeds)
    raw = _one_or_list(value)
    if not raw:
        raise ConfigError(f"seed: expected an integer >= 0 or a list of them, e.g. 'seed=[41,42]', got {value!r}")
    return tuple(_int("seed", s) for s in raw)


def _beta(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= 1:
        raise ConfigError(f"beta: expected a number in (0, 1], got {value!r}")
    return float(value)


def _interval_s(key: str, value: Any, zero: str) -> float:
    """A sweep-wide interval in seconds (``progress_every_s``, ``checkpoint_every_s``): a number >= 0,
    where 0 means ``zero`` (said in the error)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
        raise ConfigError(f"{key}: expected a number of seconds >= 0 (0: {zero}), got {value!r}")
    return float(value)


def _check_budgets(algos: tuple[AlgoChoice, ...], pairs: list[tuple[MoralityChain, str]], preset: Preset) -> None:
    """A learner that trains needs a budget above 0 on every scenario it is swept on."""
    for algo in algos:
        for _, scenario in pairs:
            if learner_trains(algo.spec.target) and preset.budget_for(scenario) <= 0:
                raise ConfigError(f"preset={preset.name}.budget: a budget of 0 steps trains nothing ({algo.spec.name} on {scenario})")


def _launcher(node: Mapping[str, Any]) -> dict[str, Any]:
    """The launcher's settings over its own schema (:data:`runners.compose.schema.LAUNCHERS`)."""
    kind = node.get("name")
    if kind not in LAUNCHERS:
        raise ConfigError(f"launcher: unknown launcher {kind!r}{_hint(str(kind), list(LAUNCHERS))}; valid: {', '.join(LAUNCHERS)}")
    return dataclasses.asdict(_typed(LAUNCHERS[kind], node, where=f"launcher={kind}"))


def _engine(cfg: DictConfig) -> tuple[str, int, Device]:
    """The training engine, the largest fleet and the device fleets train on (:class:`Device`,
    resolved here once: checked against what torch sees when the fleets train on this machine)."""
    engine = cfg.get("engine")
    if engine not in ENGINES:
        raise ConfigError(f"engine: expected fleet or single, got {engine!r}{_hint(str(engine), list(ENGINES))}")
    try:
        device = Device.parse(str(cfg.get("device")))
    except SpecError as exc:
        raise ConfigError(str(exc)) from exc
    given = cfg.get("fleet_size")
    fleet_size = _int("fleet_size", FLEET_SIZES.get(device.kind, FLEET_SIZES["cpu"]) if given is None else given, 1)
    if not device.on_cpu and engine != "fleet":
        raise ConfigError(f"device={device}: only the fleet engine trains off the CPU; use engine=fleet or device=cpu")
    # the GPU must be here unless nothing trains here: a dry run plans, SLURM trains on its nodes
    here = not cfg.get("dry_run") and (cfg.get("launcher") or {}).get("name") != "slurm"
    try:
        device = device.checked(here)
    except SpecError as exc:
        raise ConfigError(str(exc)) from exc
    return str(engine), fleet_size, device


def _fleet_update(value: Any, engine: str) -> str:
    """``fleet_update``: one of the fleet's update engines; another than the default only where
    fleets train (with ``engine=single`` it would change nothing, silently)."""
    if value not in UPDATE_ENGINES:
        raise ConfigError(f"fleet_update: expected {' or '.join(UPDATE_ENGINES)}, got {value!r}"
                          f"{_hint(str(value), list(UPDATE_ENGINES))}")
    if engine != "fleet" and value != DEFAULT_UPDATE_ENGINE:
        raise ConfigError(f"fleet_update={value}: only the fleet engine has update engines; use engine=fleet "
                          f"or fleet_update={DEFAULT_UPDATE_ENGINE}")
    return str(value)


def _sweep_name(name: Any, experiment: Mapping[str, Any], algos: tuple[AlgoChoice, ...],
                chains: Mapping[str, MoralityChain], protocol: ProtocolSpec, preset: Preset) -> str:
    """``name=``, else the experiment's name or the algos and chains, then the protocol and preset."""
    if name:
        return str(name)
    selection = experiment.get("name") if experiment else "-".join(a.spec.name for a in algos) + "_" + "-".join(chains)
    return f"{selection}_{protocol.name}_{preset.name}"


def validate(cfg: DictConfig, overrides: Sequence[str] | None = None) -> SweepConfig:
    """Check the composed config and resolve it into a :class:`SweepConfig`, group by group.

    The checks run in a fixed order (the first error is the one reported, so the order is part of
    what a user sees): preset, chains, algos, protocol, scenarios, pairs, variants, coverage, seeds,
    the sweep-wide values, launcher, engine, fleet update. Nothing outside the configuration is touched; the
    machine (a writable results directory, MLflow, SLURM) is checked by
    :func:`runners.launch.preflight.preflight` once the configuration is known to be valid.

    ``overrides``: the command line it was composed with, whose ``algo.<option>.*`` settings are
    the top layer of each learner (:func:`learner_layers`); by default those Hydra recorded in the
    configuration (``hydra.overrides.task``, when it was composed with its ``hydra`` node).
    """
    if overrides is None:
        overrides = list(cfg.hydra.overrides.task) if "hydra" in cfg else []
    cfg = _without_hydra(cfg)
    known = all_scenarios()
    algo_options = group_options("algo")
    preset = _preset_with_algos(_group(cfg, "preset"), algo_options)
    chains = _chains(_group(cfg, "chain"))
    algos_sel = _algo_selection(_group(cfg, "algo"), algo_options)
    protocol = _protocol(cfg.get("protocol"), algo_options)
    algos = tuple(_algo(option, node, preset, protocol, overrides) for option, node in algos_sel.items())
    paper_chains = _scenario_chains()
    scen_sel = _scenario_selection(_group(cfg, "scenario"), known)
    experiment = _group(cfg, "experiment")
    pairs = (_experiment_pairs(experiment, chains, scen_sel, known) if experiment
             else _chain_pairs(chains, scen_sel, paper_chains))
    if not pairs:
        raise ConfigError("the selection is empty: no (chain, scenario) pair remains")
    variants = _variants(cfg.get("variant"), pairs, known)
    _check_coverage(pairs, variants, known)
    seeds = _seeds(cfg.get("seed"), preset)
    beta = _beta(cfg.get("beta"))
    max_steps = cfg.get("max_steps")
    if max_steps is not None:
        max_steps = _int("max_steps", max_steps, 1)
    _check_max_steps(pairs, variants, known, beta, max_steps)
    _check_budgets(algos, pairs, preset)
    warnings = tuple(w for algo in algos if (w := _rollout_warning(algo.spec, preset, pairs)))
    launcher = _launcher(_group(cfg, "launcher"))
    engine, fleet_size, device = _engine(cfg)
    fleet_update = _fleet_update(cfg.get("fleet_update"), engine)
    checkpoint_every_s = _interval_s("checkpoint_every_s", cfg.get("checkpoint_every_s"), "no checkpoints")
    return SweepConfig(
        pairs=tuple(pairs),
        variants=tuple(variants) if variants is not None else None,
        seeds=seeds,
        algos=algos,
        protocol=protocol,
        preset=preset,
        launcher=launcher,
        beta=beta,
        max_steps=max_steps,
        results_dir=results_path(cfg.get("results_dir")),
        results_dir_setting=str(cfg.get("results_dir")),
        dry_run=cfg.get("dry_run"),
        plan_file=Path(cfg.get("plan_file")).expanduser() if cfg.get("plan_file") else None,
        retry_failed=cfg.get("retry_failed"),
        mlflow=cfg.get("mlflow"),
        gif=cfg.get("gif"),
        progress_every_s=_interval_s("progress_every_s", cfg.get("progress_every_s"), "no progress lines"),
        name=_sweep_name(cfg.get("name"), experiment, algos, chains, protocol, preset),
        chain_files={chain.name: option for option, chain in chains.items()},
        engine=engine,
        fleet_size=fleet_size,
        device=device,
        fleet_update=fleet_update,
        checkpoint_every_s=checkpoint_every_s,
        warnings=warnings,
    )
