"""Resolve a composed sweep configuration into a :class:`SweepConfig`, before anything runs.

Hydra composes ``conf/`` over the typed schemas of :mod:`runners.config_schema`, so unknown keys and
wrong types have already failed at composition. What is left here is what a type cannot say:
ranges (in the schemas' ``__post_init__``), one setting against another (a variant of the
selected scenarios, a budget that trains nothing, a protocol or preset naming an algo that does
not exist), hyper-parameters against the learner's class, chain coverage, a writable results
directory. Each raises :class:`ConfigError` naming the key, where it came from and the valid
choices. Nothing is written and no run starts unless the whole sweep is valid.
"""

from __future__ import annotations

import dataclasses
import difflib
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from omegaconf import DictConfig, ListConfig, OmegaConf

from morality_gym.baselines import typed
from morality_gym.baselines.hparams import validate_learner
from morality_gym.baselines.specs import ALGO_FILE_EXTRAS, LearnerSpec, ProtocolSpec, SpecError
from morality_gym.baselines.targets import learner_trains
from morality_gym.envs.registry import scenarios as all_scenarios
from morality_gym.norms.chain import ChainError, MoralityChain, check_name_collision, get_chain, parse_chain
from runners.paths import CONF_DIR, find_config, group_options  # noqa: F401 - re-exported: CONF_DIR is defined once
from runners.config_schema import ENGINES, LAUNCHERS, AlgoFile, Planning, Preset, register

register()  # the schemas conf/config.yaml names (sweep_schema, schema/launcher/*): Hydra needs them stored


class ConfigError(ValueError):
    """An invalid sweep setting; the message says which key, where, and what is valid."""


