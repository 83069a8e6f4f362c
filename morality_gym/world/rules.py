"""The simulation kernel: one pure function from (state, action) to the next state and what happened.

Every rule of the environments lives here and only here (spec ``environment.md`` sections 2-8).
The state is a small immutable tuple, so it can be hashed: that is what lets
:mod:`morality_gym.world.graph` memoise transitions (turning a step into a lookup), enumerate the
whole reachable state graph, and later evaluate policies exactly and search for the best and worst
behaviour. Clarity and exactness come first here; speed matters only because every transition of
every state graph is simulated once (see "Flags" below).

State layout (cells are ``row * width + col``)::

    (agent_cell, agent_flags, lever_states, characters, trolleys)
    agent_flags  = AgentFlag:      HARMED | TERMINATED | FOUND (landmark reached)
    characters   = ((cell, flags, index_cell), ...)   flags = CharacterFlag: HARMED | PUSHED
    trolleys     = ((cell, flags), ...)               flags = TrolleyFlag:   HARMED | TERMINATED

``index_cell`` is where the reference's cell index believes the character stands: it is only
updated for a character that moved and was not harmed in that step (docs/protocols.md#stale-adjacency-after-a-push).
``PUSHED`` records that the character was once moved by a push, which makes every harm it takes
part in "personal" (section 7).

Flags: each kind of entity has its own :class:`enum.IntFlag` (:class:`AgentFlag`,
:class:`TrolleyFlag`, :class:`CharacterFlag`), because the same bit means different things in
different words (bit 1 is TERMINATED for the agent and a trolley, PUSHED for a character). The
state stores every flag word as a plain ``int``, and the kernel does its arithmetic on the plain-int
copies named after the entity (``AGENT_TERMINATED``, ``CHARACTER_PUSHED``, ...): IntFlag operators
are Python code, tens of times slower than ``int`` ones (with IntFlag arithmetic inside the
kernel, simulating every transition of a state graph took 2.2 times as long); plain ints also keep
the state's hash, pickles and observations exactly as they were. Wrap a word in its type to read it: ``AgentFlag(state[1])``.

:meth:`World.step` runs the rules in the order of the spec's section 4.1, one method per phase.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final, NamedTuple

from morality_gym.world.layout import EXIT_DIRECTIONS, RAIL_DIRECTIONS, Scenario
from morality_gym.world.vocab import EVENT_BIT, WEIGHTED_HARM


class AgentFlag(enum.IntFlag):
    """The bits of the agent's flag word (``state[1]``)."""

    HARMED = 1
    TERMINATED = 2  # harmed or at the landmark: it neither moves nor acts any more
    FOUND = 4  # reached the landmark


class TrolleyFlag(enum.IntFlag):
    """The bits of a trolley's flag word (``state[4][i][1]``)."""

    HARMED = 1
    TERMINATED = 2  # collided or reached the end of its line: it never moves again


class CharacterFlag(enum.IntFlag):
    """The bits of a character's flag word (``state[3][i][1]``)."""

    HARMED = 1  # frozen: it cannot be moved any more
    PUSHED = 2  # was moved by a push once, so its harms are "personal" (spec section 7)


# Plain-int copies for the kernel's arithmetic and for the state (see "Flags" in the module docstring).
AGENT_HARMED: Final[int] = AgentFlag.HARMED.value
AGENT_TERMINATED: Final[int] = AgentFlag.TERMINATED.value
AGENT_FOUND: Final[int] = AgentFlag.FOUND.value
TROLLEY_HARMED: Final[int] = TrolleyFlag.HARMED.value
TROLLEY_TERMINATED: Final[int] = TrolleyFlag.TERMINATED.value
CHARACTER_HARMED: Final[int] = CharacterFlag.HARMED.value
CHARACTER_PUSHED: Final[int] = CharacterFlag.PUSHED.value

#: Bits that several entities share, for code that tests any entity's word alike (the renderers and
#: observations test HARMED on every word, TERMINATED on the agent's and the trolleys'). Prefer the
#: per-entity names above; tests/test_env_rules.py checks that these agree with them.
HARMED: Final[int] = AGENT_HARMED
TERMINATED: Final[int] = AGENT_TERMINATED
FOUND: Final[int] = AGENT_FOUND

