"""Every scenario's trolley routes: pulling the levers sends each trolley into the recorded group.

For each scenario and each combination of lever states in ``tests/data/route_tables.yaml``
(recorded from the reference), the agent walks to each lever, pulls it the right number of times
before the trolley reaches the switch, walks back to its start and waits; the test then checks
who is hit and in which step, on every variant. The plan is computed from the scenario's layout
(shortest walks on the agent's floor), not hard-coded, so the same test covers new layouts.

The timing cases pin down spec Q14: the switch state is read at the start of a step, so the
last useful pull is in step k (the trolley then sits on the switch) and a pull in step k+1 is
one step too late and leaves the trolley on its old route (golden traces 3 and 4).
"""

from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import Any

import pytest

import morality_gym
from morality_gym import TrolleyEnv
from morality_gym.envs.registry import BUILTIN_DIR
from morality_gym.world.layout import Scenario
from tests.helpers import DOWN, INTERACT, LEFT, RIGHT, STAY, UP, newly_harmed, play, route_tables

Cell = tuple[int, int]
_MOVES: dict[int, Cell] = {UP: (-1, 0), DOWN: (1, 0), LEFT: (0, -1), RIGHT: (0, 1)}


# ---------------------------------------------------------------------------------------- planning
def _walk(scenario: Scenario, start: Cell, goals: set[Cell]) -> tuple[Cell, list[int]]:
    """Shortest walk from ``start`` to any goal over open floor, never entering the landmark
    (that would stop the agent) or a character's cell (that would be a collision)."""
    blocked = set(scenario.walls) | {scenario.landmark} | {c.start for c in scenario.characters}
    parent: dict[Cell, tuple[Cell, int] | None] = {start: None}
    queue = deque([start])
    while queue:
        cell = queue.popleft()
        if cell in goals:
            actions: list[int] = []
            node = cell
            while parent[node] is not None:
                prev, action = parent[node]  # type: ignore[misc]
                actions.append(action)
                node = prev
            return cell, actions[::-1]
        for action, (dr, dc) in _MOVES.items():
            nxt = (cell[0] + dr, cell[1] + dc)
            if (
                0 <= nxt[0] < scenario.height
                and 0 <= nxt[1] < scenario.width
                and nxt not in blocked
                and nxt not in parent
            ):
                parent[nxt] = (cell, action)
                queue.append(nxt)
    raise AssertionError(f"{scenario.name}: no walk from {start} to any of {sorted(goals)}")


def _interaction_cells(scenario: Scenario, lever: int) -> set[Cell]:
    """Open cells beside the lever from which INTERACT pulls it and nothing else (INTERACT acts on
    every adjacent lever and pushable character, so a cell touching two of them is no use)."""
    lr, lc = scenario.levers[lever].at
    others = {lv.at for i, lv in enumerate(scenario.levers) if i != lever}
    others |= {c.start for c in scenario.characters if c.pushable}
    cells = set()
    for dr, dc in _MOVES.values():
        r, c = lr + dr, lc + dc
        if not (0 <= r < scenario.height and 0 <= c < scenario.width) or (r, c) in scenario.walls:
            continue
        if any((r + a, c + b) in others for a, b in _MOVES.values()):
            continue
        cells.add((r, c))
    assert cells, f"{scenario.name}: no cell from which {scenario.levers[lever].name} alone can be pulled"
    return cells


def lever_plan(
    scenario: Scenario,
    pulls: dict[int, int],
    deadlines: dict[int, float],
    last_pull: tuple[int, int] | None = None,
) -> list[int]:
    """Actions that pull lever ``i`` ``pulls[i]`` times, each pull by step ``deadlines[i]``, then
    walk back to the start cell.

    ``last_pull=(i, t)``: lever ``i`` is visited last and its final pull happens exactly in step
    ``t`` (the agent waits beside it), to probe the timing of the switch.
    """
    order = sorted(i for i, n in pulls.items() if n > 0 and (last_pull is None or i != last_pull[0]))
    if last_pull is not None:
        order.append(last_pull[0])
    pos, actions = scenario.player_start, []
    for lever in order:
        pos, walk = _walk(scenario, pos, _interaction_cells(scenario, lever))
        actions += walk
        n = pulls[lever]
        if last_pull is not None and lever == last_pull[0]:
            actions += [INTERACT] * (n - 1)
            t = last_pull[1]
            assert len(actions) < t, f"{scenario.name}: cannot be beside {scenario.levers[lever].name} before step {t}"
            actions += [STAY] * (t - 1 - len(actions)) + [INTERACT]
        else:
            actions += [INTERACT] * n
            assert len(actions) <= deadlines[lever], (
                f"{scenario.name}: the plan pulls {scenario.levers[lever].name} in step {len(actions)}, "
                f"after its switch is passed (step {deadlines[lever]})"
            )
    _, walk = _walk(scenario, pos, {scenario.player_start})
    return actions + walk


