"""Scenario files: load, validate and describe the YAML data that defines each dilemma.

A scenario is data, not code (``morality_gym/data/scenarios/*.yaml``): three ASCII pictures of the
grid (floor, rails, things), the switch wiring, the characters, and a small table of variants.
This module turns such a file into an immutable :class:`Scenario`. Everything a user can get
wrong is checked here, once, with a message that names the file, the field and the fix, because
a silently mis-read layout would corrupt every number computed on it afterwards.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from morality_gym.clitools import did_you_mean
from morality_gym.world.vocab import ALL_NAMES, CHARACTER_TYPES

Cell = tuple[int, int]

#: Rail glyph -> outgoing (row, col) offset.
RAIL_DIRECTIONS: dict[str, Cell] = {"<": (0, -1), ">": (0, 1), "^": (-1, 0), "v": (1, 0)}
#: Switch exit letter (as in the spec) -> (row, col) offset.
EXIT_DIRECTIONS: dict[str, Cell] = {"L": (0, -1), "R": (0, 1), "U": (-1, 0), "D": (1, 0)}
UTILITY_TYPES: tuple[str, ...] = ("n_human_harm", "n_animal_harm", "n_robot_harm")

_TOP_LEVEL_KEYS = {
    "name": True,
    "summary": False,
    "rewards": True,
    "landmark_mode": False,
    "trolley_start": False,
    "layout": True,
    "switches": False,
    "levers_loop": False,
    "characters": True,
    "utility_bounds": True,
    "variants": True,
}
_GLOBAL_UTILITY_KEYS = ("n_harm", "n_human_harm", "n_robot_harm", "n_animal_harm", "n_weighted_harm")


class ScenarioError(ValueError):
    """A scenario file is malformed; the message names the file, the field and the fix."""


@dataclass(frozen=True)
class CharacterSpec:
    """A character group's fixed properties (its type and size come from the variant)."""

    name: str
    start: Cell
    pushable: bool
    onehot: tuple[str, ...]


@dataclass(frozen=True)
class SwitchSpec:
    """A switch cell, its exits in state order and the (0-based) lever that sets it."""

    name: str
    at: Cell
    exits: tuple[str, ...]
    lever: int


@dataclass(frozen=True)
class LeverSpec:
    """A lever: its cell, how many states it has and the (0-based) switches it drives."""

    name: str
    at: Cell
    n_states: int
    switches: tuple[int, ...]


@dataclass(frozen=True)
class VariantSpec:
    """One row of a scenario's variant table."""

    name: str
    types: tuple[str, ...]
    amounts: tuple[int, ...]
    bounds: Mapping[str, tuple[float, float]]
    relevant: tuple[str, ...]


@dataclass(frozen=True)
class Scenario:
    """An immutable, validated scenario: layout, wiring, rewards and variants."""

    name: str
    summary: str
    source: str
    height: int
    width: int
    walls: frozenset[Cell]
    rails: Mapping[Cell, str]
    player_start: Cell
    landmark: Cell
    trolley_starts: tuple[Cell, ...]
    levers: tuple[LeverSpec, ...]
    switches: tuple[SwitchSpec, ...]
    levers_loop: bool
    characters: tuple[CharacterSpec, ...]
    step_reward: float
    landmark_reward: float
    agent_harmed_reward: float
    landmark_mode: str
    trolley_start: str
    utility_bounds: Mapping[str, tuple[float, float]]
    variants: Mapping[str, VariantSpec] = field(repr=False)

    def env_id(self, variant: str) -> str:
        """The registered id of one variant, e.g. ``SwitchStandard-HumanA-v1``."""
        return f"{self.name}-{variant}-v1"

    @property
    def env_ids(self) -> list[str]:
        return [self.env_id(v) for v in self.variants]

    def picture(self, variant: str | None = None) -> list[str]:
        """The one-glyph-per-cell overview used by the docs and the ``ansi`` renderer.

        Drawing priority: agent > trolley > character > landmark > lever > switch > rail > floor;
        characters are ``h a r`` (``H A R`` when pushable) for human, animal, robot.
        """
        types = self.variants[variant].types if variant else tuple(c.onehot[0] for c in self.characters)
        grid = [["#" if (r, c) in self.walls else "." for c in range(self.width)] for r in range(self.height)]
        for cell, glyph in self.rails.items():
            grid[cell[0]][cell[1]] = glyph
        for lever in self.levers:
            grid[lever.at[0]][lever.at[1]] = "/"
        grid[self.landmark[0]][self.landmark[1]] = "G"
        for spec, kind in zip(self.characters, types):
            letter = kind[0]
            grid[spec.start[0]][spec.start[1]] = letter.upper() if spec.pushable else letter
        for cell in self.trolley_starts:
            grid[cell[0]][cell[1]] = "T"
        grid[self.player_start[0]][self.player_start[1]] = "P"
        return ["".join(row) for row in grid]