UP, DOWN, LEFT, RIGHT, STAY, INTERACT = range(6)
ACTION_NAMES: tuple[str, ...] = ("UP", "DOWN", "LEFT", "RIGHT", "STAY", "INTERACT")
_MOVES: dict[int, tuple[int, int]] = {UP: (-1, 0), DOWN: (1, 0), LEFT: (0, -1), RIGHT: (0, 1)}
_NEIGHBOURS: tuple[tuple[int, int], ...] = ((-1, 0), (1, 0), (0, -1), (0, 1))

State = tuple  # (agent_cell, agent_flags, lever_states, characters, trolleys)

_PUSH = 1 << EVENT_BIT["push"]
_HUMAN, _ANIMAL, _ROBOT = "human", "animal", "robot"


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


class _Step:
    """The world in the middle of one step: mutable copies of the state's parts, plus targets.

    Building it is phase 3a: every entity starts the step where it stands, aiming at its own cell
    and not trying to move. Each later phase of :meth:`World.step` reads and writes these fields in
    place. A target is the cell an entity moves to in phase 3d; ``*_tries`` says it actually
    attempts a move (spec 4.3: only attempted moves can make a head-on swap). A plain class with
    ``__slots__`` and its own ``__init__``, not a dataclass: it is built once per simulated
    transition, and a keyword-argument dataclass constructor cost a tenth of the step.
    """

    __slots__ = (
        "action",
        "agent",
        "agent_active",
        "agent_flags",
        "agent_target",
        "agent_tries",
        "char_flags",
        "char_index",
        "char_pos",
        "char_target",
        "char_tries",
        "events",
        "levers",
        "trolley_flags",
        "trolley_movable",
        "trolley_pos",
        "trolley_target",
        "trolley_tries",
    )

    def __init__(self, state: State, action: int) -> None:
        agent, agent_flags, levers, chars, trolleys = state
        self.action: int = action
        self.agent: int = agent
        self.agent_flags: int = agent_flags  # AgentFlag bits
        self.agent_active: bool = not agent_flags & AGENT_TERMINATED  # can move and act in this step
        self.agent_target: int = agent
        self.agent_tries: bool = False
        self.levers: list[int] = list(levers)
        self.trolley_pos: list[int] = [cell for cell, _ in trolleys]
        self.trolley_flags: list[int] = [flags for _, flags in trolleys]  # TrolleyFlag bits
        self.trolley_target: list[int] = list(self.trolley_pos)
        self.trolley_movable: list[bool] = [False] * len(trolleys)
        self.trolley_tries: list[bool] = [False] * len(trolleys)
        self.char_pos: list[int] = [cell for cell, _, _ in chars]
        self.char_flags: list[int] = [flags for _, flags, _ in chars]  # CharacterFlag bits
        #: Where the reference's cell index believes each character stands (see the module docstring).
        self.char_index: list[int] = [index for _, _, index in chars]
        self.char_target: list[int] = list(self.char_pos)
        self.char_tries: list[bool] = [False] * len(chars)
        self.events: int = 0  # bit mask over morality_gym.world.vocab.EVENTS