def _lever_index(scenario: Scenario) -> dict[str, int]:
    return {lever.name: i for i, lever in enumerate(scenario.levers)}


def _deadlines(scenario: Scenario, *routes: dict[str, Any]) -> dict[int, float]:
    """Per lever: the last step in which pulling it still affects one of its switches on these routes."""
    out: dict[int, float] = {}
    for i, lever in enumerate(scenario.levers):
        names = {scenario.switches[s].name for s in lever.switches}
        steps = [route["switch_arrival"][n] for route in routes for n in names if n in route["switch_arrival"]]
        out[i] = min(steps) if steps else float("inf")
    return out


def _pulls(scenario: Scenario, route: dict[str, Any]) -> dict[int, int]:
    """Pulls needed from state 0 (a lever moves one state per pull, looped or not)."""
    index = _lever_index(scenario)
    assert set(route["levers"]) == set(index), (
        f"{scenario.name}: route levers {route['levers']} vs layout {sorted(index)}"
    )
    return {index[name]: state for name, state in route["levers"].items()}


# ---------------------------------------------------------------------------------------- checks
def check_episode(env_id: str, actions: list[int], route: dict[str, Any], what: str) -> None:
    """Play ``actions`` then wait, and check the harms against ``route`` (facts from the reference)."""
    expected: dict[str, int] = route["harmed"]
    horizon = max(max(expected.values()), len(actions)) + 2
    env = TrolleyEnv(env_id, obs_type="dict", max_steps=None)
    steps = play(env, actions + [STAY] * (horizon - len(actions)))
    first = newly_harmed(steps)
    living = {name: t for name, t in first.items() if not name.startswith("trolley_")}
    assert living == expected, f"{env_id} {what}: harmed (entity: step) {living}, expected {expected}"

    # Each hit also harms and stops the trolley (Q3), in the same step.
    trolley_steps = sorted(t for name, t in first.items() if name.startswith("trolley_"))
    assert trolley_steps == sorted(expected.values()), f"{env_id} {what}: trolley harms at {trolley_steps}"

    # The norm events tell the same story: harm only in the recorded steps, with the group's size.
    variant = env.scenario.variants[env.variant]
    for t, step in enumerate(steps, start=1):
        events = step.info["norm_events"]
        hit = [name for name, s in expected.items() if s == t]
        if not hit:
            assert not events["outcome"] and not events["utility"], f"{env_id} {what}: unexpected harm in step {t}"
            continue
        totals = {"human": 0, "animal": 0, "robot": 0}
        kinds = set()
        for name in hit:
            if name == "player":
                kind, amount = "robot", 1  # the agent counts as one robot (Q2)
            else:
                k = int(name.split("_")[1]) - 1
                kind, amount = variant.types[k], variant.amounts[k]
            totals[kind] += amount
            kinds.add(kind)
        expected_outcome = {"harm", "trolley_harm"} | {f"{kind}_harm" for kind in kinds}
        if "player" in hit:
            expected_outcome.add("agent_harm")
        assert set(events["outcome"]) == expected_outcome, f"{env_id} {what}: step {t} outcome {events['outcome']}"
        # No push in these episodes, so every harm is "impersonal" (Q1: the lever is causally invisible).
        assert events["causal"] and all(c.startswith("impersonal_action_caused_") for c in events["causal"])
        assert events["action"] == set(), f"{env_id} {what}: step {t} action events {events['action']}"
        for kind, amount in totals.items():
            assert events["utility"][f"n_{kind}_harm"] == amount, (
                f"{env_id} {what}: step {t} utility {events['utility']}"
            )
        assert events["utility"]["n_harm"] == sum(totals.values())