def _fail(source: str, where: str, problem: str, fix: str) -> ScenarioError:
    return ScenarioError(f"{source}: {where}: {problem}. Fix: {fix}")


def _close(word: str, choices: list[str]) -> str:
    return did_you_mean(word, choices, n=3, quote=False)


def _cell(source: str, where: str, value: Any, height: int, width: int) -> Cell:
    if (
        not isinstance(value, (list, tuple))
        or len(value) != 2
        or not all(isinstance(v, int) and not isinstance(v, bool) for v in value)
    ):
        raise _fail(source, where, f"expected a cell [row, col], got {value!r}", "write it as [row, col]")
    row, col = int(value[0]), int(value[1])
    if not (0 <= row < height and 0 <= col < width):
        raise _fail(
            source, where, f"cell {[row, col]} is outside the {height}x{width} grid", "use a cell inside the grid"
        )
    return row, col


def _bounds(source: str, where: str, value: Any) -> tuple[float, float]:
    if (
        not isinstance(value, (list, tuple))
        or len(value) != 2
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
    ):
        raise _fail(source, where, f"expected [low, high], got {value!r}", "write bounds as [low, high]")
    lo, hi = float(value[0]), float(value[1])
    if lo > hi:
        raise _fail(source, where, f"low {lo:g} is above high {hi:g}", "swap them")
    return lo, hi



def yaml_problem(exc: yaml.YAMLError) -> str:
    """A YAML parser's error on one line: what it expected, and where (line, column).

    PyYAML's own text spans five lines (the context, a copy of the line, a caret): as a warning
    about a user's scenario file, which the docs promise on one line, it printed as four or more."""
    problem = getattr(exc, "problem", None)
    mark = getattr(exc, "problem_mark", None)
    if problem and mark is not None:
        context = getattr(exc, "context", None)
        return f"{context + ': ' if context else ''}{problem} at line {mark.line + 1}, column {mark.column + 1}"
    return " ".join(str(exc).split())

def load_scenario(path: str | Path) -> Scenario:
    """Load and validate one scenario file.

    Raises :class:`ScenarioError` with the file, the field and a fix for every problem found.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read the file: {exc}") from exc
    return scenario_from_bytes(data, str(path))


def scenario_from_bytes(data: bytes, source: str) -> Scenario:
    """A scenario file's bytes, already read (so that a caller can digest the very bytes it parsed)."""
    try:
        raw = yaml.safe_load(data.decode())
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{source}: cannot read the file: not UTF-8 text ({exc})") from exc
    except yaml.YAMLError as exc:
        raise ScenarioError(f"{source}: not valid YAML: {yaml_problem(exc)}") from exc
    return parse_scenario(raw, source)


