"""Validate a composed sweep configuration into a :class:`SweepConfig`, before anything runs.

Hydra composes ``conf/``; this module checks every value a user can get wrong (unknown scenario,
variant, chain or algorithm, wrong types, a zero budget, an unwritable results directory, a
malformed user chain) and raises :class:`ConfigError` naming the key, where it came from and the
valid choices. Nothing is written and no run starts unless the whole sweep is valid.
"""

from __future__ import annotations

import difflib
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from omegaconf import DictConfig, OmegaConf

from morality_gym.baselines.hparams import validate_learner
from morality_gym.baselines.specs import LearnerSpec, ProtocolSpec, SpecError, protocol_spec
from morality_gym.baselines.targets import learner_trains
from morality_gym.envs.registry import scenarios as all_scenarios
from morality_gym.norms.chain import ChainError, MoralityChain, check_name_collision, get_chain, parse_chain
from runners.paths import CONF_DIR, find_config, group_options  # re-exported: CONF_DIR is defined once, there

_TOP_KEYS = {
    "scenario", "chain", "algo", "protocol", "preset", "launcher", "experiment", "variant", "seed", "beta",
    "max_steps", "results_dir", "dry_run", "retry_failed", "mlflow", "gif", "name", "engine", "fleet_size",
}
_PRESET_KEYS = {
    "name", "seeds", "budget", "budget_overrides", "eval_episodes", "learn_eval_every", "learn_eval_episodes", "algo_overrides",
}
_LAUNCHER_KEYS = {
    "local": {"name", "workers"},
    "slurm": {"name", "partition", "timeout_min", "cpus_per_task", "mem_gb", "array_parallelism", "folder", "poll_s"},
}


class ConfigError(ValueError):
    """An invalid sweep setting; the message says which key, where, and what is valid."""


