"""One observation for every dilemma: a padded symbolic grid with one channel per kind of thing.

The default observation (:mod:`morality_gym.world.observe`) is the reference's flat vector, whose
length and meaning change with the scenario (a lever adds its states, a character seven numbers), so
a policy trained on one scenario cannot even be fed another's. This grid has one fixed shape,
``(GRID_CHANNELS, GRID_HEIGHT, GRID_WIDTH)``, for every built-in, user or generated scenario (the
idea of MiniGrid's symbolic observation): cell ``[k, r, c]`` says how much of kind ``k`` is at row
``r``, column ``c``; cells beyond the scenario's grid are all zero (the ``floor`` and ``wall``
channels tell where the grid ends). One policy can therefore act in all of them, which is what a
held-out generalisation split needs.

Values are small integers (``uint8``): 0/1 flags, group sizes, lever numbers and states, so the
per-state tables of the batched simulators stay small (``GRID_CHANNELS * GRID_HEIGHT *
GRID_WIDTH`` bytes per state). The lever-switch wiring, which the flat vector never showed, is
visible here: a switch cell holds the number of the lever that sets it, a lever cell its own number.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from gymnasium import spaces

from morality_gym.world.layout import EXIT_DIRECTIONS, RAIL_DIRECTIONS
from morality_gym.world.rules import (
    AGENT_HARMED,
    AGENT_TERMINATED,
    CHARACTER_HARMED,
    TROLLEY_TERMINATED,
    State,
    World,
)

#: Rows and columns of the padded grid. The largest built-in scenario is 10 x 9 (Switch7) and the
#: generator's grammar stays within 13 x 10; 16 leaves room for user scenarios while keeping a
#: state's grid at 5 KiB.
GRID_HEIGHT: Final[int] = 16
GRID_WIDTH: Final[int] = 16

#: The channels, in order. ``rail_*``: the direction a trolley on the cell moves next (at a switch,
#: the exit its lever selects now). ``switch``/``lever``: the lever's number (1, 2, ...);
#: ``lever_state``: its current state. ``human``/``animal``/``robot``: the size of the unharmed
#: groups of that type standing on the cell; ``harmed``: the size of the harmed groups of any type;
#: ``pushable``: 1 under an unharmed group the agent can push.
GRID_CHANNEL_NAMES: Final[tuple[str, ...]] = (
    "wall",
    "floor",
    "rail_left",
    "rail_right",
    "rail_up",
    "rail_down",
    "switch",
    "lever",
    "lever_state",
    "landmark",
    "agent",
    "agent_stopped",
    "agent_harmed",
    "trolley",
    "trolley_stopped",
    "human",
    "animal",
    "robot",
    "harmed",
    "pushable",
)
GRID_CHANNELS: Final[int] = len(GRID_CHANNEL_NAMES)
CHANNEL: Final[dict[str, int]] = {name: i for i, name in enumerate(GRID_CHANNEL_NAMES)}
#: The largest value any channel takes is a group size; uint8 holds what a file can declare in practice.
_MAX_VALUE = 255
_DIRECTION_CHANNEL = {(0, -1): CHANNEL["rail_left"], (0, 1): CHANNEL["rail_right"],
                      (-1, 0): CHANNEL["rail_up"], (1, 0): CHANNEL["rail_down"]}


class GridTooSmallError(ValueError):
    """A scenario larger than the padded grid: its grid observation cannot exist."""


class GridCodec:
    """Turns a world's kernel states into the fixed-shape grid (module docstring).

    The parts that never change in an episode (walls, floor, plain rails, landmark, lever and switch
    numbers) are drawn once into :attr:`static`; :meth:`encode` copies it and adds the moving parts.
    """

    def __init__(self, world: World) -> None:
        scn = world.scenario
        if scn.height > GRID_HEIGHT or scn.width > GRID_WIDTH:
            raise GridTooSmallError(
                f"{scn.source}: layout: {scn.name} is {scn.height}x{scn.width}, larger than the grid "
                f"observation's {GRID_HEIGHT}x{GRID_WIDTH}. Fix: use obs_type='flat' for it, or a smaller layout"
            )
        self.world = world
        self._switch_exits = [(sw.at, sw.lever, sw.exits) for sw in scn.switches]
        self.static = self._static_layers()
        self.static.setflags(write=False)

    @staticmethod
    def space() -> spaces.Box:
        """The same Box for every scenario: ``uint8`` of shape ``(GRID_CHANNELS, GRID_HEIGHT, GRID_WIDTH)``."""
        return spaces.Box(0, _MAX_VALUE, shape=(GRID_CHANNELS, GRID_HEIGHT, GRID_WIDTH), dtype=np.uint8)

    def _static_layers(self) -> np.ndarray:
        scn = self.world.scenario
        grid = np.zeros((GRID_CHANNELS, GRID_HEIGHT, GRID_WIDTH), dtype=np.uint8)
        for r in range(scn.height):
            for c in range(scn.width):
                grid[CHANNEL["wall" if (r, c) in scn.walls else "floor"], r, c] = 1
        for (r, c), glyph in scn.rails.items():
            if glyph != "S":
                grid[_DIRECTION_CHANNEL[RAIL_DIRECTIONS[glyph]], r, c] = 1
        for (r, c), lever, _ in self._switch_exits:
            grid[CHANNEL["switch"], r, c] = lever + 1
        for number, lever in enumerate(scn.levers, start=1):
            grid[CHANNEL["lever"], lever.at[0], lever.at[1]] = number
        grid[CHANNEL["landmark"], scn.landmark[0], scn.landmark[1]] = 1
        return grid

    def encode(self, state: State) -> np.ndarray:
        """The grid of ``state``: a new ``uint8`` array of shape ``(GRID_CHANNELS, GRID_HEIGHT, GRID_WIDTH)``."""
        world = self.world
        grid = self.static.copy()
        agent, aflags, levers, chars, trolleys = state
        for (r, c), lever, exits in self._switch_exits:
            grid[_DIRECTION_CHANNEL[EXIT_DIRECTIONS[exits[levers[lever]]]], r, c] = 1
        for value, spec in zip(levers, world.scenario.levers):
            grid[CHANNEL["lever_state"], spec.at[0], spec.at[1]] = value
        r, c = divmod(agent, world.width)
        grid[CHANNEL["agent"], r, c] = 1
        grid[CHANNEL["agent_stopped"], r, c] = 1 if aflags & AGENT_TERMINATED else 0
        grid[CHANNEL["agent_harmed"], r, c] = 1 if aflags & AGENT_HARMED else 0
        for cell, flags in trolleys:
            r, c = divmod(cell, world.width)
            grid[CHANNEL["trolley_stopped" if flags & TROLLEY_TERMINATED else "trolley"], r, c] = 1
        for (cell, flags, _), kind, amount, pushable in zip(chars, world.char_types, world.char_amounts,
                                                           world.char_pushable):
            r, c = divmod(cell, world.width)
            harmed = bool(flags & CHARACTER_HARMED)
            channel = CHANNEL["harmed" if harmed else kind]
            grid[channel, r, c] = min(_MAX_VALUE, int(grid[channel, r, c]) + amount)
            if pushable and not harmed:
                grid[CHANNEL["pushable"], r, c] = 1
        return grid


def grid_table(world: World, states: list[State]) -> np.ndarray:
    """The grids of ``states`` stacked, ``[len(states), GRID_CHANNELS, GRID_HEIGHT, GRID_WIDTH]`` (the
    per-state table the batched simulators gather from, as they do from the flat observations)."""
    codec = GridCodec(world)
    table = np.empty((len(states), GRID_CHANNELS, GRID_HEIGHT, GRID_WIDTH), dtype=np.uint8)
    for i, state in enumerate(states):
        table[i] = codec.encode(state)
    return table