def parse_scenario(raw: Any, source: str = "<scenario>") -> Scenario:
    """Validate an already-parsed scenario mapping (see :func:`load_scenario`).

    One parser per section of the file; each returns its part of the :class:`Scenario` and raises
    the errors about its own section. They run in a fixed order, so a file with several mistakes
    is always reported at the same one first, and the later sections are checked against the
    earlier ones (switches against the rails, variants against the characters).
    """
    _check_fields(source, raw)
    name = _parse_name(source, raw["name"])
    grid = _parse_grid(source, raw["layout"])
    switches = _parse_switches(source, raw.get("switches"), grid)
    levers = _wire_levers(source, grid.lever_cells, switches)
    levers_loop = _parse_levers_loop(source, raw.get("levers_loop", True))
    characters = _parse_characters(source, raw["characters"], grid.char_cells)
    rewards = _parse_rewards(source, raw["rewards"])
    landmark_mode = _parse_choice(source, "landmark_mode", raw.get("landmark_mode", "enter"), ("enter", "interact"))
    trolley_start = _parse_choice(
        source, "trolley_start", raw.get("trolley_start", "episode_start"), ("episode_start", "landmark_reached")
    )
    utility_bounds = _parse_utility_bounds(source, raw["utility_bounds"])
    variants = _parse_variants(source, raw["variants"], characters)
    return Scenario(
        name=name,
        summary=str(raw.get("summary", "")).strip(),
        source=source,
        height=grid.height,
        width=grid.width,
        walls=grid.walls,
        rails=dict(grid.rails),
        player_start=grid.player,
        landmark=grid.landmark,
        trolley_starts=grid.trolleys,
        levers=levers,
        switches=switches,
        levers_loop=levers_loop,
        characters=characters,
        step_reward=rewards["step"],
        landmark_reward=rewards["landmark"],
        agent_harmed_reward=rewards["agent_harmed"],
        landmark_mode=landmark_mode,
        trolley_start=trolley_start,
        utility_bounds=utility_bounds,
        variants=variants,
    )


# ============================================================================ top level
def _check_fields(source: str, raw: Any) -> None:
    """The file is a mapping with only known fields and every required one."""
    if not isinstance(raw, dict):
        raise _fail(source, "top level", "expected a mapping of fields", "start the file with 'name: ...'")
    for key in raw:
        if key not in _TOP_LEVEL_KEYS:
            raise _fail(
                source,
                str(key),
                f"unknown field{_close(str(key), list(_TOP_LEVEL_KEYS))}",
                f"use only {', '.join(_TOP_LEVEL_KEYS)}",
            )
    for key, required in _TOP_LEVEL_KEYS.items():
        if required and key not in raw:
            raise _fail(source, key, "required field is missing", f"add '{key}:'")


def _parse_name(source: str, name: Any) -> str:
    """``name:``, a CamelCase identifier: it becomes the first part of every env id."""
    if not isinstance(name, str) or not re.fullmatch(r"[A-Z][A-Za-z0-9]*", name):
        raise _fail(source, "name", f"{name!r} is not a CamelCase identifier", "use a name like 'SwitchStandard'")
    return name


def _parse_choice(source: str, key: str, value: Any, choices: tuple[str, ...]) -> str:
    """A field that takes one of a few words (``landmark_mode``, ``trolley_start``)."""
    if value not in choices:
        raise _fail(source, key, f"{value!r} is unknown", f"use {' or '.join(choices)}")
    return value


def _parse_levers_loop(source: str, value: Any) -> bool:
    """``levers_loop:``: whether a lever at its last state wraps round to 0 or stays there."""
    if not isinstance(value, bool):
        raise _fail(source, "levers_loop", f"{value!r} is not true/false", "write true or false")
    return value


def _parse_rewards(source: str, rewards: Any) -> dict[str, float]:
    """``rewards:``: the step, landmark and agent-harmed rewards, as floats."""
    if not isinstance(rewards, dict) or set(rewards) != {"step", "landmark", "agent_harmed"}:
        raise _fail(
            source,
            "rewards",
            f"expected keys step, landmark, agent_harmed; got {rewards!r}",
            "write {step: -1, landmark: 100, agent_harmed: -100}",
        )
    for key, value in rewards.items():
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise _fail(source, f"rewards.{key}", f"{value!r} is not a number", "write a number")
    return {key: float(value) for key, value in rewards.items()}


def _parse_utility_bounds(source: str, raw_bounds: Any) -> dict[str, tuple[float, float]]:
    """``utility_bounds:``: [low, high] for every utility, over all variants of the scenario."""
    if not isinstance(raw_bounds, dict):
        raise _fail(source, "utility_bounds", "expected a mapping", "write {n_harm: [0, 5], ...}")
    bounds = {}
    for key in _GLOBAL_UTILITY_KEYS:
        if key not in raw_bounds:
            raise _fail(
                source,
                f"utility_bounds.{key}",
                "is missing",
                f"give bounds for all of {', '.join(_GLOBAL_UTILITY_KEYS)}",
            )
        bounds[key] = _bounds(source, f"utility_bounds.{key}", raw_bounds[key])
    for key in raw_bounds:
        if key not in _GLOBAL_UTILITY_KEYS:
            raise _fail(
                source,
                f"utility_bounds.{key}",
                f"unknown utility{_close(str(key), list(_GLOBAL_UTILITY_KEYS))}",
                f"use {', '.join(_GLOBAL_UTILITY_KEYS)}",
            )
    return bounds


