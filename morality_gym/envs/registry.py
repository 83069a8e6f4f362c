"""Where scenarios come from, which env ids exist, and how an id is resolved (with helpful errors).

Built-in scenarios are the YAML files in ``morality_gym/data/scenarios``. Users add their own
without touching code: put YAML files in a directory and either call
:func:`~morality_gym.envs.registration.add_scenario_dir` or list the directory in the
``MORALITY_GYM_SCENARIOS`` environment variable (``os.pathsep``-separated). Every variant of every
scenario is registered with Gymnasium as ``MoralityGym/{Scenario}-{Variant}-v1``
(:mod:`morality_gym.envs.registration`, which builds on this module; this module knows nothing of
Gymnasium nor of the env class, so that both can import it).

A user's file is checked more thoroughly than a built-in one: its utility bounds are compared
with what its worlds can produce (:mod:`morality_gym.world.bounds`, ~0.1 s per variant; the
built-in files pass the same check in the test suite, so ``import morality_gym`` does not pay
for it). A bad file found through ``MORALITY_GYM_SCENARIOS`` must not break the built-in envs
nor every command: it is skipped with a one-line :class:`ScenarioFileWarning` (file, field, fix)
and remembered, so that asking for the scenario it would have defined explains why it is not
there (:func:`skipped_scenario_files`). :func:`load_scenario_dir` is an explicit request, so it
raises instead.
"""

from __future__ import annotations

import difflib
import hashlib
import os
import threading
import warnings
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import yaml

from morality_gym.clitools import OneLineWarning
from morality_gym.constants import MAX_STEPS
from morality_gym.world.bounds import compare_bounds, variant_spans
from morality_gym.world.bounds_cache import cache_dir_of, read_entry, write_entry
from morality_gym.world.graph import StateGraph
from morality_gym.world.layout import Scenario, ScenarioError, load_scenario, scenario_from_bytes
from morality_gym.world.observe import ObservationCodec
from morality_gym.world.rules import Overrides, World

NAMESPACE = "MoralityGym"
VERSION = "v1"
#: Every env truncates at step ``max_steps + 1``; this is ``max_steps`` unless a caller sets it
#: (public alias of :data:`morality_gym.constants.MAX_STEPS`, 200 in every run of the paper). A user
#: scenario's bounds are checked against the horizon it implies when the file is loaded.
DEFAULT_MAX_STEPS = MAX_STEPS
BUILTIN_DIR = Path(__file__).resolve().parent.parent / "data" / "scenarios"
SCENARIOS_ENV = "MORALITY_GYM_SCENARIOS"

_scenarios: dict[str, Scenario] = {}
_extra_dirs: list[Path] = []
_skipped: list[SkippedScenario] = []
_lock = threading.Lock()


class UnknownEnvError(KeyError):
    """An env id that does not name a registered scenario variant; the message lists close ids."""

    def __str__(self) -> str:  # KeyError would otherwise print the message in quotes
        return str(self.args[0])


class ScenarioFileWarning(OneLineWarning):
    """A user's scenario file was skipped; the message says why and how to fix it."""


@dataclass(frozen=True)
class SkippedScenario:
    """A user's scenario file that was not loaded, the scenario name it declares (if readable), why."""

    path: Path
    name: str | None
    error: str


def _declared_name(path: Path) -> str | None:
    """The ``name:`` a scenario file declares, if the file is readable YAML with one."""
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError):
        return None
    name = raw.get("name") if isinstance(raw, dict) else None
    return name if isinstance(name, str) else None


def _horizon() -> int:
    return MAX_STEPS + 1


