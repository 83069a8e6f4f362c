"""The reference rows of Table 1, computed from the environments rather than from runs (part of
:mod:`leaderboard.runs.aggregate`): the random policy's exact expectation and the oracle's best and
worst, per (chain, scenario, beta, max_steps), cached on disk between builds.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from leaderboard.runs.display_order import (  # noqa: F401 - the reference rows' names, re-exported
    ORACLE_BEST,
    ORACLE_WORST,
    RANDOM_EXACT,
    REFERENCE_LEARNERS,
    row_order,
)
from leaderboard.runs.selection import CELL_KEYS
from morality_gym.clitools import write_atomically
from morality_gym.envs.registry import parse_env_id, scenario_named
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.oracle import oracle
from morality_gym.norms.chain import ChainError, parse_chain

#: Bump when the content of the reference cache changes meaning (old entries are then recomputed).
REFERENCE_CACHE_VERSION = 2  # 2: entries record the chain's norms and the variants it cannot score


# ---------------------------------------------------------------------------------------- reference rows
def reference_key(chain: str, scenario: str, beta: float, max_steps: int) -> str:
    """The cache key of a reference row: everything its numbers depend on."""
    return f"{chain}|{scenario}|beta={float(beta):g}|max_steps={int(max_steps)}"


def reference_mean(entry: Mapping[str, Any], field_name: str, variants: Iterable[str] | None = None) -> float:
    """Mean of one reference quantity over ``variants`` (default: all the scenario's), as Table 1
    averages a cell over its variants: a reference is compared with cells over the same variants."""
    chosen = entry["variants"] if variants is None else {v: entry["variants"][v] for v in variants}
    values = [v[field_name] for v in chosen.values()]
    return float(np.mean(values)) if values else math.nan


def covered_variants(runs: pd.DataFrame) -> dict[tuple[str, str, str, str], dict[str, frozenset[str]]]:
    """The variants each learner cell averages (those of its usable runs), per Table 1 row:
    ``{(protocol, preset, chain, scenario): {learner: variants}}``."""
    out: dict[tuple[str, str, str, str], dict[str, frozenset[str]]] = {}
    usable = runs.loc[runs["ok"]] if len(runs) else runs
    for key, part in usable.groupby(CELL_KEYS, dropna=False):
        *row, learner = key
        out.setdefault(tuple(row), {})[str(learner)] = frozenset(str(v) for v in part["variant"])
    return out


def reference_coverage(variants: list[str], n_all: int, cells: Mapping[str, frozenset[str]]) -> str:
    """Why a reference row is over fewer than all ``n_all`` variants, or covers more than some cell ('' if neither)."""
    notes = []
    if len(variants) < n_all:
        notes.append(f"over the {len(variants)} of {n_all} variants the row's runs cover ({', '.join(variants)})")
    narrower = sorted(learner for learner, vs in cells.items() if vs != set(variants))
    if narrower:
        notes.append(f"cells over other variants: {', '.join(narrower)}")
    return "; ".join(notes)


def reference_requests(table: pd.DataFrame) -> list[tuple[str, str, float, int]]:
    """The distinct (chain, scenario, beta, max_steps) the learner rows need references for."""
    learners = table.loc[table["kind"] == "learner"]
    found = {(c, s, float(b), int(m)) for c, s, b, m in zip(learners["chain"], learners["scenario"],
                                                             learners["beta"], learners["max_steps"])}
    order = {pair: i for i, pair in enumerate(row_order((c, s) for c, s, _, _ in found))}
    return sorted(found, key=lambda r: (order[(r[0], r[1])], r[2], r[3]))


def chain_definitions(runs: pd.DataFrame) -> dict[str, Any]:
    """Each chain of the runs as its runs defined it (a :class:`~morality_gym.norms.chain.MoralityChain`
    from the run config's norms), by name.

    A user's chain (a file given to the sweep) has no built-in name to look up: its reference rows
    are computed from this, the definition the runs were scored with. Runs without a readable
    chain definition are left out (their chain is then looked up by name).
    """
    out: dict[str, Any] = {}
    for config in runs["config"] if "config" in runs.columns else []:
        try:
            chain = json.loads(config)["chain"] if isinstance(config, str) else None
            if chain is None or chain["name"] in out:
                continue
            out[chain["name"]] = parse_chain({"name": chain["name"], "norms": [{"norm": n, "modality": m} for n, m in chain["norms"]]},
                                             source=f"the runs' chain {chain['name']}")
        except (ValueError, KeyError, TypeError, ChainError):
            continue
    return out


def _chain_content(chain: Any) -> list[list[str]] | None:
    return None if isinstance(chain, str) else [[n.name, n.modality] for n in chain.norms]


def _compute_entry(chain: str, scenario: str, beta: float, max_steps: int, definition: Any = None) -> dict[str, Any]:
    chain_or_name = definition if definition is not None else chain
    variants: dict[str, dict[str, Any]] = {}
    unscorable: dict[str, str] = {}
    for env_id in scenario_named(scenario).env_ids:
        try:
            exact = exact_evaluate("random", env_id, chain_or_name, max_steps=max_steps, beta=beta)
        except ChainError as exc:  # a user's chain may fit some variants only; sweeps run it on those
            unscorable[parse_env_id(env_id)[1]] = str(exc)
            continue
        extremes = oracle(env_id, chain_or_name, beta=beta, max_steps=max_steps)
        variants[parse_env_id(env_id)[1]] = {
            "env_id": env_id,
            "random_exact": float(exact.metric),
            "random_functions": {k: float(v) for k, v in exact.functions.items()},
            "oracle_best": float(extremes.best.metric),
            "oracle_worst": float(extremes.worst.metric),
            "oracle_best_actions": list(extremes.best.actions),
            "oracle_worst_actions": list(extremes.worst.actions),
        }
    return {"chain": chain, "scenario": scenario, "beta": beta, "max_steps": max_steps,
            "env_ids": scenario_named(scenario).env_ids, "variants": variants, "unscorable": unscorable,
            "norms": _chain_content(chain_or_name)}


def load_reference_cache(path: Path) -> dict[str, Any]:
    """Entries of the reference cache; an unreadable or outdated cache counts as empty."""
    try:
        body = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(body, dict) or body.get("version") != REFERENCE_CACHE_VERSION:
        return {}
    entries = body.get("entries")
    return entries if isinstance(entries, dict) else {}


def _write_json_atomic(path: Path, body: Any) -> None:
    write_atomically(path, lambda fh: fh.write(json.dumps(body, indent=1, sort_keys=True).encode("utf-8")))


@dataclass
class ReferenceResult:
    """Reference entries by key, how many came from the cache, and the rows that could not be computed."""

    entries: dict[str, dict[str, Any]] = field(default_factory=dict)
    cached: int = 0
    computed: int = 0
    errors: dict[str, str] = field(default_factory=dict)


def compute_reference(
    requests: list[tuple[str, str, float, int]],
    cache_path: Path,
    progress: Callable[[Iterable[Any], str, int], Iterable[Any]] | None = None,
    chains: Mapping[str, Any] | None = None,
) -> ReferenceResult:
    """Exact Random and oracle best/worst of each requested row, per variant, cached on disk.

    The oracle needs ~10 s for all of Table 1, too slow to repeat on every build, and its result
    depends only on (chain, scenario, beta, max_steps), the chain's norms and the scenario's
    variants, which is what an entry is keyed and checked by. ``chains``: the chains' definitions
    by name (:func:`chain_definitions` of the runs), needed for a user's chain, which has no
    built-in name; a chain not in it is looked up by name. A row that cannot be computed is
    reported in ``errors`` (with the reason) instead of failing the whole build.
    """
    chains = dict(chains or {})

    cache = load_reference_cache(cache_path)
    result = ReferenceResult()
    todo = []
    for chain, scenario, beta, steps in requests:
        key = reference_key(chain, scenario, beta, steps)
        entry = cache.get(key)
        try:
            env_ids = scenario_named(scenario).env_ids
        except KeyError as exc:
            result.errors[key] = str(exc)
            continue
        content = _chain_content(chains[chain]) if chain in chains else None
        if entry is not None and entry.get("env_ids") == env_ids and (content is None or entry.get("norms") == content):
            result.entries[key] = entry
            result.cached += 1
        else:
            todo.append((key, chain, scenario, beta, steps))
    iterator: Iterable[Any] = progress(todo, "reference rows (exact Random, oracle)", len(todo)) if progress and todo else todo
    for key, chain, scenario, beta, steps in iterator:
        try:
            # as the cache will give it back: its JSON sorts the per-variant keys, and a mean summed in
            # another order differs in the last bit, which made a first build's numbers (and the
            # statistics' cache key) differ from every later build's
            entry = _compute_entry(chain, scenario, beta, steps, chains.get(chain))
            result.entries[key] = json.loads(json.dumps(entry, sort_keys=True))
            result.computed += 1
        except Exception as exc:  # noqa: BLE001 - reported per row, the build goes on
            result.errors[key] = f"{type(exc).__name__}: {exc}"
    if result.computed:
        _write_json_atomic(cache_path, {"version": REFERENCE_CACHE_VERSION, "entries": cache | result.entries})
    return result