# ============================================================================ layout
@dataclass(frozen=True)
class _Grid:
    """What the three pictures of ``layout:`` say: the grid, its rails and where things start."""

    height: int
    width: int
    walls: frozenset[Cell]
    rails: dict[Cell, str]  # rail glyph (< > ^ v) or S (switch) per rail cell
    player: Cell
    landmark: Cell
    trolleys: tuple[Cell, ...]
    lever_cells: tuple[Cell, ...]  # in reading order, which numbers the levers
    char_cells: dict[int, Cell]  # character number (its digit) -> start cell


def _parse_grid(source: str, text: Any) -> _Grid:
    """``layout:``: the pictures, read cell by cell and checked against each other."""
    floor, rails_picture, things = _parse_layout(source, text)
    walls, rails = _read_floor_and_rails(source, floor, rails_picture)
    player, landmark, trolleys, lever_cells, char_cells = _read_things(source, things)
    _check_things(source, walls, rails, player, landmark, trolleys, char_cells)
    return _Grid(
        height=len(floor),
        width=len(floor[0]),
        walls=frozenset(walls),
        rails=rails,
        player=player[0],
        landmark=landmark[0],
        trolleys=tuple(trolleys),
        lever_cells=tuple(lever_cells),
        char_cells=char_cells,
    )


def _parse_layout(source: str, text: Any) -> tuple[list[str], list[str], list[str]]:
    """Split the block into the floor, rails and things pictures, all of one width."""
    if not isinstance(text, str):
        raise _fail(
            source, "layout", "expected a block of text (layout: |)", "write the three pictures as a literal block"
        )
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if not lines or lines[0].split() != ["floor", "rails", "things"]:
        raise _fail(
            source,
            "layout",
            "the first line must be the header 'floor rails things'",
            "add the header line above the pictures",
        )
    floor, rails, things = [], [], []
    for number, line in enumerate(lines[1:], start=1):
        parts = line.split()
        if len(parts) != 3:
            raise _fail(
                source,
                f"layout row {number - 1}",
                f"expected 3 pictures separated by spaces, found {len(parts)}",
                "keep the floor, rails and things pictures side by side with no spaces inside them",
            )
        floor.append(parts[0])
        rails.append(parts[1])
        things.append(parts[2])
    width = len(floor[0])
    for name, picture in (("floor", floor), ("rails", rails), ("things", things)):
        for row, text_row in enumerate(picture):
            if len(text_row) != width:
                raise _fail(
                    source,
                    f"layout {name} row {row}",
                    f"has {len(text_row)} cells but row 0 of floor has {width}",
                    "make every row of every picture the same width",
                )
    return floor, rails, things


def _read_floor_and_rails(source: str, floor: list[str], rails_picture: list[str]) -> tuple[set[Cell], dict[Cell, str]]:
    """The walls and the rail cells. One pass over both pictures, so that the first unknown glyph
    in reading order is the one reported (the floor's before the rails' in the same cell)."""
    walls: set[Cell] = set()
    rails: dict[Cell, str] = {}
    for r, (floor_row, rails_row) in enumerate(zip(floor, rails_picture)):
        for c, (ground, rail) in enumerate(zip(floor_row, rails_row)):
            if ground == "#":
                walls.add((r, c))
            elif ground != ".":
                raise _fail(
                    source, f"layout floor cell [{r}, {c}]", f"unknown glyph {ground!r}", "use '#' (wall) or '.' (open)"
                )
            if rail in RAIL_DIRECTIONS or rail == "S":
                rails[(r, c)] = rail
            elif rail != ".":
                raise _fail(
                    source,
                    f"layout rails cell [{r}, {c}]",
                    f"unknown glyph {rail!r}",
                    "use < > ^ v (rail), S (switch) or '.'",
                )
    return walls, rails


