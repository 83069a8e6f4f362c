"""A drawn dilemma's state graph: its size, within a cap, and the exact range of its harm totals.

The size cap keeps every generated dilemma as cheap as a built-in one wherever a whole graph is
used: the exact evaluator and the oracle propagate it for 201 steps, the batched simulators and the
fleets gather from per-state tables (a grid observation is 5 KiB a state), and a split holds
hundreds of dilemmas. The harm bounds of a variant are not drawn but measured, by the same exact
enumeration that checks a user's file (:func:`morality_gym.world.bounds.reachable_totals`), so
they are right by construction and the loader's check of them is a test of this code.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from morality_gym.constants import MAX_STEPS
from morality_gym.world.bounds import reachable_totals
from morality_gym.world.graph import N_ACTIONS, StateGraph
from morality_gym.world.layout import UTILITY_TYPES, Scenario
from morality_gym.world.observe import ObservationCodec
from morality_gym.world.rules import World
from morality_gym.world.vocab import UTILITIES

#: Most states a generated variant's graph may have. The largest built-in graph (Switch7, 1,298
#: states) takes about a second for the oracle and the exact Random value under all six chains;
#: 5,000 keeps a generated variant within a few seconds and its grid table within 25 MiB.
MAX_STATES: Final[int] = 5_000
#: The horizon a variant's totals are enumerated within: an env truncates at step ``MAX_STEPS + 1``
#: (the loader checks a user file's bounds within the same horizon).
HORIZON: Final[int] = MAX_STEPS + 1


class GraphTooLarge(Exception):
    """A variant's state graph has more than the allowed number of states."""


@dataclass(frozen=True)
class VariantMeasure:
    """What enumerating one variant's graph gives: its size and the span of each episode harm total."""

    n_states: int
    spans: dict[str, tuple[int, int]]  # every utility of vocab.UTILITIES: (lowest, highest) total
    graph: StateGraph = field(repr=False, compare=False)  # enumerated once, reused by the checks and scores


def bounded_graph(world: World, max_states: int) -> StateGraph:
    """The world's fully enumerated state graph, or :class:`GraphTooLarge` as soon as it passes
    ``max_states`` (so an oversized draw costs no more than the cap)."""
    graph = StateGraph(world, ObservationCodec(world))
    queue, seen = deque([0]), {0}
    while queue:
        sid = queue.popleft()
        for action in range(N_ACTIONS):
            nxt = graph.edge(sid, action).next
            if nxt not in seen:
                seen.add(nxt)
                queue.append(nxt)
        if len(graph.states) > max_states:
            raise GraphTooLarge(f"{world.scenario.name}: more than {max_states} states")
    return graph


def measure_variant(scenario: Scenario, variant: str, max_states: int = MAX_STATES) -> VariantMeasure:
    """Enumerate one variant (within ``max_states``) and the harm totals its episodes can end with."""
    graph = bounded_graph(World(scenario, variant), max_states)
    totals = reachable_totals(graph.tables(), HORIZON)
    spans = {name: (int(np.min(totals[:, i])), int(np.max(totals[:, i]))) for i, name in enumerate(UTILITIES)}
    return VariantMeasure(graph.tables().n_states, spans, graph)


def variant_bounds(measure: VariantMeasure) -> dict[str, tuple[int, int]]:
    """A variant's ``bounds``: exactly the lowest and highest total of each type utility."""
    return {key: measure.spans[key] for key in UTILITY_TYPES}


def scenario_bounds(measures: list[VariantMeasure]) -> dict[str, tuple[int, int]]:
    """The scenario-wide ``utility_bounds``: from 0 to the highest total any variant reaches (at
    least 1, so that no normalisation divides by zero)."""
    return {name: (0, max(1, *(m.spans[name][1] for m in measures))) for name in UTILITIES}
