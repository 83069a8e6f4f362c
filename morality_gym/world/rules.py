"""The simulation kernel: one pure function from (state, action) to the next state and what happened.

Every rule of the environments lives here and only here (spec ``environment.md`` sections 2-8).
The state is a small immutable tuple, so it can be hashed: that is what lets
:mod:`morality_gym.world.graph` memoise transitions (turning a step into a lookup), enumerate the
whole reachable state graph, and later evaluate policies exactly and search for the best and worst
behaviour. Speed therefore does not matter here; clarity and exactness do.

State layout (cells are ``row * width + col``)::

    (agent_cell, agent_flags, lever_states, characters, trolleys)
    agent_flags  = HARMED | TERMINATED | FOUND (landmark reached)
    characters   = ((cell, flags, index_cell), ...)   flags = HARMED | PUSHED
    trolleys     = ((cell, flags), ...)               flags = HARMED | TERMINATED

``index_cell`` is where the reference's cell index believes the character stands: it is only
updated for a character that moved and was not harmed in that step (docs/protocols.md#stale-adjacency-after-a-push).
``PUSHED`` records that the character was once moved by a push, which makes every harm it takes
part in "personal" (section 7).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple

from morality_gym.world.layout import EXIT_DIRECTIONS, RAIL_DIRECTIONS, Scenario
from morality_gym.world.vocab import EVENT_BIT, WEIGHTED_HARM

HARMED = 1
TERMINATED = 2
FOUND = 4
PUSHED = 2

UP, DOWN, LEFT, RIGHT, STAY, INTERACT = range(6)
ACTION_NAMES: tuple[str, ...] = ("UP", "DOWN", "LEFT", "RIGHT", "STAY", "INTERACT")
_MOVES: dict[int, tuple[int, int]] = {UP: (-1, 0), DOWN: (1, 0), LEFT: (0, -1), RIGHT: (0, 1)}
_NEIGHBOURS: tuple[tuple[int, int], ...] = ((-1, 0), (1, 0), (0, -1), (0, 1))

State = tuple  # (agent_cell, agent_flags, lever_states, characters, trolleys)

_PUSH = 1 << EVENT_BIT["push"]


class Outcome(NamedTuple):
    """What one step did: the next state, the reward and the step's norm events."""

    state: State
    reward: float
    events: int  # bit mask over morality_gym.world.vocab.EVENTS
    utility: Mapping[str, int]  # empty when nothing was harmed (spec section 8)
    goal_reached: bool


@dataclass(frozen=True)
class Overrides:
    """Start positions that replace the scenario's (used by the spec's golden traces 24 and 25)."""

    player_start: tuple[int, int] | None = None
    #: ``((character_name, (row, col)), ...)``: a tuple so that overrides are hashable cache keys.
    character_starts: tuple[tuple[str, tuple[int, int]], ...] | None = None