def _read_things(
    source: str, things: list[str]
) -> tuple[list[Cell], list[Cell], list[Cell], list[Cell], dict[int, Cell]]:
    """Where the things picture puts the agent (P), the landmark (G), the trolleys (T), the levers
    (/) and the numbered characters (1-9), each in reading order."""
    player: list[Cell] = []
    landmark: list[Cell] = []
    trolleys: list[Cell] = []
    lever_cells: list[Cell] = []
    char_cells: dict[int, Cell] = {}
    by_glyph = {"P": player, "G": landmark, "T": trolleys, "/": lever_cells}
    for r, row in enumerate(things):
        for c, glyph in enumerate(row):
            if glyph == ".":
                continue
            if glyph in by_glyph:
                by_glyph[glyph].append((r, c))
            elif glyph.isdigit() and glyph != "0":
                if int(glyph) in char_cells:
                    raise _fail(
                        source,
                        f"layout things cell [{r}, {c}]",
                        f"character {glyph} appears twice",
                        "number characters 1, 2, 3, ... once each",
                    )
                char_cells[int(glyph)] = (r, c)
            else:
                raise _fail(
                    source,
                    f"layout things cell [{r}, {c}]",
                    f"unknown glyph {glyph!r}",
                    "use P, G, T, /, a digit 1-9 or '.'",
                )
    return player, landmark, trolleys, lever_cells, char_cells


def _check_things(
    source: str,
    walls: set[Cell],
    rails: dict[Cell, str],
    player: list[Cell],
    landmark: list[Cell],
    trolleys: list[Cell],
    char_cells: dict[int, Cell],
) -> None:
    """One agent and one landmark on open floor, at least one trolley and all of them on rails,
    and characters numbered 1, 2, 3, ... without gaps."""
    for glyph, found, what in (("P", player, "agent start"), ("G", landmark, "landmark")):
        if len(found) != 1:
            raise _fail(
                source,
                "layout things",
                f"expected exactly one '{glyph}' ({what}), found {len(found)}",
                f"draw one '{glyph}'",
            )
    if not trolleys:
        raise _fail(source, "layout things", "no trolley start 'T'", "draw at least one 'T' on a rail cell")
    for cell in trolleys:
        if cell not in rails:
            raise _fail(source, f"trolley start {list(cell)}", "is not on a rail", "put 'T' on a rail cell")
    if player[0] in walls:
        raise _fail(
            source, f"agent start {list(player[0])}", "is on a wall", "start the agent on an open '.' floor cell"
        )
    if landmark[0] in walls:
        raise _fail(
            source, f"landmark {list(landmark[0])}", "is on a wall, so it can never be reached", "put 'G' on open floor"
        )
    if sorted(char_cells) != list(range(1, len(char_cells) + 1)):
        raise _fail(
            source,
            "layout things",
            f"characters are numbered {sorted(char_cells)}",
            "number them 1, 2, 3, ... without gaps",
        )


# ============================================================================ switches and levers
def _parse_switches(source: str, raw_switches: Any, grid: _Grid) -> tuple[SwitchSpec, ...]:
    """``switches:``: one entry per 'S' of the rails picture, whose exits all lead onto rails.

    Switches are numbered like the reference numbers them: in the order they are listed.
    """
    raw_switches = raw_switches or []
    if not isinstance(raw_switches, list):
        raise _fail(source, "switches", "expected a list", "write '- {at: [r, c], exits: [L, D], lever: 1}' items")
    switches: list[SwitchSpec] = []
    for i, item in enumerate(raw_switches):
        switches.append(_parse_switch(source, f"switches[{i}]", item, grid, {s.at for s in switches}))
    described = {s.at for s in switches}
    missing = [list(cell) for cell, glyph in sorted(grid.rails.items()) if glyph == "S" and cell not in described]
    if missing:
        raise _fail(
            source, "switches", f"switch cells {missing} have no entry", "add one entry per 'S' in the rails picture"
        )
    return tuple(SwitchSpec(f"switch_{i + 1}", s.at, s.exits, s.lever) for i, s in enumerate(switches))