def _hint(word: str, choices: list[str]) -> str:
    close = difflib.get_close_matches(str(word), choices, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _int(where: str, value: Any, minimum: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"{where}: expected an integer >= {minimum}, got {value!r}")
    return value


@dataclass(frozen=True)
class Preset:
    name: str
    seeds: tuple[int, ...]
    budget: int
    budget_overrides: Mapping[str, int]
    eval_episodes: int
    learn_eval_every: int
    learn_eval_episodes: int
    algo_overrides: Mapping[str, Mapping[str, Any]]

    def budget_for(self, scenario: str) -> int:
        return int(self.budget_overrides.get(scenario, self.budget))


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
    chain_files: Mapping[str, str] = field(default_factory=dict)  # chain name -> config option name
    engine: str = "fleet"  # fleet | single (runners/fleet.py)
    fleet_size: int = 36  # most runs trained together in one fleet


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


def _algo(option: str, node: Mapping[str, Any], preset: Preset, protocol: ProtocolSpec) -> AlgoChoice:
    """file values < the protocol's overrides for this algorithm < the preset's overrides for it <
    command-line overrides. Any class works (``_target_``); nothing here knows the baselines."""
    path, file_node = load_algo_file(option)
    where = f"algo={option} ({path})"
    composed = {k: v for k, v in node.items() if k != "planning"}
    planning = (node.get("planning") or file_node.get("planning") or {})
    file_values = {k: v for k, v in file_node.items() if k != "planning"}
    name = composed.get("name", option)
    try:
        base = LearnerSpec.from_mapping(file_values, name)
        spec = protocol.apply(base)
        override = preset.algo_overrides.get(option)
        if override:
            spec = spec.with_overrides(override)
        delta = _diff(composed, file_values)
        if delta:
            spec = spec.with_overrides(delta)
    except SpecError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    _check_hparam_types(where, spec, base)
    try:
        validate_learner(spec)  # keys against the algorithm class, values against sane ranges
    except SpecError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    steps_per_s, overhead, speedup = _planning_rate(where, planning, file_values, spec, protocol.name)
    return AlgoChoice(spec, steps_per_s, overhead, speedup)


_PLANNING_KEYS = {"steps_per_s", "update_share", "overhead_s", "fleet_speedup"}


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
    the fleet engine's measured gain at K >= 12 (BENCHMARKS.md), used by :mod:`runners.fleet`.
    """
    planning = dict(planning)
    by_protocol = planning.pop("protocols", None) or {}
    if not isinstance(by_protocol, Mapping):
        raise ConfigError(f"{where}: planning.protocols must map protocol names to planning values, got {by_protocol!r}")
    if protocol is not None and protocol in by_protocol:
        chosen = by_protocol[protocol]
        if not isinstance(chosen, Mapping):
            raise ConfigError(f"{where}: planning.protocols.{protocol} must be a mapping, got {chosen!r}")
        planning.update(chosen)
    unknown = set(planning) - _PLANNING_KEYS
    if unknown:
        raise ConfigError(f"{where}: unknown planning key(s) {sorted(unknown)}; valid: {sorted(_PLANNING_KEYS | {'protocols'})}")
    try:
        steps_per_s = float(planning.get("steps_per_s", 2000.0))
        share = float(planning.get("update_share", 1.0))
        overhead = float(planning.get("overhead_s", 1.0))
        speedup = float(planning.get("fleet_speedup", 1.0))
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


def _preset(node: Mapping[str, Any]) -> Preset:
    where = f"preset={node.get('name', '?')}"
    unknown = set(node) - _PRESET_KEYS
    if unknown:
        key = sorted(unknown)[0]
        raise ConfigError(f"{where}: unknown key {key!r}{_hint(key, sorted(_PRESET_KEYS))}; valid: {', '.join(sorted(_PRESET_KEYS))}")
    seeds = node.get("seeds")
    if not isinstance(seeds, list) or not seeds:
        raise ConfigError(f"{where}.seeds: expected a non-empty list of integers, got {seeds!r}")
    budgets = dict(node.get("budget_overrides") or {})
    known = all_scenarios()
    for scenario, value in budgets.items():
        if scenario not in known:
            raise ConfigError(f"{where}.budget_overrides: unknown scenario {scenario!r}{_hint(scenario, list(known))}")
        _int(f"{where}.budget_overrides.{scenario}", value)
    return Preset(
        name=str(node.get("name")),
        seeds=tuple(_int(f"{where}.seeds", s) for s in seeds),
        budget=_int(f"{where}.budget", node.get("budget")),
        budget_overrides=budgets,
        eval_episodes=_int(f"{where}.eval_episodes", node.get("eval_episodes"), 1),
        learn_eval_every=_int(f"{where}.learn_eval_every", node.get("learn_eval_every")),
        learn_eval_episodes=_int(f"{where}.learn_eval_episodes", node.get("learn_eval_episodes"), 1),
        algo_overrides=dict(node.get("algo_overrides") or {}),
    )


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
    for key in cfg:
        if key not in _TOP_KEYS and key != "hydra":
            raise ConfigError(f"unknown top-level key {key!r}{_hint(str(key), sorted(_TOP_KEYS))}; valid: {', '.join(sorted(_TOP_KEYS))}")
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
        protocol = protocol_spec(str(protocol_node.get("name")), {k: v for k, v in protocol_node.items() if k != "name"})
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
        variants = OmegaConf.to_container(variants) if not isinstance(variants, str) else [variants]
        if not isinstance(variants, list) or not all(isinstance(v, str) for v in variants):
            raise ConfigError(f"variant: expected a list of variant names, got {variants!r}")
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
        raw = OmegaConf.to_container(seeds) if not isinstance(seeds, int) else [seeds]
        if not isinstance(raw, list) or not raw:
            raise ConfigError(f"seed: expected a list of integers, got {raw!r}")
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

    launcher = _group(cfg, "launcher")
    kind = launcher.get("name")
    if kind not in _LAUNCHER_KEYS:
        raise ConfigError(f"launcher: unknown launcher {kind!r}; valid: {', '.join(_LAUNCHER_KEYS)}")
    unknown = set(launcher) - _LAUNCHER_KEYS[kind]
    if unknown:
        key = sorted(unknown)[0]
        raise ConfigError(f"launcher={kind}: unknown key {key!r}{_hint(key, sorted(_LAUNCHER_KEYS[kind]))}")
    if kind == "local" and launcher.get("workers") is not None:
        _int("launcher.workers", launcher["workers"], 1)
    if kind == "slurm":
        for key in ("timeout_min", "cpus_per_task", "mem_gb", "array_parallelism"):
            _int(f"launcher.{key}", launcher[key], 1)

    for key in ("dry_run", "retry_failed", "mlflow", "gif"):
        if not isinstance(cfg.get(key), bool):
            raise ConfigError(f"{key}: expected true or false, got {cfg.get(key)!r}")
    engine = cfg.get("engine", "fleet")
    if engine not in ("fleet", "single"):
        raise ConfigError(f"engine: expected fleet or single, got {engine!r}{_hint(str(engine), ['fleet', 'single'])}")
    fleet_size = _int("fleet_size", cfg.get("fleet_size", 36), 1)
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
    )
