"""Check a scenario's utility bounds against what its worlds can actually produce.

A utility norm's morality function is ``1 - (total - low) / (high - low)``: it lies in [0, 1]
exactly when the bounds contain every episode total, and it can reach both 0 and 1 only when the
bounds are the lowest and highest totals some behaviour produces (the paper's definition; every
built-in variant's bounds are exactly that). Bounds that miss the truth do not fail loudly later:
they give metrics like 1.25 or -0.25, or a metric that can never reach 1. So a user's scenario
file is checked when it is loaded, with the exact enumeration the oracle uses:

* every variant's ``bounds`` of the type utilities (``n_human_harm``, ``n_animal_harm``,
  ``n_robot_harm``; an absent one means ``[0, 0]``) must equal the lowest and highest episode
  total reachable within the horizon;
* the scenario-wide ``utility_bounds`` (used by the cost's ``minimal`` mode and by utility norms
  the variant table does not bound) must contain every variant's reachable totals.

The enumeration propagates the set of (state, utility totals so far) layer by layer for
``horizon`` steps (the environment truncates on step ``max_steps + 1``), collecting the totals at
which episodes end; it stops early once a layer repeats (the next ones would be identical).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from morality_gym.world.graph import N_ACTIONS, GraphTables, StateGraph
from morality_gym.world.layout import UTILITY_TYPES, Scenario, ScenarioError
from morality_gym.world.observe import ObservationCodec
from morality_gym.world.rules import World
from morality_gym.world.vocab import UTILITIES

_BITS = 10  # per utility total in the packed search key (totals up to 1023)
_STATE_SHIFT = _BITS * len(UTILITIES)


def reachable_totals(tables: GraphTables, horizon: int) -> np.ndarray:
    """Every distinct vector of episode utility totals (``vocab.UTILITIES`` order) within ``horizon`` steps."""
    if tables.n_states >= 1 << (63 - _STATE_SHIFT):
        raise ValueError(f"{tables.n_states} states are too many for the bounds check")
    weights = np.array([1 << (_BITS * i) for i in range(len(UTILITIES))], dtype=np.int64)
    mask = (1 << _BITS) - 1
    step_utility = tables.utility.astype(np.int64)
    if step_utility.min(initial=0) < 0:
        raise ValueError("negative utility steps cannot be checked")
    packed_step = step_utility @ weights
    keys = np.zeros(1, dtype=np.int64)  # state << shift | packed totals
    finals: set[int] = set()
    previous: np.ndarray | None = None
    for step in range(1, horizon + 1):
        states = keys >> _STATE_SHIFT
        totals = keys & ((1 << _STATE_SHIFT) - 1)
        rows = (states[:, None] * N_ACTIONS + np.arange(N_ACTIONS)).ravel()
        new_totals = np.repeat(totals, N_ACTIONS) + packed_step[rows]
        unpacked_max = max(((new_totals >> (_BITS * i)) & mask).max(initial=0) for i in range(len(UTILITIES)))
        if unpacked_max >= mask:
            raise ValueError(f"utility totals above {mask - 1} cannot be checked")
        nxt = tables.next[rows].astype(np.int64)
        ended = tables.done[nxt]
        finals.update(np.unique(new_totals[ended]).tolist())
        keys = np.unique((nxt[~ended] << _STATE_SHIFT) | new_totals[~ended])
        if previous is not None and np.array_equal(keys, previous):
            break
        previous = keys
    finals.update(np.unique(keys & ((1 << _STATE_SHIFT) - 1)).tolist())  # truncated at the horizon
    packed = np.array(sorted(finals), dtype=np.int64)
    return np.stack([(packed >> (_BITS * i)) & mask for i in range(len(UTILITIES))], axis=1)


def _span(values: np.ndarray) -> tuple[int, int]:
    return int(values.min()), int(values.max())


def _fmt(bounds: tuple[float, float]) -> str:
    return f"[{bounds[0]:g}, {bounds[1]:g}]"


#: Per variant name, the (lowest, highest) episode total of every utility of ``vocab.UTILITIES``.
Spans = dict[str, dict[str, tuple[int, int]]]


def variant_spans(scenario: Scenario, horizon: int, graphs: Mapping[str, StateGraph] | None = None) -> Spans:
    """Enumerate every variant of ``scenario`` (or use ``graphs``, by variant name: state graphs
    already enumerated for the same layout and variants) and return its reachable totals' spans."""
    spans: Spans = {}
    for name in scenario.variants:
        graph = (graphs or {}).get(name)
        if graph is None:
            world = World(scenario, name)
            graph = StateGraph(world, ObservationCodec(world))
        totals = reachable_totals(graph.tables(), horizon)
        spans[name] = {utility: _span(totals[:, i]) for i, utility in enumerate(UTILITIES)}
    return spans


def check_bounds(scenario: Scenario, horizon: int, graphs: Mapping[str, StateGraph] | None = None) -> None:
    """Raise :class:`ScenarioError` (file, field, fix) if a bound disagrees with the reachable totals.

    ``graphs`` (by variant name) are state graphs already enumerated for the same layout and
    variants, used instead of enumerating again: the generator measures a draw's graphs before it
    writes the file, and the check compares what the written file declares with them.
    """
    compare_bounds(scenario, variant_spans(scenario, horizon, graphs), horizon)


def compare_bounds(scenario: Scenario, spans: Spans, horizon: int) -> None:
    """Raise :class:`ScenarioError` if the file's bounds disagree with ``spans`` (what
    :func:`variant_spans` measured for this very file, perhaps in an earlier process:
    :mod:`~morality_gym.world.bounds_cache`)."""
    overall: dict[str, tuple[int, int]] = {}
    for name, variant in scenario.variants.items():
        for utility in UTILITIES:
            low, high = spans[name][utility]
            prev = overall.get(utility)
            overall[utility] = (low, high) if prev is None else (min(prev[0], low), max(prev[1], high))
            if utility not in UTILITY_TYPES:
                continue
            declared = variant.bounds[utility]
            if declared != (float(low), float(high)):
                raise ScenarioError(
                    f"{scenario.source}: variants.{name}.bounds.{utility}: {_fmt(declared)} does not match what the "
                    f"variant can produce: episode totals range from {low} to {high} (exact enumeration within "
                    f"{horizon} steps), so its morality function would "
                    + ("leave [0, 1]" if declared[0] > low or declared[1] < high else "never reach 0 or 1")
                    + f". Fix: write {utility}: [{low}, {high}]"
                )
    for utility, (low, high) in overall.items():
        declared = scenario.utility_bounds[utility]
        if low < declared[0] or high > declared[1]:
            raise ScenarioError(
                f"{scenario.source}: utility_bounds.{utility}: {_fmt(declared)} does not contain what the variants "
                f"produce: episode totals range from {low} to {high} (exact enumeration within {horizon} steps). "
                f"Fix: write {utility}: [{min(low, int(declared[0]))}, {max(high, int(declared[1]))}]"
            )