def _parse_switch(source: str, where: str, item: Any, grid: _Grid, described: set[Cell]) -> SwitchSpec:
    """One ``switches:`` entry (still unnamed); ``described`` holds the cells of the entries before it."""
    if not isinstance(item, dict) or set(item) != {"at", "exits", "lever"}:
        raise _fail(
            source,
            where,
            f"expected keys at, exits, lever; got {item!r}",
            "write {at: [r, c], exits: [L, D], lever: 1}",
        )
    at = _cell(source, f"{where}.at", item["at"], grid.height, grid.width)
    if grid.rails.get(at) != "S":
        raise _fail(
            source, f"{where}.at", f"cell {list(at)} is not an 'S' in the rails picture", "point 'at' to a switch cell"
        )
    if at in described:
        raise _fail(source, f"{where}.at", f"switch {list(at)} is described twice", "describe each switch once")
    exits = item["exits"]
    if not isinstance(exits, list) or len(exits) < 2 or any(e not in EXIT_DIRECTIONS for e in exits):
        raise _fail(source, f"{where}.exits", f"{exits!r} is not a list of 2+ directions", "use letters L, R, U, D")
    for e in exits:
        dr, dc = EXIT_DIRECTIONS[e]
        nxt = (at[0] + dr, at[1] + dc)
        if nxt not in grid.rails:
            raise _fail(
                source,
                f"{where}.exits",
                f"exit {e} leads to {list(nxt)}, which has no rail",
                "exit only onto rail cells",
            )
    lever = item["lever"]
    n_levers = len(grid.lever_cells)
    if not isinstance(lever, int) or not 1 <= lever <= n_levers:
        raise _fail(
            source,
            f"{where}.lever",
            f"{lever!r} is not a lever number 1..{n_levers}",
            "levers are numbered in reading order",
        )
    return SwitchSpec(name="", at=at, exits=tuple(exits), lever=lever - 1)


def _wire_levers(source: str, lever_cells: tuple[Cell, ...], switches: tuple[SwitchSpec, ...]) -> tuple[LeverSpec, ...]:
    """The levers, numbered in reading order: each drives at least one switch, all with as many
    exits as the lever has states."""
    levers: list[LeverSpec] = []
    for li, cell in enumerate(lever_cells):
        driven = tuple(si for si, s in enumerate(switches) if s.lever == li)
        if not driven:
            raise _fail(
                source, f"lever {li + 1} at {list(cell)}", "drives no switch", "wire it to a switch or remove it"
            )
        sizes = {len(switches[si].exits) for si in driven}
        if len(sizes) != 1:
            raise _fail(
                source,
                f"lever {li + 1}",
                f"drives switches with different numbers of exits {sorted(sizes)}",
                "give every switch on one lever the same number of exits",
            )
        levers.append(LeverSpec(f"lever_{li + 1}", cell, sizes.pop(), driven))
    return tuple(levers)


# ============================================================================ characters
def _parse_characters(source: str, raw_chars: Any, char_cells: dict[int, Cell]) -> tuple[CharacterSpec, ...]:
    """``characters:``: one entry per digit drawn in the things picture, in number order."""
    if not isinstance(raw_chars, dict):
        raise _fail(source, "characters", "expected a mapping from digit to properties", "write '1: {pushable: false}'")
    if sorted(raw_chars) != sorted(char_cells):
        raise _fail(
            source,
            "characters",
            f"entries {sorted(raw_chars)} do not match the digits {sorted(char_cells)} in the things picture",
            "list exactly the characters drawn in the layout",
        )
    return tuple(_parse_character(source, k, raw_chars[k], char_cells[k]) for k in sorted(char_cells))


def _parse_character(source: str, number: int, item: Any, start: Cell) -> CharacterSpec:
    """One ``characters:`` entry: whether it can be pushed, and its one-hot order of types."""
    where = f"characters.{number}"
    if not isinstance(item, dict) or not {"pushable"} <= set(item) <= {"pushable", "onehot"}:
        raise _fail(source, where, f"expected pushable and optionally onehot; got {item!r}", "write {pushable: false}")
    if not isinstance(item["pushable"], bool):
        raise _fail(source, f"{where}.pushable", f"{item['pushable']!r} is not true/false", "write true or false")
    onehot = item.get("onehot", list(CHARACTER_TYPES))
    if sorted(onehot) != sorted(CHARACTER_TYPES):
        raise _fail(
            source,
            f"{where}.onehot",
            f"{onehot!r} is not an ordering of {list(CHARACTER_TYPES)}",
            "list each type once",
        )
    return CharacterSpec(f"character_{number}", start, item["pushable"], tuple(onehot))


