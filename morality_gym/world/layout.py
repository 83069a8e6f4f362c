"""Scenario files: load, validate and describe the YAML data that defines each dilemma.

A scenario is data, not code (``morality_gym/data/scenarios/*.yaml``): three ASCII pictures of the
grid (floor, rails, things), the switch wiring, the characters, and a small table of variants.
This module turns such a file into an immutable :class:`Scenario`. Everything a user can get
wrong is checked here, once, with a message that names the file, the field and the fix, because
a silently mis-read layout would corrupt every number computed on it afterwards.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

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
    match = difflib.get_close_matches(word, choices, n=3)
    return f" (did you mean {', '.join(match)}?)" if match else ""


def _cell(source: str, where: str, value: Any, height: int, width: int) -> Cell:
    if (
        not isinstance(value, (list, tuple))
        or len(value) != 2
        or not all(isinstance(v, int) and not isinstance(v, bool) for v in value)
    ):
        raise _fail(source, where, f"expected a cell [row, col], got {value!r}", "write it as [row, col]")
    row, col = int(value[0]), int(value[1])
    if not (0 <= row < height and 0 <= col < width):
        raise _fail(source, where, f"cell {[row, col]} is outside the {height}x{width} grid", "use a cell inside the grid")
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


def _parse_layout(source: str, text: Any) -> tuple[list[str], list[str], list[str]]:
    if not isinstance(text, str):
        raise _fail(source, "layout", "expected a block of text (layout: |)", "write the three pictures as a literal block")
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if not lines or lines[0].split() != ["floor", "rails", "things"]:
        raise _fail(
            source, "layout", "the first line must be the header 'floor rails things'", "add the header line above the pictures"
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


def load_scenario(path: str | Path) -> Scenario:
    """Load and validate one scenario file.

    Raises :class:`ScenarioError` with the file, the field and a fix for every problem found.
    """
    path = Path(path)
    source = str(path)
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ScenarioError(f"{source}: not valid YAML: {exc}") from exc
    except OSError as exc:
        raise ScenarioError(f"{source}: cannot read the file: {exc}") from exc
    return parse_scenario(raw, source)


def parse_scenario(raw: Any, source: str = "<scenario>") -> Scenario:
    """Validate an already-parsed scenario mapping (see :func:`load_scenario`)."""
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

    name = raw["name"]
    if not isinstance(name, str) or not re.fullmatch(r"[A-Z][A-Za-z0-9]*", name):
        raise _fail(source, "name", f"{name!r} is not a CamelCase identifier", "use a name like 'SwitchStandard'")

    floor, rails_pic, things = _parse_layout(source, raw["layout"])
    height, width = len(floor), len(floor[0])

    walls: set[Cell] = set()
    rails: dict[Cell, str] = {}
    for r in range(height):
        for c in range(width):
            f, rl = floor[r][c], rails_pic[r][c]
            if f == "#":
                walls.add((r, c))
            elif f != ".":
                raise _fail(source, f"layout floor cell [{r}, {c}]", f"unknown glyph {f!r}", "use '#' (wall) or '.' (open)")
            if rl in RAIL_DIRECTIONS or rl == "S":
                rails[(r, c)] = rl
            elif rl != ".":
                raise _fail(
                    source, f"layout rails cell [{r}, {c}]", f"unknown glyph {rl!r}", "use < > ^ v (rail), S (switch) or '.'"
                )

    player: list[Cell] = []
    landmark: list[Cell] = []
    trolleys: list[Cell] = []
    lever_cells: list[Cell] = []
    char_cells: dict[int, Cell] = {}
    for r in range(height):
        for c in range(width):
            g = things[r][c]
            if g == ".":
                continue
            if g == "P":
                player.append((r, c))
            elif g == "G":
                landmark.append((r, c))
            elif g == "T":
                trolleys.append((r, c))
            elif g == "/":
                lever_cells.append((r, c))
            elif g.isdigit() and g != "0":
                if int(g) in char_cells:
                    raise _fail(source, f"layout things cell [{r}, {c}]", f"character {g} appears twice", "number characters 1, 2, 3, ... once each")
                char_cells[int(g)] = (r, c)
            else:
                raise _fail(
                    source, f"layout things cell [{r}, {c}]", f"unknown glyph {g!r}", "use P, G, T, /, a digit 1-9 or '.'"
                )
    for glyph, found, what in (("P", player, "agent start"), ("G", landmark, "landmark")):
        if len(found) != 1:
            raise _fail(source, "layout things", f"expected exactly one '{glyph}' ({what}), found {len(found)}", f"draw one '{glyph}'")
    if not trolleys:
        raise _fail(source, "layout things", "no trolley start 'T'", "draw at least one 'T' on a rail cell")
    for cell in trolleys:
        if cell not in rails:
            raise _fail(source, f"trolley start {list(cell)}", "is not on a rail", "put 'T' on a rail cell")
    if player[0] in walls:
        raise _fail(source, f"agent start {list(player[0])}", "is on a wall", "start the agent on an open '.' floor cell")
    if landmark[0] in walls:
        raise _fail(source, f"landmark {list(landmark[0])}", "is on a wall, so it can never be reached", "put 'G' on open floor")
    if sorted(char_cells) != list(range(1, len(char_cells) + 1)):
        raise _fail(source, "layout things", f"characters are numbered {sorted(char_cells)}", "number them 1, 2, 3, ... without gaps")

    # Rails: every rail and switch exit must point at a rail cell.
    raw_switches = raw.get("switches") or []
    if not isinstance(raw_switches, list):
        raise _fail(source, "switches", "expected a list", "write '- {at: [r, c], exits: [L, D], lever: 1}' items")
    switch_cells = sorted(cell for cell, glyph in rails.items() if glyph == "S")
    switches: list[SwitchSpec] = []
    seen_switch: set[Cell] = set()
    for i, item in enumerate(raw_switches):
        where = f"switches[{i}]"
        if not isinstance(item, dict) or set(item) != {"at", "exits", "lever"}:
            raise _fail(source, where, f"expected keys at, exits, lever; got {item!r}", "write {at: [r, c], exits: [L, D], lever: 1}")
        at = _cell(source, f"{where}.at", item["at"], height, width)
        if rails.get(at) != "S":
            raise _fail(source, f"{where}.at", f"cell {list(at)} is not an 'S' in the rails picture", "point 'at' to a switch cell")
        if at in seen_switch:
            raise _fail(source, f"{where}.at", f"switch {list(at)} is described twice", "describe each switch once")
        seen_switch.add(at)
        exits = item["exits"]
        if not isinstance(exits, list) or len(exits) < 2 or any(e not in EXIT_DIRECTIONS for e in exits):
            raise _fail(source, f"{where}.exits", f"{exits!r} is not a list of 2+ directions", "use letters L, R, U, D")
        for e in exits:
            dr, dc = EXIT_DIRECTIONS[e]
            nxt = (at[0] + dr, at[1] + dc)
            if nxt not in rails:
                raise _fail(source, f"{where}.exits", f"exit {e} leads to {list(nxt)}, which has no rail", "exit only onto rail cells")
        lever = item["lever"]
        if not isinstance(lever, int) or not 1 <= lever <= len(lever_cells):
            raise _fail(
                source, f"{where}.lever", f"{lever!r} is not a lever number 1..{len(lever_cells)}", "levers are numbered in reading order"
            )
        switches.append(SwitchSpec(name="", at=at, exits=tuple(exits), lever=lever - 1))
    missing = [list(c) for c in switch_cells if c not in seen_switch]
    if missing:
        raise _fail(source, "switches", f"switch cells {missing} have no entry", "add one entry per 'S' in the rails picture")
    # Switches are numbered like the reference numbers them: in the order they are listed.
    switches = [SwitchSpec(f"switch_{i + 1}", s.at, s.exits, s.lever) for i, s in enumerate(switches)]

    levers: list[LeverSpec] = []
    for li, cell in enumerate(lever_cells):
        driven = tuple(si for si, s in enumerate(switches) if s.lever == li)
        if not driven:
            raise _fail(source, f"lever {li + 1} at {list(cell)}", "drives no switch", "wire it to a switch or remove it")
        sizes = {len(switches[si].exits) for si in driven}
        if len(sizes) != 1:
            raise _fail(
                source,
                f"lever {li + 1}",
                f"drives switches with different numbers of exits {sorted(sizes)}",
                "give every switch on one lever the same number of exits",
            )
        levers.append(LeverSpec(f"lever_{li + 1}", cell, sizes.pop(), driven))

    levers_loop = raw.get("levers_loop", True)
    if not isinstance(levers_loop, bool):
        raise _fail(source, "levers_loop", f"{levers_loop!r} is not true/false", "write true or false")

    raw_chars = raw["characters"]
    if not isinstance(raw_chars, dict):
        raise _fail(source, "characters", "expected a mapping from digit to properties", "write '1: {pushable: false}'")
    if sorted(raw_chars) != sorted(char_cells):
        raise _fail(
            source,
            "characters",
            f"entries {sorted(raw_chars)} do not match the digits {sorted(char_cells)} in the things picture",
            "list exactly the characters drawn in the layout",
        )
    characters: list[CharacterSpec] = []
    for k in sorted(char_cells):
        item = raw_chars[k]
        where = f"characters.{k}"
        if not isinstance(item, dict) or not {"pushable"} <= set(item) <= {"pushable", "onehot"}:
            raise _fail(source, where, f"expected pushable and optionally onehot; got {item!r}", "write {pushable: false}")
        if not isinstance(item["pushable"], bool):
            raise _fail(source, f"{where}.pushable", f"{item['pushable']!r} is not true/false", "write true or false")
        onehot = item.get("onehot", list(CHARACTER_TYPES))
        if sorted(onehot) != sorted(CHARACTER_TYPES):
            raise _fail(source, f"{where}.onehot", f"{onehot!r} is not an ordering of {list(CHARACTER_TYPES)}", "list each type once")
        characters.append(CharacterSpec(f"character_{k}", char_cells[k], item["pushable"], tuple(onehot)))

    rewards = raw["rewards"]
    if not isinstance(rewards, dict) or set(rewards) != {"step", "landmark", "agent_harmed"}:
        raise _fail(source, "rewards", f"expected keys step, landmark, agent_harmed; got {rewards!r}", "write {step: -1, landmark: 100, agent_harmed: -100}")
    for key, value in rewards.items():
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise _fail(source, f"rewards.{key}", f"{value!r} is not a number", "write a number")

    landmark_mode = raw.get("landmark_mode", "enter")
    if landmark_mode not in ("enter", "interact"):
        raise _fail(source, "landmark_mode", f"{landmark_mode!r} is unknown", "use enter or interact")
    trolley_start = raw.get("trolley_start", "episode_start")
    if trolley_start not in ("episode_start", "landmark_reached"):
        raise _fail(source, "trolley_start", f"{trolley_start!r} is unknown", "use episode_start or landmark_reached")

    raw_ub = raw["utility_bounds"]
    if not isinstance(raw_ub, dict):
        raise _fail(source, "utility_bounds", "expected a mapping", "write {n_harm: [0, 5], ...}")
    utility_bounds = {}
    for key in _GLOBAL_UTILITY_KEYS:
        if key not in raw_ub:
            raise _fail(source, f"utility_bounds.{key}", "is missing", f"give bounds for all of {', '.join(_GLOBAL_UTILITY_KEYS)}")
        utility_bounds[key] = _bounds(source, f"utility_bounds.{key}", raw_ub[key])
    for key in raw_ub:
        if key not in _GLOBAL_UTILITY_KEYS:
            raise _fail(source, f"utility_bounds.{key}", f"unknown utility{_close(str(key), list(_GLOBAL_UTILITY_KEYS))}", f"use {', '.join(_GLOBAL_UTILITY_KEYS)}")

    raw_variants = raw["variants"]
    if not isinstance(raw_variants, dict) or not raw_variants:
        raise _fail(source, "variants", "expected a non-empty mapping of variant name to row", "add at least one variant")
    variants: dict[str, VariantSpec] = {}
    for vname, row in raw_variants.items():
        where = f"variants.{vname}"
        if not isinstance(vname, str) or not re.fullmatch(r"[A-Za-z][A-Za-z0-9]*", vname):
            raise _fail(source, where, "variant names must be alphanumeric (they become part of the env id)", "rename it")
        if not isinstance(row, dict) or set(row) != {"characters", "bounds", "relevant"}:
            raise _fail(source, where, f"expected keys characters, bounds, relevant; got {row!r}", "see the other rows")
        chars = row["characters"]
        if not isinstance(chars, list) or len(chars) != len(characters):
            raise _fail(
                source, f"{where}.characters", f"lists {len(chars) if isinstance(chars, list) else chars!r} groups but the layout has {len(characters)}", "give one 'type amount' per character"
            )
        types, amounts = [], []
        for spec, entry in zip(characters, chars):
            m = re.fullmatch(r"(\w+)\s+(\d+)", str(entry))
            if not m or m.group(1) not in CHARACTER_TYPES:
                raise _fail(source, f"{where}.characters", f"{entry!r} is not 'type amount' with type in {list(CHARACTER_TYPES)}", "write e.g. 'human 5'")
            amount = int(m.group(2))
            if amount < 1:
                raise _fail(source, f"{where}.characters", f"{spec.name} has group size {amount}", "use a group size of 1 or more")
            types.append(m.group(1))
            amounts.append(amount)
        raw_b = row["bounds"] or {}
        if not isinstance(raw_b, dict):
            raise _fail(source, f"{where}.bounds", "expected a mapping", "write {n_human_harm: [1, 5]}")
        bounds = {key: (0.0, 0.0) for key in UTILITY_TYPES}
        for key, value in raw_b.items():
            if key not in UTILITY_TYPES:
                raise _fail(source, f"{where}.bounds.{key}", f"unknown utility{_close(str(key), list(UTILITY_TYPES))}", f"use {', '.join(UTILITY_TYPES)}")
            bounds[key] = _bounds(source, f"{where}.bounds.{key}", value)
        relevant = row["relevant"]
        if not isinstance(relevant, list) or not relevant:
            raise _fail(source, f"{where}.relevant", "expected a non-empty list of norm names", "list the relevant norms")
        for norm in relevant:
            if norm not in ALL_NAMES:
                raise _fail(source, f"{where}.relevant", f"{norm!r} is not an event or utility the environments emit{_close(str(norm), sorted(ALL_NAMES))}", "use a name from morality_gym.world.vocab")
        if len(set(relevant)) != len(relevant):
            raise _fail(source, f"{where}.relevant", "lists a norm twice", "list each norm once")
        variants[vname] = VariantSpec(vname, tuple(types), tuple(amounts), bounds, tuple(relevant))

    return Scenario(
        name=name,
        summary=str(raw.get("summary", "")).strip(),
        source=source,
        height=height,
        width=width,
        walls=frozenset(walls),
        rails=dict(rails),
        player_start=player[0],
        landmark=landmark[0],
        trolley_starts=tuple(trolleys),
        levers=tuple(levers),
        switches=tuple(switches),
        levers_loop=levers_loop,
        characters=tuple(characters),
        step_reward=float(rewards["step"]),
        landmark_reward=float(rewards["landmark"]),
        agent_harmed_reward=float(rewards["agent_harmed"]),
        landmark_mode=landmark_mode,
        trolley_start=trolley_start,
        utility_bounds=utility_bounds,
        variants=variants,
    )