def load_user_file(path: str | Path, graphs: Mapping[str, StateGraph] | None = None) -> Scenario:
    """Load and check one scenario file as every user file is checked (the layout and fields, then
    its bounds by exact enumeration); raises :class:`ScenarioError`. Registers nothing.

    ``graphs``: already enumerated state graphs of the file's variants (see
    :func:`~morality_gym.world.bounds.check_bounds`). Where the file's directory keeps a bounds
    cache (:mod:`~morality_gym.world.bounds_cache`), the spans measured for these very bytes are
    read from it instead of enumerating again, and recorded there after a measurement."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read the file: {exc}") from exc
    scenario = scenario_from_bytes(data, str(path))
    horizon = _horizon()
    folder = cache_dir_of(path)
    digest = hashlib.sha256(data).hexdigest()
    spans = read_entry(folder, digest, horizon, list(scenario.variants)) if folder is not None else None
    if spans is None:
        spans = variant_spans(scenario, horizon, graphs)
        if folder is not None:
            write_entry(folder, digest, horizon, spans)
    compare_bounds(scenario, spans, horizon)
    return scenario



def _load_dir(directory: Path, user: bool = False) -> dict[str, Scenario]:
    """Every scenario file of ``directory``; raises on the first bad one (built-ins, explicit requests)."""
    found: dict[str, Scenario] = {}
    for path in sorted(directory.glob("*.yaml")):
        scenario = load_user_file(path) if user else load_scenario(path)
        if scenario.name in found:
            raise ScenarioError(f"{path}: name: scenario name {scenario.name!r} is already defined by "
                                f"{found[scenario.name].source}. Fix: rename one of them")
        found[scenario.name] = scenario
    return found


def _skip(path: Path, error: str) -> None:
    """Remember a skipped user file and say so on one line (the warning's location is the file)."""
    prefix = f"{path}: "
    message = error.removeprefix(prefix)
    _skipped.append(SkippedScenario(path, _declared_name(path) if path.is_file() else None, error))
    warnings.warn_explicit(f"skipped this scenario file: {message}", ScenarioFileWarning, str(path), 1)


_format_warning = warnings.formatwarning


def _one_line_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                      line: str | None = None) -> str:
    """Python shows a warning with the source line it points at; a skipped scenario file's first
    line says nothing, so its warning is the one line ``<file>: ScenarioFileWarning: <why, fix>``
    (so is every :class:`~morality_gym.clitools.OneLineWarning`: a refused cache entry, ...).
    Every other warning is formatted as before."""
    if isinstance(category, type) and issubclass(category, OneLineWarning):
        text = " | ".join(part.strip() for part in str(message).splitlines() if part.strip())
        return f"{filename}: {category.__name__}: {text}\n"
    return _format_warning(message, category, filename, lineno, line)


warnings.formatwarning = _one_line_warning


def _load_env_dirs(known: dict[str, Scenario]) -> None:
    """Load ``MORALITY_GYM_SCENARIOS`` file by file, skipping (and reporting) each bad one."""
    for entry in [p for p in os.environ.get(SCENARIOS_ENV, "").split(os.pathsep) if p]:
        directory = Path(entry)
        if not directory.is_dir():
            _skip(directory, f"{directory}: {SCENARIOS_ENV} lists it, but it is not a directory. "
                             f"Fix: correct or remove the entry in {SCENARIOS_ENV}")
            continue
        for path in sorted(directory.glob("*.yaml")):
            try:
                scenario = load_user_file(path)
            except ScenarioError as exc:
                _skip(path, str(exc))
                continue
            if scenario.name in known:
                _skip(path, f"{path}: name: scenario {scenario.name!r} is already defined by {known[scenario.name].source}. "
                            "Fix: give this scenario another name")
                continue
            known[scenario.name] = scenario


def scenarios() -> dict[str, Scenario]:
    """All known scenarios by name (built-in first, then user directories), loaded once."""
    with _lock:
        if not _scenarios:
            loaded = _load_dir(BUILTIN_DIR)
            _load_env_dirs(loaded)
            for directory in _extra_dirs:
                for name, scenario in _load_dir(directory, user=True).items():
                    if name not in loaded:
                        loaded[name] = scenario
            _scenarios.update(loaded)
        return _scenarios


def skipped_scenario_files() -> list[SkippedScenario]:
    """The user scenario files that were skipped, with the reason (see the module docstring)."""
    scenarios()
    return list(_skipped)