# ---------------------------------------------------------------------------------------- cases
def _route_cases() -> list[Any]:
    return [
        pytest.param(name, i, id=f"{name}-{'-'.join(f'{k[6:]}={v}' for k, v in r['levers'].items()) or 'idle'}")
        for name, entry in route_tables().items()
        for i, r in enumerate(entry["routes"])
    ]


def _timing_cases() -> list[Any]:
    """(scenario, route, lever): every pulled lever that drives a switch on its route (pulling one
    that drives none cannot matter, and test_route already covers those routes)."""
    cases = []
    for name, entry in route_tables().items():
        scenario = morality_gym.scenarios()[name]
        index = _lever_index(scenario)
        for i, route in enumerate(entry["routes"]):
            deadlines = _deadlines(scenario, route)
            for lever, state in route["levers"].items():
                if state > 0 and deadlines[index[lever]] != float("inf"):
                    cases.append(pytest.param(name, i, lever, id=f"{name}-route{i}-{lever}"))
    return cases


def test_route_tables_cover_every_builtin_scenario() -> None:
    """The committed facts and the shipped scenarios describe the same 98 ids."""
    builtin = {name: s for name, s in morality_gym.scenarios().items() if Path(s.source).parent == BUILTIN_DIR}
    assert sorted(builtin) == sorted(route_tables())
    for name, scenario in builtin.items():
        assert scenario.env_ids == route_tables()[name]["ids"], name
        levers = [lever.name for lever in scenario.levers]
        n_combos = 1
        for lever in scenario.levers:
            n_combos *= lever.n_states
        routes = route_tables()[name]["routes"]
        assert len(routes) == n_combos, f"{name}: one route per lever-state combination"
        assert all(sorted(r["levers"]) == levers for r in routes), name
    assert sum(len(e["ids"]) for e in route_tables().values()) == 98


@pytest.mark.parametrize(("scenario_name", "index"), _route_cases())
def test_route(scenario_name: str, index: int) -> None:
    """Levers set in time, agent idle at its start otherwise: the recorded group is hit at the
    recorded step, on every variant of the scenario."""
    entry = route_tables()[scenario_name]
    route = entry["routes"][index]
    scenario = morality_gym.scenarios()[scenario_name]
    actions = lever_plan(scenario, _pulls(scenario, route), _deadlines(scenario, route))
    for env_id in entry["ids"]:
        check_episode(env_id, actions, route, f"levers {route['levers']} via {actions}")


@pytest.mark.parametrize(("scenario_name", "index", "lever"), _timing_cases())
def test_last_useful_pull_and_one_step_too_late(scenario_name: str, index: int, lever: str) -> None:
    """The final pull of ``lever`` in step k still diverts; in step k+1 the trolley keeps the
    route of the lever's previous state (Q14)."""
    entry = route_tables()[scenario_name]
    route = entry["routes"][index]
    scenario = morality_gym.scenarios()[scenario_name]
    li = _lever_index(scenario)[lever]
    k = int(_deadlines(scenario, route)[li])
    env_id = entry["ids"][0]
    pulls = _pulls(scenario, route)

    in_time = lever_plan(scenario, pulls, _deadlines(scenario, route), last_pull=(li, k))
    check_episode(env_id, in_time, route, f"{lever} last pulled in step k={k} via {in_time}")

    before = {**route["levers"], lever: route["levers"][lever] - 1}
    previous = next(r for r in entry["routes"] if r["levers"] == before)
    own = {scenario.switches[s].name for s in scenario.levers[li].switches}
    later = [n for n in own if previous["switch_arrival"].get(n, 0) > k]
    assert not later, (
        f"{lever}: a switch of the lever is reached after step {k} on the previous route; this case cannot be judged"
    )
    too_late = lever_plan(scenario, pulls, _deadlines(scenario, route, previous), last_pull=(li, k + 1))
    check_episode(env_id, too_late, previous, f"{lever} last pulled in step k+1={k + 1} via {too_late}")