def _hint(word: str, choices: list[str]) -> str:
    close = difflib.get_close_matches(str(word), choices, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


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
    spec: LearnerSpec
    steps_per_s: float  # planning estimate per worker
    overhead_s: float
    fleet_speedup: float = 1.0  # measured speed-up of the fleet engine at K >= 12 (planning only)


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
    engine: str  # fleet | single (runners/jobs.py; default: runners.config_schema.Sweep)
    fleet_size: int  # most runs trained together in one fleet
    device: str = "cpu"  # where fleets train (runners.config_schema.Sweep)
    chain_files: Mapping[str, str] = field(default_factory=dict)  # chain name -> config option name
    warnings: tuple[str, ...] = ()  # shown with the plan: valid, but probably not what the user meant


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
    from runners.paths import config_roots

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


def _diff(composed: Mapping[str, Any], base: Mapping[str, Any]) -> dict[str, Any]:
    """What the command line changed relative to the file (nested for ``hparams``)."""
    out: dict[str, Any] = {}
    for key, value in composed.items():
        if key == "hparams" and isinstance(value, Mapping):
            inner = {k: v for k, v in value.items() if (base.get("hparams") or {}).get(k, object()) != v}
            if inner:
                out["hparams"] = inner
        elif base.get(key, object()) != value:
            out[key] = value
    return out


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
    import inspect

    from morality_gym.baselines.hparams import algorithm_class

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
    from morality_gym.baselines.specs import training_steps

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


def _algo(option: str, node: Mapping[str, Any], preset: Preset, protocol: ProtocolSpec) -> AlgoChoice:
    """file values < the protocol's overrides for this algorithm < the preset's overrides for it <
    the preset's rollout cap < command-line overrides. Any class works (``_target_``); nothing here
    knows the baselines."""
    path, file_node = load_algo_file(option)
    where = f"algo={option} ({path})"
    file_values = {k: v for k, v in file_node.items() if k not in ALGO_FILE_EXTRAS}
    # What the command line changed: the composed node against the file over the same schema.
    try:
        file_typed = OmegaConf.to_container(typed.merge(AlgoFile, file_values, where=where))
    except typed.TypedConfigError as exc:
        raise ConfigError(str(exc)) from exc
    composed = {k: v for k, v in node.items() if k not in ALGO_FILE_EXTRAS}
    planning = dict(node.get("planning") or {})
    name = composed.get("name") or option
    try:
        base = LearnerSpec.from_mapping(file_values, name, where=where)
        spec = protocol.apply(base)
        override = preset.algo_overrides.get(option)
        if override:
            spec = spec.with_overrides(override, where=f"preset={preset.name}.algo_overrides.{option}")
        if preset.rollout_cap is not None:
            spec = _cap_rollout(spec, preset.rollout_cap, where=f"preset={preset.name}.rollout_cap")
        delta = {k: v for k, v in _diff(composed, file_typed).items() if not (k in ("name", "label") and v is None)}
        if delta:
            spec = spec.with_overrides(delta, where=where)
    except SpecError as exc:
        raise ConfigError(f"{where}: {exc}" if where not in str(exc) else str(exc)) from exc
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    _check_hparam_types(where, spec, base)
    try:
        validate_learner(spec)  # keys against the algorithm class, values against sane ranges
    except SpecError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    steps_per_s, overhead, speedup = _planning_rate(where, planning, file_values, spec, protocol.name)
    return AlgoChoice(spec, steps_per_s, overhead, speedup)


_PLANNING_KEYS = set(typed.valid_keys(Planning)) - {"protocols"}


def _planning_rate(where: str, planning: Mapping[str, Any], file_values: Mapping[str, Any],
                   spec: LearnerSpec, protocol: str | None = None) -> tuple[float, float, float]:
    """Training steps per second, fixed seconds per run and the fleet speed-up, for the plan's estimate.

    ``planning.steps_per_s`` is measured with the algorithm file's own settings. Only part of a
    training step's time is gradient work (``update_share``); that part scales with the number of
    update epochs per rollout, the rest (simulation, rollout bookkeeping) does not. Scaling the
    whole rate by the epoch ratio, as a first version did, made the smoke preset (2 epochs
    instead of 10-40) look 2.7x slower than it ran. ``overhead_s`` covers what every run pays
    regardless of its budget: building the envs, the final and exact evaluations, the GIF, writes.

    ``planning.protocols.<protocol>`` replaces some of these values under one protocol: a protocol
    can change a learner's speed by an order of magnitude (PPO-Lag's early stop ends its update
    after one pass under ``paper`` and after up to 40 under ``corrected``). ``fleet_speedup`` is
    the fleet engine's measured gain at K >= 12 (BENCHMARKS.md), used by :mod:`runners.jobs`.
    """
    planning = dict(planning)
    by_protocol = planning.pop("protocols", None) or {}
    if not isinstance(by_protocol, Mapping):
        raise ConfigError(f"{where}: planning.protocols must map protocol names to planning values, got {by_protocol!r}")
    if protocol is not None and protocol in by_protocol:
        chosen = by_protocol[protocol]
        if not isinstance(chosen, Mapping):
            raise ConfigError(f"{where}: planning.protocols.{protocol} must be a mapping, got {chosen!r}")
        planning.update({k: v for k, v in chosen.items() if v is not None})  # unset: the algo's own value
    unknown = set(planning) - _PLANNING_KEYS
    if unknown:
        raise ConfigError(f"{where}: unknown planning key(s) {sorted(unknown)}; valid: {sorted(_PLANNING_KEYS | {'protocols'})}")
    default = Planning()
    try:
        steps_per_s = float(planning.get("steps_per_s", default.steps_per_s))
        share = float(planning.get("update_share", default.update_share))
        overhead = float(planning.get("overhead_s", default.overhead_s))
        speedup = float(planning.get("fleet_speedup", default.fleet_speedup))
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: planning values must be numbers ({exc})") from exc
    if steps_per_s <= 0 or not 0.0 <= share <= 1.0 or overhead < 0 or speedup < 1.0:
        raise ConfigError(f"{where}: planning needs steps_per_s > 0, 0 <= update_share <= 1, overhead_s >= 0, fleet_speedup >= 1; "
                          f"got {dict(planning)}")
    ratio = 1.0
    for key in ("n_epochs", "n_critic_updates"):
        reference, actual = file_values.get("hparams", {}).get(key), spec.hparams.get(key)
        if reference and actual:
            ratio *= actual / reference
    seconds_per_step = ((1.0 - share) + share * ratio) / steps_per_s
    return 1.0 / seconds_per_step, overhead, speedup


def _preset(node: Any) -> Preset:
    """The typed preset; ranges and scenario names (what the schema's types cannot say) checked."""
    preset = _typed(Preset, node, where=f"preset={(node or {}).get('name', '?')}")
    known = all_scenarios()
    for scenario in preset.budget_overrides:
        if scenario not in known:
            raise ConfigError(f"preset={preset.name}.budget_overrides: unknown scenario {scenario!r}{_hint(scenario, list(known))}")
    return preset


def _results_dir(value: Any) -> Path:
    """The results directory, created if needed and proven writable by writing a probe file."""
    import tempfile

    if not isinstance(value, str) or not value:
        raise ConfigError(f"results_dir: expected a path, got {value!r}")
    path = Path(value).expanduser()
    if not path.is_absolute():
        path = Path(os.environ.get("MORALITY_GYM_ORIGINAL_CWD", os.getcwd())) / path
    if path.exists() and not path.is_dir():
        raise ConfigError(f"results_dir={value}: exists and is not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-probe-"):
            pass
    except OSError as exc:
        raise ConfigError(f"results_dir={value}: not a writable directory ({exc.strerror or exc})") from exc
    return path


def validate(cfg: DictConfig) -> SweepConfig:
    """Check the composed config and resolve it into a :class:`SweepConfig`."""
    if "hydra" in cfg:  # composed with the compose API and return_hydra_config=True: its search path counts
        from hydra.core.hydra_config import HydraConfig

        HydraConfig.instance().set_config(cfg)
        cfg = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"])
    known = all_scenarios()
    preset = _preset(_group(cfg, "preset"))
    algo_options = group_options("algo")
    for algo_name in preset.algo_overrides:
        if algo_name not in algo_options:
            raise ConfigError(f"preset={preset.name}.algo_overrides: unknown algo {algo_name!r}{_hint(algo_name, algo_options)}")

    chains_sel = _group(cfg, "chain")
    if not chains_sel:
        raise ConfigError("chain: select at least one chain, e.g. chain=utility")
    chains: dict[str, MoralityChain] = {}
    for option, node in chains_sel.items():
        if isinstance(node, Mapping) and ("ref" in node or "norms" in node) and option in ("ref", "norms", "name"):
            raise ConfigError("chain: a chain file is missing its '# @package chain.<file name>' first line")
        chains[option] = _load_chain(option, node)
    _check_distinct_chains(chains)

    algos_sel = _group(cfg, "algo")
    if not algos_sel:
        raise ConfigError("algo: select at least one algorithm, e.g. algo=ppo")
    for option, node in algos_sel.items():
        if not isinstance(node, Mapping) or option not in algo_options:
            raise ConfigError(f"algo: a selected algo file is missing its '# @package algo.<file name>' first line "
                              f"(its key {option!r} landed at the top of the algo group); add the line")
    protocol_node = _group(cfg, "protocol")
    try:
        protocol = ProtocolSpec.from_mapping(protocol_node, where=f"protocol={protocol_node.get('name', '?')}")
    except SpecError as exc:
        raise ConfigError(f"protocol: {exc}") from exc
    for algo_name in protocol.learner_overrides:
        if algo_name not in algo_options:
            raise ConfigError(f"protocol={protocol.name}.learner_overrides: unknown algo {algo_name!r}"
                              f"{_hint(str(algo_name), algo_options)}; keys are algo names, valid: {', '.join(algo_options)}")
    algos = tuple(_algo(option, node, preset, protocol) for option, node in algos_sel.items())

    paper_chains = _scenario_chains()
    scen_sel = _group(cfg, "scenario")
    for name in scen_sel:
        if name not in known:
            raise ConfigError(f"scenario: unknown scenario {name!r}{_hint(name, list(known))}; valid: {', '.join(known)}")

    experiment = _group(cfg, "experiment")
    pairs: list[tuple[MoralityChain, str]] = []
    if experiment:
        raw_pairs = experiment.get("pairs")
        if not isinstance(raw_pairs, list) or not raw_pairs:
            raise ConfigError(f"experiment={experiment.get('name')}: 'pairs' must be a list of [chain, Scenario]")
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
    else:
        for option, chain in chains.items():
            if scen_sel:
                targets = list(scen_sel)
            else:
                targets = [s for s, cs in paper_chains.items() if option in cs]
                if not targets:
                    raise ConfigError(
                        f"chain={option}: no scenario of the paper uses this chain; choose scenarios, e.g. 'scenario=[push_or_switch]'"
                    )
            pairs.extend((chain, s) for s in targets)
    if not pairs:
        raise ConfigError("the selection is empty: no (chain, scenario) pair remains")

    variants = cfg.get("variant")
    if variants is not None:
        variants = _one_or_list(variants)
        if not variants or not all(isinstance(v, (str, int)) and not isinstance(v, bool) for v in variants):
            raise ConfigError(f"variant: expected a variant name or a list of them, e.g. 'variant=[HumanA]', got {variants!r}")
        variants = [str(v) for v in variants]  # variant=1 is parsed as a number; the check below names the valid ones
        for v in variants:
            if not any(v in known[s].variants for _, s in pairs):
                valid = sorted({vv for _, s in pairs for vv in known[s].variants})
                raise ConfigError(f"variant: {v!r} is not a variant of the selected scenarios{_hint(v, valid)}; valid: {', '.join(valid)}")

    # Coverage: every env the sweep will run must be scorable by its chain; the variant filter
    # applies first, so a chain that only fits some variants can be swept on those.
    from morality_gym.norms.metric import bind_chain

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
    seeds = cfg.get("seed")
    if seeds is None:
        seed_list = preset.seeds
    else:
        raw = _one_or_list(seeds)
        if not raw:
            raise ConfigError(f"seed: expected an integer >= 0 or a list of them, e.g. 'seed=[41,42]', got {seeds!r}")
        seed_list = tuple(_int("seed", s) for s in raw)

    beta = cfg.get("beta")
    if isinstance(beta, bool) or not isinstance(beta, (int, float)) or not 0 < beta <= 1:
        raise ConfigError(f"beta: expected a number in (0, 1], got {beta!r}")
    max_steps = cfg.get("max_steps")
    if max_steps is not None:
        max_steps = _int("max_steps", max_steps, 1)
    for algo in algos:
        for _, scenario in pairs:
            if learner_trains(algo.spec.target) and preset.budget_for(scenario) <= 0:
                raise ConfigError(f"preset={preset.name}.budget: a budget of 0 steps trains nothing ({algo.spec.name} on {scenario})")

    warnings = tuple(w for algo in algos if (w := _rollout_warning(algo.spec, preset, pairs)))

    launcher_node = _group(cfg, "launcher")
    kind = launcher_node.get("name")
    if kind not in LAUNCHERS:
        raise ConfigError(f"launcher: unknown launcher {kind!r}{_hint(str(kind), list(LAUNCHERS))}; valid: {', '.join(LAUNCHERS)}")
    launcher = dataclasses.asdict(_typed(LAUNCHERS[kind], launcher_node, where=f"launcher={kind}"))

    engine = cfg.get("engine")
    if engine not in ENGINES:
        raise ConfigError(f"engine: expected fleet or single, got {engine!r}{_hint(str(engine), list(ENGINES))}")
    fleet_size = _int("fleet_size", cfg.get("fleet_size"), 1)
    device = str(cfg.get("device"))
    if device != "cpu":
        if engine != "fleet":
            raise ConfigError(f"device={device}: only the fleet engine trains off the CPU; use engine=fleet or device=cpu")
        from morality_gym.baselines.fleet.base import fleet_device

        try:
            fleet_device(device)
        except SpecError as exc:
            raise ConfigError(str(exc)) from exc
    if cfg.get("mlflow") and not cfg.get("dry_run"):
        from runners.tracking import TrackingError, check_reachable

        try:
            check_reachable(_results_dir(cfg.get("results_dir")))
        except TrackingError as exc:
            raise ConfigError(str(exc)) from exc
    if kind == "slurm" and not cfg.get("dry_run"):
        from runners.slurm_controller import SlurmUnavailable, check_controller

        try:
            check_controller()
        except SlurmUnavailable as exc:
            raise ConfigError(str(exc)) from exc
    name = cfg.get("name") or (
        (experiment.get("name") if experiment else "-".join(a.spec.name for a in algos) + "_" + "-".join(chains))
        + f"_{protocol.name}_{preset.name}"
    )
    return SweepConfig(
        pairs=tuple(pairs),
        variants=tuple(variants) if variants is not None else None,
        seeds=tuple(seed_list),
        algos=algos,
        protocol=protocol,
        preset=preset,
        launcher=launcher,
        beta=float(beta),
        max_steps=max_steps,
        results_dir=_results_dir(cfg.get("results_dir")),
        dry_run=cfg.get("dry_run"),
        retry_failed=cfg.get("retry_failed"),
        mlflow=cfg.get("mlflow"),
        gif=cfg.get("gif"),
        name=str(name),
        chain_files={chain.name: option for option, chain in chains.items()},
        engine=str(engine),
        fleet_size=fleet_size,
        device=device,
        warnings=warnings,
    )