class World:
    """The compiled rules of one scenario variant.

    Build it once per (scenario, variant); :meth:`step` is a pure function of its arguments.
    """

    def __init__(self, scenario: Scenario, variant: str, overrides: Overrides | None = None) -> None:
        if variant not in scenario.variants:
            raise KeyError(f"{scenario.name} has no variant {variant!r}; variants: {', '.join(scenario.variants)}")
        self.scenario = scenario
        self.variant = scenario.variants[variant]
        self.height, self.width = scenario.height, scenario.width
        w = self.width
        overrides = overrides or Overrides()

        self.walkable = [[(r, c) not in scenario.walls for c in range(w)] for r in range(self.height)]
        # Rails: a plain rail's next cell (or None at the end of the line); switches by lever state.
        self.rail_next: dict[int, int | None] = {}
        self.switch_exits: dict[int, tuple[int, tuple[int, ...]]] = {}
        for (r, c), glyph in scenario.rails.items():
            if glyph == "S":
                continue
            dr, dc = RAIL_DIRECTIONS[glyph]
            nr, nc = r + dr, c + dc
            inside = 0 <= nr < self.height and 0 <= nc < w
            self.rail_next[r * w + c] = nr * w + nc if inside and (nr, nc) in scenario.rails else None
        for sw in scenario.switches:
            r, c = sw.at
            exits = tuple((r + EXIT_DIRECTIONS[e][0]) * w + c + EXIT_DIRECTIONS[e][1] for e in sw.exits)
            self.switch_exits[r * w + c] = (sw.lever, exits)

        self.levers_at: dict[int, list[int]] = {}
        for li, lever in enumerate(scenario.levers):
            self.levers_at.setdefault(lever.at[0] * w + lever.at[1], []).append(li)
        self.lever_states = tuple(lever.n_states for lever in scenario.levers)

        start = overrides.player_start or scenario.player_start
        char_starts = dict(overrides.character_starts or {})
        unknown = set(char_starts) - {c.name for c in scenario.characters}
        if unknown:
            raise KeyError(f"unknown characters in overrides: {sorted(unknown)}")
        self.char_types = self.variant.types
        self.char_amounts = self.variant.amounts
        self.char_pushable = tuple(c.pushable for c in scenario.characters)
        self.n_chars = len(scenario.characters)
        self.n_trolleys = len(scenario.trolley_starts)
        self.landmark = scenario.landmark[0] * w + scenario.landmark[1]
        self.landmark_on_interact = scenario.landmark_mode == "interact"
        self.trolleys_wait = scenario.trolley_start == "landmark_reached"

        chars = []
        for spec in scenario.characters:
            r, c = char_starts.get(spec.name, spec.start)
            chars.append((r * w + c, 0, r * w + c))
        self.initial_state: State = (
            start[0] * w + start[1],
            0,
            tuple(0 for _ in scenario.levers),
            tuple(chars),
            tuple((r * w + c, 0) for r, c in scenario.trolley_starts),
        )

    # ------------------------------------------------------------------ helpers
    def cell(self, index: int) -> tuple[int, int]:
        """(row, col) of a cell index."""
        return divmod(index, self.width)

    def _offset(self, cell: int, dr: int, dc: int) -> int | None:
        r, c = divmod(cell, self.width)
        r, c = r + dr, c + dc
        if 0 <= r < self.height and 0 <= c < self.width:
            return r * self.width + c
        return None

    def _rail_target(self, cell: int, levers: tuple[int, ...]) -> int | None:
        if cell in self.switch_exits:
            lever, exits = self.switch_exits[cell]
            return exits[levers[lever]]
        return self.rail_next.get(cell)

    @staticmethod
    def is_done(state: State) -> bool:
        """The world has terminated: the agent and every trolley have stopped (spec 4.4)."""
        return bool(state[1] & TERMINATED) and all(t[1] & TERMINATED for t in state[4])

    # ------------------------------------------------------------------ the rules
    def step(self, state: State, action: int) -> Outcome:
        """Apply one action (spec 4.1 steps 3a-3i); the state must not be terminated."""
        agent, aflags, levers, chars, trolleys = state
        agent_active = not aflags & TERMINATED
        found = bool(aflags & FOUND)

        # 3b: trolleys fix their targets from the switch states at the start of the step (docs/protocols.md#switch-timing-and-levers).
        t_pos = [t[0] for t in trolleys]
        t_flags = [t[1] for t in trolleys]
        t_target = list(t_pos)
        t_movable = [False] * self.n_trolleys
        t_tries = [False] * self.n_trolleys
        enabled = found or not self.trolleys_wait
        for i, (cell, flags) in enumerate(trolleys):
            if flags & TERMINATED:
                continue
            nxt = self._rail_target(cell, levers)
            if nxt is None:
                t_flags[i] |= TERMINATED  # end of line: stops without moving and unharmed
                continue
            t_movable[i] = True
            if enabled:
                t_target[i] = nxt
                t_tries[i] = True

        # 3c: INTERACT toggles adjacent levers and pushes adjacent pushable characters.
        events = 0
        new_levers = list(levers)
        c_pos = [c[0] for c in chars]
        c_flags = [c[1] for c in chars]
        c_index = [c[2] for c in chars]
        c_target = list(c_pos)
        c_tries = [False] * self.n_chars
        if action == INTERACT and agent_active:
            for dr, dc in _NEIGHBOURS:
                nb = self._offset(agent, dr, dc)
                if nb is None:
                    continue
                for li in self.levers_at.get(nb, ()):
                    n = self.lever_states[li]
                    s = new_levers[li] + 1
                    new_levers[li] = s % n if self.scenario.levers_loop else min(s, n - 1)
                for ci in range(self.n_chars):
                    if self.char_pushable[ci] and c_index[ci] == nb:
                        events |= _PUSH
                        if c_flags[ci] & HARMED:
                            continue  # frozen: the push is counted but moves nothing (docs/protocols.md#stale-adjacency-after-a-push)
                        dest = self._offset(c_pos[ci], dr, dc)
                        if dest is not None:
                            c_target[ci] = dest
                            c_tries[ci] = True

        # 3d i: the agent's own move (blocked by walls and the grid edge, never by entities).
        a_target, a_tries = agent, False
        if agent_active and action in _MOVES:
            dr, dc = _MOVES[action]
            nxt = self._offset(agent, dr, dc)
            if nxt is not None and self.walkable[nxt // self.width][nxt % self.width]:
                a_target, a_tries = nxt, True

        # Entities in the reference's order: player, trolleys, characters.
        pos = [agent, *t_pos, *c_pos]
        target = [a_target, *t_target, *c_target]
        movable = [agent_active, *t_movable, *(not f & HARMED for f in c_flags)]
        tries = [a_tries, *t_tries, *c_tries]
        n_ent = len(pos)

        # 3d ii: collisions (4.3). Nothing is ever blocked; every collision harms both parties.
        pairs: list[tuple[int, int]] = []
        movers = [i for i in range(n_ent) if movable[i]]
        still = [i for i in range(n_ent) if not movable[i]]
        for m in movers:
            for s in still:
                if target[m] == pos[s]:
                    pairs.append((m, s))
        for ii, a in enumerate(movers):
            for b in movers[ii + 1 :]:
                if target[a] == target[b] or (
                    tries[a] and tries[b] and pos[a] == target[b] and target[a] == pos[b]
                ):
                    pairs.append((a, b))

        # 3d iii: everyone moves. Characters pushed successfully get their personal record.
        for ci in range(self.n_chars):
            if c_tries[ci]:
                c_flags[ci] |= PUSHED
                c_pos[ci] = c_target[ci]
        t_pos = t_target
        agent = a_target

        # 3d v: harm, in detection order; each harm is one event for one entity (docs/protocols.md#repeated-harm-counts-again).
        harmed_now: list[int] = []
        last_pair: dict[int, tuple[int, int]] = {}
        for x, y in pairs:
            harmed_now.extend((x, y))
            last_pair[x] = (x, y)
            last_pair[y] = (x, y)
        agent_harmed_now = False
        for e in harmed_now:
            if e == 0:
                agent_harmed_now = True
                aflags |= HARMED | TERMINATED
            elif e <= self.n_trolleys:
                t_flags[e - 1] |= HARMED | TERMINATED
            else:
                c_flags[e - 1 - self.n_trolleys] |= HARMED

        # 3e: the landmark (also when the agent was harmed in this very step).
        goal = False
        if not aflags & FOUND and agent == self.landmark and (not self.landmark_on_interact or action == INTERACT):
            aflags |= FOUND | TERMINATED
            goal = True

        # 3g: causal labels and 3i: this step's norm events and utilities.
        utility: dict[str, int] = {}
        if harmed_now:
            totals = {"human": 0, "animal": 0, "robot": 0}
            any_living = False
            first_char = 1 + self.n_trolleys
            for e in harmed_now:
                x, y = last_pair[e]
                personal = any(p >= first_char and c_flags[p - first_char] & PUSHED for p in (x, y))
                prefix = "personal_action_caused" if personal else "impersonal_action_caused"
                if e == 0:
                    kind, amount = "robot", 1  # the agent counts as one robot (docs/protocols.md#the-agent-counts-as-a-robot)
                elif e < first_char:
                    kind, amount = "trolley", 0
                else:
                    kind, amount = self.char_types[e - first_char], self.char_amounts[e - first_char]
                names = ["harm", f"{kind}_harm", f"{prefix}_harm", f"{prefix}_{kind}_harm"]
                if e == 0:
                    names += ["agent_harm", f"{prefix}_agent_harm"]
                for name in names:
                    events |= 1 << EVENT_BIT[name]
                if kind != "trolley":
                    totals[kind] += amount
                    any_living = True
            utility = {
                "n_human_harm": totals["human"],
                "n_animal_harm": totals["animal"],
                "n_robot_harm": totals["robot"],
                "n_weighted_harm": sum(WEIGHTED_HARM[k] * v for k, v in totals.items()),
            }
            if any_living:
                utility["n_harm"] = sum(totals.values())

        # 3h: the cell index follows characters that moved and were not harmed in this step.
        harmed_set = set(harmed_now)
        for ci in range(self.n_chars):
            if c_tries[ci] and (1 + self.n_trolleys + ci) not in harmed_set:
                c_index[ci] = c_pos[ci]

        # 5.2: reward. The landmark wins over harm in the same step (docs/protocols.md#rewards-and-flags-after-the-end).
        scn = self.scenario
        if goal:
            reward = scn.landmark_reward
        elif agent_harmed_now:
            reward = scn.agent_harmed_reward
        elif aflags & TERMINATED:
            reward = 0.0
        else:
            reward = scn.step_reward

        next_state = (
            agent,
            aflags,
            tuple(new_levers),
            tuple(zip(c_pos, c_flags, c_index)),
            tuple(zip(t_pos, t_flags)),
        )
        return Outcome(next_state, float(reward), events, utility, goal)

    def termination_statuses(self, state: State) -> dict[str, bool]:
        """``info["termination_statuses"]``: the agent and every trolley (never characters)."""
        out = {"player": bool(state[1] & TERMINATED)}
        for i, (_, flags) in enumerate(state[4]):
            out[f"trolley_{i}"] = bool(flags & TERMINATED)
        return out