# ============================================================================ variants
def _parse_variants(source: str, raw_variants: Any, characters: tuple[CharacterSpec, ...]) -> dict[str, VariantSpec]:
    """``variants:``: the table of variants, at least one row."""
    if not isinstance(raw_variants, dict) or not raw_variants:
        raise _fail(
            source, "variants", "expected a non-empty mapping of variant name to row", "add at least one variant"
        )
    return {name: _parse_variant(source, name, row, characters) for name, row in raw_variants.items()}


def _parse_variant(source: str, name: Any, row: Any, characters: tuple[CharacterSpec, ...]) -> VariantSpec:
    """One row of the variant table: its characters' types and sizes, bounds and relevant norms."""
    where = f"variants.{name}"
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z][A-Za-z0-9]*", name):
        raise _fail(source, where, "variant names must be alphanumeric (they become part of the env id)", "rename it")
    if not isinstance(row, dict) or set(row) != {"characters", "bounds", "relevant"}:
        raise _fail(source, where, f"expected keys characters, bounds, relevant; got {row!r}", "see the other rows")
    types, amounts = _parse_groups(source, f"{where}.characters", row["characters"], characters)
    bounds = _parse_variant_bounds(source, f"{where}.bounds", row["bounds"])
    relevant = _parse_relevant(source, f"{where}.relevant", row["relevant"])
    return VariantSpec(name, types, amounts, bounds, relevant)


def _parse_groups(
    source: str, where: str, groups: Any, characters: tuple[CharacterSpec, ...]
) -> tuple[tuple[str, ...], tuple[int, ...]]:
    """A variant's ``characters: [human 5, animal 1, ...]``: (types, group sizes), one per character."""
    if not isinstance(groups, list) or len(groups) != len(characters):
        listed = len(groups) if isinstance(groups, list) else groups
        raise _fail(
            source,
            where,
            f"lists {listed!r} groups but the layout has {len(characters)}",
            "give one 'type amount' per character",
        )
    types, amounts = [], []
    for spec, entry in zip(characters, groups):
        m = re.fullmatch(r"(\w+)\s+(\d+)", str(entry))
        if not m or m.group(1) not in CHARACTER_TYPES:
            raise _fail(
                source,
                where,
                f"{entry!r} is not 'type amount' with type in {list(CHARACTER_TYPES)}",
                "write e.g. 'human 5'",
            )
        amount = int(m.group(2))
        if amount < 1:
            raise _fail(source, where, f"{spec.name} has group size {amount}", "use a group size of 1 or more")
        types.append(m.group(1))
        amounts.append(amount)
    return tuple(types), tuple(amounts)


def _parse_variant_bounds(source: str, where: str, raw_bounds: Any) -> dict[str, tuple[float, float]]:
    """A variant's ``bounds:``: [low, high] per harm type; the types it leaves out are [0, 0]."""
    raw_bounds = raw_bounds or {}
    if not isinstance(raw_bounds, dict):
        raise _fail(source, where, "expected a mapping", "write {n_human_harm: [1, 5]}")
    bounds = {key: (0.0, 0.0) for key in UTILITY_TYPES}
    for key, value in raw_bounds.items():
        if key not in UTILITY_TYPES:
            raise _fail(
                source,
                f"{where}.{key}",
                f"unknown utility{_close(str(key), list(UTILITY_TYPES))}",
                f"use {', '.join(UTILITY_TYPES)}",
            )
        bounds[key] = _bounds(source, f"{where}.{key}", value)
    return bounds


def _parse_relevant(source: str, where: str, relevant: Any) -> tuple[str, ...]:
    """A variant's ``relevant:``: distinct names of events or utilities the environments emit."""
    if not isinstance(relevant, list) or not relevant:
        raise _fail(source, where, "expected a non-empty list of norm names", "list the relevant norms")
    for norm in relevant:
        if norm not in ALL_NAMES:
            raise _fail(
                source,
                where,
                f"{norm!r} is not an event or utility the environments emit{_close(str(norm), sorted(ALL_NAMES))}",
                "use a name from morality_gym.world.vocab",
            )
    if len(set(relevant)) != len(relevant):
        raise _fail(source, where, "lists a norm twice", "list each norm once")
    return tuple(relevant)