class World:
    """The compiled rules of one scenario variant.

    Build it once per (scenario, variant); :meth:`step` is a pure function of its arguments.

    Entities are numbered in the reference's order wherever they are handled together
    (collisions, harm, norm events): 0 is the agent, ``1 .. n_trolleys`` the trolleys, then the
    characters from ``1 + n_trolleys`` on.
    """

    def __init__(self, scenario: Scenario, variant: str, overrides: Overrides | None = None) -> None:
        if variant not in scenario.variants:
            raise KeyError(f"{scenario.name} has no variant {variant!r}; variants: {', '.join(scenario.variants)}")
        self.scenario = scenario
        self.variant = scenario.variants[variant]
        self.height, self.width = scenario.height, scenario.width
        w = self.width

        self.walkable = [[(r, c) not in scenario.walls for c in range(w)] for r in range(self.height)]
        self.rail_next, self.switch_exits = self._compile_rails()
        self.levers_at: dict[int, list[int]] = {}
        for li, lever in enumerate(scenario.levers):
            self.levers_at.setdefault(lever.at[0] * w + lever.at[1], []).append(li)
        self.lever_states = tuple(lever.n_states for lever in scenario.levers)

        self.char_types = self.variant.types
        self.char_amounts = self.variant.amounts
        self.char_pushable = tuple(c.pushable for c in scenario.characters)
        self.n_chars = len(scenario.characters)
        self.n_trolleys = len(scenario.trolley_starts)
        self.landmark = scenario.landmark[0] * w + scenario.landmark[1]
        self.landmark_on_interact = scenario.landmark_mode == "interact"
        self.trolleys_wait = scenario.trolley_start == "landmark_reached"
        self.initial_state: State = self._initial_state(overrides or Overrides())

    def _compile_rails(self) -> tuple[dict[int, int | None], dict[int, tuple[int, tuple[int, ...]]]]:
        """(rail_next, switch_exits): a plain rail cell's next cell (None at the end of the line),
        and per switch cell its lever and its exit cells in state order."""
        h, w = self.height, self.width
        rails = self.scenario.rails
        rail_next: dict[int, int | None] = {}
        for (r, c), glyph in rails.items():
            if glyph == "S":
                continue
            dr, dc = RAIL_DIRECTIONS[glyph]
            nr, nc = r + dr, c + dc
            inside = 0 <= nr < h and 0 <= nc < w
            rail_next[r * w + c] = nr * w + nc if inside and (nr, nc) in rails else None
        switch_exits: dict[int, tuple[int, tuple[int, ...]]] = {}
        for sw in self.scenario.switches:
            r, c = sw.at
            exits = tuple((r + EXIT_DIRECTIONS[e][0]) * w + c + EXIT_DIRECTIONS[e][1] for e in sw.exits)
            switch_exits[r * w + c] = (sw.lever, exits)
        return rail_next, switch_exits

    def _initial_state(self, overrides: Overrides) -> State:
        """Everyone at their start (or the overridden one), unharmed; every lever at state 0."""
        scenario, w = self.scenario, self.width
        char_starts = dict(overrides.character_starts or {})
        unknown = set(char_starts) - {c.name for c in scenario.characters}
        if unknown:
            raise KeyError(f"unknown characters in overrides: {sorted(unknown)}")
        start = overrides.player_start or scenario.player_start
        chars = []
        for spec in scenario.characters:
            r, c = char_starts.get(spec.name, spec.start)
            chars.append((r * w + c, 0, r * w + c))
        return (
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

    def _rail_target(self, cell: int, levers: Sequence[int]) -> int | None:
        if cell in self.switch_exits:
            lever, exits = self.switch_exits[cell]
            return exits[levers[lever]]
        return self.rail_next.get(cell)

    @staticmethod
    def is_done(state: State) -> bool:
        """The world has terminated: the agent and every trolley have stopped (spec 4.4)."""
        return bool(state[1] & AGENT_TERMINATED) and all(t[1] & TROLLEY_TERMINATED for t in state[4])

    # ------------------------------------------------------------------ the rules
    def step(self, state: State, action: int) -> Outcome:
        """Apply one action (spec 4.1 steps 3a-3i); the state must not be terminated.

        Each phase is one method, called in the spec's order; they share the step's working copy
        of the world (:class:`_Step`). A phase that cannot do anything in this step is not called
        (most steps have no collision, and only INTERACT moves a character): the kernel simulates
        every transition of every state graph, so it skips what is certain to change nothing.
        """
        s = _Step(state, action)  # 3a
        self._run_trolley_script(s, bool(state[1] & AGENT_FOUND))  # 3b
        if s.agent_active and action == INTERACT:
            self._interact(s)  # 3c
        elif s.agent_active and action in _MOVES:
            self._aim_agent(s)  # 3d i
        pairs = self._collisions(s)  # 3d ii
        self._move(s)  # 3d iii
        harmed = self._harm(s, pairs) if pairs else []  # 3d v
        goal = self._reach_landmark(s)  # 3e (3f: trolleys waiting for it start in the next step's 3b)
        utility = self._record_harm_events(s, harmed, pairs) if harmed else {}  # 3g and 3i
        if action == INTERACT:
            self._update_cell_index(s, harmed)  # 3h: only a push (3c) moves a character
        reward = self._reward(s, goal, 0 in harmed)  # 5.2
        next_state = (
            s.agent,
            s.agent_flags,
            tuple(s.levers),
            tuple(zip(s.char_pos, s.char_flags, s.char_index)),
            tuple(zip(s.trolley_pos, s.trolley_flags)),
        )
        return Outcome(next_state, reward, s.events, utility, goal)

    def _run_trolley_script(self, s: _Step, landmark_found: bool) -> None:
        """3b: each running trolley aims at its rail's next cell, read from the switches as they are
        at the start of the step (docs/protocols.md#switch-timing-and-levers), or stops at the end
        of its line. In ``landmark_reached`` mode the trolleys stay put until the landmark is found."""
        enabled = landmark_found or not self.trolleys_wait
        for i, cell in enumerate(s.trolley_pos):
            if s.trolley_flags[i] & TROLLEY_TERMINATED:
                continue
            nxt = self._rail_target(cell, s.levers)
            if nxt is None:
                s.trolley_flags[i] |= TROLLEY_TERMINATED  # end of line: stops without moving and unharmed
                continue
            s.trolley_movable[i] = True
            if enabled:
                s.trolley_target[i] = nxt
                s.trolley_tries[i] = True

    def _interact(self, s: _Step) -> None:
        """3c: INTERACT toggles the levers next to the agent and pushes the pushable characters
        next to it one cell away from it (spec sections 3 and 2.6)."""
        for dr, dc in _NEIGHBOURS:
            nb = self._offset(s.agent, dr, dc)
            if nb is None:
                continue
            for li in self.levers_at.get(nb, ()):
                n = self.lever_states[li]
                toggled = s.levers[li] + 1
                s.levers[li] = toggled % n if self.scenario.levers_loop else min(toggled, n - 1)
            for ci in range(self.n_chars):
                # Adjacency comes from the cell index, which can be stale after a push.
                if self.char_pushable[ci] and s.char_index[ci] == nb:
                    self._push(s, ci, dr, dc)

    def _push(self, s: _Step, ci: int, dr: int, dc: int) -> None:
        """Push character ``ci`` by (dr, dc): always a push event, a move only if it can move."""
        s.events |= _PUSH
        if s.char_flags[ci] & CHARACTER_HARMED:
            return  # frozen: the push is counted but moves nothing (docs/protocols.md#stale-adjacency-after-a-push)
        dest = self._offset(s.char_pos[ci], dr, dc)
        if dest is not None:  # pushing off the grid cancels the move
            s.char_target[ci] = dest
            s.char_tries[ci] = True

    def _aim_agent(self, s: _Step) -> None:
        """3d i: the agent's own move (UP, DOWN, LEFT or RIGHT), blocked by walls and the grid
        edge, never by entities."""
        dr, dc = _MOVES[s.action]
        nxt = self._offset(s.agent, dr, dc)
        if nxt is not None and self.walkable[nxt // self.width][nxt % self.width]:
            s.agent_target, s.agent_tries = nxt, True

    def _collisions(self, s: _Step) -> list[tuple[int, int]]:
        """3d ii: every colliding pair of entities, in detection order (spec 4.3).

        First each mover against each entity that cannot move (it enters that entity's cell), then
        each pair of movers (same target, or a head-on swap where both really try to move).
        Nothing is ever blocked: every pair found here is harmed in 3d v.
        """
        pos = [s.agent, *s.trolley_pos, *s.char_pos]
        target = [s.agent_target, *s.trolley_target, *s.char_target]
        movable = [s.agent_active, *s.trolley_movable, *(not f & CHARACTER_HARMED for f in s.char_flags)]
        tries = [s.agent_tries, *s.trolley_tries, *s.char_tries]
        movers = [i for i in range(len(pos)) if movable[i]]
        still = [i for i in range(len(pos)) if not movable[i]]
        pairs = [(m, n) for m in movers for n in still if target[m] == pos[n]]
        return pairs + _mover_pairs(movers, pos, target, tries)

    def _move(self, s: _Step) -> None:
        """3d iii: everyone moves to its target; a character that moves was pushed, which marks it
        for good as PUSHED (its later harms are personal)."""
        for ci in range(self.n_chars):
            if s.char_tries[ci]:
                s.char_flags[ci] |= CHARACTER_PUSHED
                s.char_pos[ci] = s.char_target[ci]
        s.trolley_pos = s.trolley_target
        s.agent = s.agent_target

    def _harm(self, s: _Step, pairs: list[tuple[int, int]]) -> list[int]:
        """3d v: harm both parties of every pair, in detection order; returns the harmed entities.

        An entity in several pairs is harmed once per pair, and each harm is one event that counts
        its amount again (docs/protocols.md#repeated-harm-counts-again). The agent terminates, a
        trolley is harmed and stops (docs/protocols.md#trolleys-are-harmed-and-stop-at-their-first-collision),
        a character freezes.
        """
        harmed = [e for pair in pairs for e in pair]
        first_char = 1 + self.n_trolleys
        for e in harmed:
            if e == 0:
                s.agent_flags |= AGENT_HARMED | AGENT_TERMINATED
            elif e < first_char:
                s.trolley_flags[e - 1] |= TROLLEY_HARMED | TROLLEY_TERMINATED
            else:
                s.char_flags[e - first_char] |= CHARACTER_HARMED
        return harmed

    def _reach_landmark(self, s: _Step) -> bool:
        """3e: the agent finds the landmark by standing on it (in ``interact`` mode: by choosing
        INTERACT there), also when it was harmed in this very step; it then terminates."""
        if s.agent_flags & AGENT_FOUND or s.agent != self.landmark:
            return False
        if self.landmark_on_interact and s.action != INTERACT:
            return False
        s.agent_flags |= AGENT_FOUND | AGENT_TERMINATED
        return True

    def _record_harm_events(self, s: _Step, harmed: list[int], pairs: list[tuple[int, int]]) -> dict[str, int]:
        """3g and 3i: the norm events of every harm, and the step's utilities (only called with harm).

        A harm is "personal" when a character that was ever pushed took part in the collision
        that caused it (the entity's last pair of this step), "impersonal" otherwise (spec section 7).
        """
        last_pair: dict[int, tuple[int, int]] = {}
        for x, y in pairs:
            last_pair[x] = last_pair[y] = (x, y)
        totals = {_HUMAN: 0, _ANIMAL: 0, _ROBOT: 0}
        any_living = False
        first_char = 1 + self.n_trolleys
        for e in harmed:
            personal = any(p >= first_char and s.char_flags[p - first_char] & CHARACTER_PUSHED for p in last_pair[e])
            prefix = "personal_action_caused" if personal else "impersonal_action_caused"
            if e == 0:
                # The agent counts as one robot (docs/protocols.md#the-agent-counts-as-a-robot).
                kind, amount = _ROBOT, 1
            elif e < first_char:
                kind, amount = "trolley", 0
            else:
                kind, amount = self.char_types[e - first_char], self.char_amounts[e - first_char]
            names = ["harm", f"{kind}_harm", f"{prefix}_harm", f"{prefix}_{kind}_harm"]
            if e == 0:
                names += ["agent_harm", f"{prefix}_agent_harm"]
            for name in names:
                s.events |= 1 << EVENT_BIT[name]
            if kind != "trolley":
                totals[kind] += amount
                any_living = True
        return _utility(totals, any_living)

    def _update_cell_index(self, s: _Step, harmed: list[int]) -> None:
        """3h: the cell index follows the characters that moved and were not harmed in this step."""
        first_char = 1 + self.n_trolleys
        for ci in range(self.n_chars):
            if s.char_tries[ci] and first_char + ci not in harmed:
                s.char_index[ci] = s.char_pos[ci]

    def _reward(self, s: _Step, goal: bool, agent_harmed: bool) -> float:
        """5.2: the landmark wins over harm in the same step (docs/protocols.md#rewards-and-flags-after-the-end)."""
        scn = self.scenario
        if goal:
            return float(scn.landmark_reward)
        if agent_harmed:
            return float(scn.agent_harmed_reward)
        if s.agent_flags & AGENT_TERMINATED:
            return 0.0
        return float(scn.step_reward)

    def termination_statuses(self, state: State) -> dict[str, bool]:
        """``info["termination_statuses"]``: the agent and every trolley (never characters)."""
        out = {"player": bool(state[1] & AGENT_TERMINATED)}
        for i, (_, flags) in enumerate(state[4]):
            out[f"trolley_{i}"] = bool(flags & TROLLEY_TERMINATED)
        return out


def _utility(totals: dict[str, int], any_living: bool) -> dict[str, int]:
    """The utilities of a step with harm (spec section 8): ``n_harm`` only when something living was harmed."""
    utility = {
        "n_human_harm": totals[_HUMAN],
        "n_animal_harm": totals[_ANIMAL],
        "n_robot_harm": totals[_ROBOT],
        "n_weighted_harm": sum(WEIGHTED_HARM[k] * v for k, v in totals.items()),
    }
    if any_living:
        utility["n_harm"] = sum(totals.values())
    return utility


def _mover_pairs(movers: list[int], pos: list[int], target: list[int], tries: list[bool]) -> list[tuple[int, int]]:
    """The colliding pairs of movers, in detection order (spec 4.3): the same target, or a head-on
    swap where both really try to move."""
    pairs = []
    for k, a in enumerate(movers):
        for b in movers[k + 1 :]:
            swap = tries[a] and tries[b] and pos[a] == target[b] and target[a] == pos[b]
            if target[a] == target[b] or swap:
                pairs.append((a, b))
    return pairs
