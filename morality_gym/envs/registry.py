"""Where scenarios come from, which env ids exist, and how an id is resolved (with helpful errors).

Built-in scenarios are the YAML files in ``morality_gym/data/scenarios``. Users add their own
without touching code: put YAML files in a directory and either call
:func:`add_scenario_dir` or list the directory in the ``MORALITY_GYM_SCENARIOS`` environment
variable (``os.pathsep``-separated). Every variant of every scenario is registered with Gymnasium
as ``MoralityGym/{Scenario}-{Variant}-v1``.
"""

from __future__ import annotations

import difflib
import os
import threading
from functools import lru_cache
from pathlib import Path

from morality_gym.world.graph import StateGraph
from morality_gym.world.layout import Scenario, load_scenario
from morality_gym.world.observe import ObservationCodec
from morality_gym.world.rules import Overrides, World

NAMESPACE = "MoralityGym"
VERSION = "v1"
BUILTIN_DIR = Path(__file__).resolve().parent.parent / "data" / "scenarios"

_scenarios: dict[str, Scenario] = {}
_extra_dirs: list[Path] = []
_lock = threading.Lock()


class UnknownEnvError(KeyError):
    """An env id that does not name a registered scenario variant; the message lists close ids."""

    def __str__(self) -> str:  # KeyError would otherwise print the message in quotes
        return str(self.args[0])


def _load_dir(directory: Path) -> dict[str, Scenario]:
    found: dict[str, Scenario] = {}
    for path in sorted(directory.glob("*.yaml")):
        scenario = load_scenario(path)
        if scenario.name in found:
            raise ValueError(f"{path}: scenario name {scenario.name!r} is already defined by {found[scenario.name].source}")
        found[scenario.name] = scenario
    return found


def scenarios() -> dict[str, Scenario]:
    """All known scenarios by name (built-in first, then user directories), loaded once."""
    with _lock:
        if not _scenarios:
            _scenarios.update(_load_dir(BUILTIN_DIR))
            env_dirs = [Path(p) for p in os.environ.get("MORALITY_GYM_SCENARIOS", "").split(os.pathsep) if p]
            for directory in env_dirs + _extra_dirs:
                for name, scenario in _load_dir(directory).items():
                    if name in _scenarios:
                        raise ValueError(f"{scenario.source}: scenario {name!r} is already defined by {_scenarios[name].source}")
                    _scenarios[name] = scenario
        return _scenarios


def add_scenario_dir(directory: str | Path) -> list[str]:
    """Load every scenario YAML in ``directory``, register its env ids and return them."""
    directory = Path(directory)
    if not directory.is_dir():
        raise NotADirectoryError(f"scenario directory {directory} does not exist")
    new = _load_dir(directory)
    known = scenarios()
    with _lock:
        for name, scenario in new.items():
            if name in known:
                raise ValueError(f"{scenario.source}: scenario {name!r} is already defined by {known[name].source}")
        _extra_dirs.append(directory)
        known.update(new)
    from morality_gym.envs.registration import register_all

    register_all()
    return [eid for s in new.values() for eid in s.env_ids]


def list_envs(scenario: str | None = None) -> list[str]:
    """Every env id (``{Scenario}-{Variant}-v1``), in scenario-file order and variant-table order."""
    if scenario is not None:
        return scenario_named(scenario).env_ids
    return [eid for s in scenarios().values() for eid in s.env_ids]


def scenario_named(name: str) -> Scenario:
    """A scenario by name; unknown names list the closest ones."""
    known = scenarios()
    if name in known:
        return known[name]
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
    all_ids = list_envs()
    lowered = {eid.lower(): eid for eid in all_ids}
    candidate = "-".join(parts)
    close = difflib.get_close_matches(candidate.lower(), list(lowered), n=5, cutoff=0.6)
    if not close and parts and parts[0] in known:
        close = [eid.lower() for eid in known[parts[0]].env_ids]
    hint = "Closest valid ids: " + ", ".join(lowered[c] for c in close) if close else f"Valid ids: morality_gym.list_envs() ({len(all_ids)} ids)"
    raise UnknownEnvError(f"Unknown MoralityGym env id {env_id!r}. {hint}.")


@lru_cache(maxsize=None)
def _cached_graph(scenario_name: str, variant: str, overrides: Overrides | None, normalise: bool) -> StateGraph:
    scenario = scenarios()[scenario_name]
    world = World(scenario, variant, overrides)
    return StateGraph(world, ObservationCodec(world, normalise=normalise))


def state_graph(env_id: str, overrides: Overrides | None = None, normalise: bool = True) -> StateGraph:
    """The (per-process, shared) memoised state graph of an env id."""
    scenario, variant = parse_env_id(env_id)
    return _cached_graph(scenario.name, variant, overrides, normalise)