def _skipped_hint(name: str) -> str:
    """Why a scenario of this name is missing, if a skipped file declared it (else '')."""
    for item in skipped_scenario_files():
        if item.name == name or item.path.stem.lower() == name.lower():
            return f"Scenario {name!r} is defined by {item.path}, which was skipped because it is invalid: {item.error}"
    return ""


def load_scenario_dir(directory: str | Path) -> list[str]:
    """Load every scenario YAML in ``directory`` into the registry and return its env ids.

    An explicit request: a bad file raises :class:`ScenarioError` and nothing of the directory is
    added. Users call :func:`~morality_gym.envs.registration.add_scenario_dir`, which also
    registers the new ids with Gymnasium. Adding a file that is already loaded (the same file,
    e.g. again in a spawned worker that re-runs the user's script) is not an error.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise NotADirectoryError(f"scenario directory {directory} does not exist")
    new = _load_dir(directory, user=True)
    known = scenarios()
    with _lock:
        for name, scenario in new.items():
            if name in known and not _same_file(known[name].source, scenario.source):
                raise ScenarioError(f"{scenario.source}: name: scenario {name!r} is already defined by "
                                    f"{known[name].source}. Fix: give this scenario another name")
        _extra_dirs.append(directory)
        known.update(new)
    _inherit(directory)
    return [eid for s in new.values() for eid in s.env_ids]


@contextmanager
def scenario_on_trial(scenario: Scenario, graphs: Mapping[str, StateGraph] | None = None) -> Iterator[list[str]]:
    """Make an already checked scenario known to this process inside the block only; yields its ids.

    The generator scores each dilemma it draws with the oracle and the exact evaluator, which find
    envs by id in this registry; most draws are thrown away, so they must not stay registered (nor
    be listed in ``MORALITY_GYM_SCENARIOS`` for child processes, as :func:`load_scenario_dir` does).
    ``graphs`` (by variant) are state graphs the caller has already enumerated for these very worlds
    (same layout and variants; enumeration is most of a draw's cost), used instead of new ones.
    Leaving the block forgets the scenario and its graphs.
    """
    known = scenarios()
    with _lock:
        if scenario.name in known:
            raise ScenarioError(f"{scenario.source}: name: scenario {scenario.name!r} is already defined by "
                                f"{known[scenario.name].source}. Fix: give this scenario another name")
        known[scenario.name] = scenario
    with _graphs_lock:
        for variant, graph in (graphs or {}).items():
            _graphs[(scenario.name, variant, None, True)] = graph
    try:
        yield scenario.env_ids
    finally:
        with _lock:
            known.pop(scenario.name, None)
        with _graphs_lock:
            for key in [k for k in _graphs if k[0] == scenario.name]:
                del _graphs[key]


def _same_file(a: str, b: str) -> bool:
    return Path(a).resolve() == Path(b).resolve()


def _inherit(directory: Path) -> None:
    """List ``directory`` in ``MORALITY_GYM_SCENARIOS`` for the processes this one starts.

    A spawned worker (``gym.make_vec(..., vectorization_mode="async")``, SB3's ``SubprocVecEnv``,
    a process pool) imports the package afresh and calls ``gym.make`` on the id: without this it
    would not know a scenario added here. This process has loaded the directory already and does
    not read the variable again.
    """
    entries = [p for p in os.environ.get(SCENARIOS_ENV, "").split(os.pathsep) if p]
    resolved = str(directory.resolve())
    if resolved not in entries and str(directory) not in entries:
        os.environ[SCENARIOS_ENV] = os.pathsep.join([*entries, resolved])


def list_envs(scenario: str | None = None) -> list[str]:
    """Every Gymnasium id (``MoralityGym/{Scenario}-{Variant}-v1``), in scenario-file order and
    variant-table order: what ``gym.make`` takes. Every function of this package also takes the
    id without the namespace (:func:`parse_env_id`); :func:`env_ids` lists those."""
    return [f"{NAMESPACE}/{eid}" for eid in env_ids(scenario)]


def env_ids(scenario: str | None = None) -> list[str]:
    """Every env id without the Gymnasium namespace (``{Scenario}-{Variant}-v1``), as results,
    run configurations and the reference's recordings name envs."""
    if scenario is not None:
        return scenario_named(scenario).env_ids
    return [eid for s in scenarios().values() for eid in s.env_ids]


def scenario_named(name: str) -> Scenario:
    """A scenario by name; unknown names list the closest ones."""
    known = scenarios()
    if name in known:
        return known[name]
    skipped = _skipped_hint(name)
    if skipped:
        raise UnknownEnvError(skipped)
    close = difflib.get_close_matches(name, list(known), n=3, cutoff=0.5)
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    raise UnknownEnvError(f"Unknown scenario {name!r}.{hint} Scenarios: {', '.join(known)}.")


def parse_env_id(env_id: str) -> tuple[Scenario, str]:
    """Resolve an env id to (scenario, variant).

    Accepts ``Scenario-Variant-v1``, with an optional ``MoralityGym/`` namespace and an optional
    ``Trolley-`` category prefix (as the reference does). Unknown ids raise
    :class:`UnknownEnvError` listing the closest valid ids.
    """
    if not isinstance(env_id, str):
        raise TypeError(f"env id must be a string, got {type(env_id).__name__}")
    bare = env_id.split("/", 1)[1] if env_id.startswith(f"{NAMESPACE}/") else env_id
    parts = bare.split("-")
    if len(parts) == 4 and parts[0] == "Trolley":
        parts = parts[1:]
    known = scenarios()
    if len(parts) == 3 and parts[2] == VERSION and parts[0] in known and parts[1] in known[parts[0]].variants:
        return known[parts[0]], parts[1]
    raise UnknownEnvError(_unknown_id_message(env_id, parts, known))


def canonical_env_id(env_id: str) -> str:
    """``env_id`` as the registry spells it (``PushOrSwitch-Human-v1``: no namespace nor ``Trolley-``
    prefix), or :class:`UnknownEnvError`; the one key under which tables, checkpoints and trained
    policies compare env ids."""
    scenario, variant = parse_env_id(env_id)
    return scenario.env_id(variant)


def _unknown_id_message(env_id: str, parts: list[str], known: dict[str, Scenario]) -> str:
    """Why an env id is unknown: a skipped scenario's reason, else the closest valid ids."""
    skipped = _skipped_hint(parts[0]) if parts else ""
    if skipped:
        return skipped
    all_ids = env_ids()
    lowered = {eid.lower(): eid for eid in all_ids}
    candidate = "-".join(parts)
    close = difflib.get_close_matches(candidate.lower(), list(lowered), n=5, cutoff=0.6)
    if not close and parts and parts[0] in known:
        close = [eid.lower() for eid in known[parts[0]].env_ids]
    hint = "Closest valid ids: " + ", ".join(lowered[c] for c in close) if close else f"Valid ids: morality_gym.list_envs() ({len(all_ids)} ids)"
    return f"Unknown MoralityGym env id {env_id!r}. {hint}."


GraphKey = tuple[str, str, Overrides | None, bool]
#: The per-process state graphs, by (scenario, variant, overrides, normalise): one per world, shared
#: by every env, simulator and evaluation of it.
_graphs: dict[GraphKey, StateGraph] = {}
_graphs_lock = threading.Lock()


def _cached_graph(scenario_name: str, variant: str, overrides: Overrides | None, normalise: bool) -> StateGraph:
    key = (scenario_name, variant, overrides, normalise)
    graph = _graphs.get(key)
    if graph is None:
        with _graphs_lock:
            graph = _graphs.get(key)
            if graph is None:
                world = World(scenarios()[scenario_name], variant, overrides)
                graph = _graphs[key] = StateGraph(world, ObservationCodec(world, normalise=normalise))
    return graph


def clear_graph_cache() -> None:
    """Forget every state graph of this process (benchmarks time enumeration from scratch)."""
    with _graphs_lock:
        _graphs.clear()


def state_graph(env_id: str, overrides: Overrides | None = None, normalise: bool = True) -> StateGraph:
    """The (per-process, shared) memoised state graph of an env id."""
    scenario, variant = parse_env_id(env_id)
    return _cached_graph(scenario.name, variant, overrides, normalise)
