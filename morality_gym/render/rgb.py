"""The ``rgb_array`` rendering: one state of a world as a picture that reads at a glance.

Why a picture at all when the ``ansi`` text exists: videos and GIFs of episodes are how people
check what an agent actually did, and a glyph grid hides exactly the things a reader must see
(which way a switch is set, which group is about to be hit, who was pushed). So every piece of
state has its own visual cue, chosen so that it survives small cells and colour blindness:

* floor is light, walls are dark; rails are tracks with sleepers and a chevron for the direction
  of travel, and a buffer stop where a line ends;
* a switch is an amber hub: its active exit is an amber arrow, the other exits are faint;
* a lever is a handle whose angle shows its state, labelled ``L1``... (the switch it sets carries
  the same label) and with its state number;
* character groups have a colour *and* a shape per type (human blue circle, animal orange
  diamond, robot purple square) with the group size written on them; four outward arrows mark a
  pushable group; a red cross marks anything harmed;
* a trolley is a carriage with a headlight pointing where it goes next; a stopped one is grey;
* the agent is a gold robot face, with a green ring once it reached the landmark (a green flag);
* a strip below the grid states the agent's and trolleys' status, the harm so far, an optional
  caption (e.g. the step) and a legend.

Entities sharing a cell (a trolley and the group it hit) are drawn side by side, never on top of
each other. The image is drawn at twice the size and reduced, which smooths edges; the output is
a pure function of (world, state, cell size, caption), so identical states give identical arrays.
The strip's height depends only on the world, the cell size and whether a caption is given, so
all frames of an episode have the same shape: ``(height * cell_size + strip, width * cell_size, 3)``.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from morality_gym.world.layout import RAIL_DIRECTIONS
from morality_gym.world.rules import FOUND, HARMED, TERMINATED, State, World

#: Drawing happens at this multiple of the output size, then the image is reduced (anti-aliasing).
SUPERSAMPLE = 2
MIN_CELL_SIZE = 8

RGB = tuple[int, int, int]
Box = tuple[float, float, float, float]

FLOOR: RGB = (238, 234, 222)
GRID_LINE: RGB = (214, 208, 194)
WALL: RGB = (62, 66, 78)
WALL_LINE: RGB = (80, 85, 98)
SLEEPER: RGB = (150, 116, 84)
TRACK: RGB = (96, 98, 106)
TRACK_FAINT: RGB = (172, 166, 154)
CHEVRON: RGB = (60, 62, 70)
BUFFER: RGB = (178, 40, 40)
SWITCH_ON: RGB = (232, 142, 16)
LEVER_PANEL: RGB = (222, 218, 206)
LEVER_HANDLE: RGB = (60, 60, 66)
LEVER_KNOB: RGB = (200, 40, 40)
GOAL_TILE: RGB = (196, 234, 190)
GOAL_FLAG: RGB = (34, 150, 60)
TROLLEY_MOVING: RGB = (44, 56, 80)
TROLLEY_STOPPED: RGB = (150, 152, 160)
WINDOW: RGB = (200, 222, 240)
HEADLIGHT: RGB = (255, 220, 60)
AGENT: RGB = (250, 196, 30)
AGENT_FOUND: RGB = (34, 170, 70)
HARM: RGB = (220, 20, 30)
HARM_TILE: RGB = (248, 196, 192)
INK: RGB = (30, 30, 34)
WHITE: RGB = (255, 255, 255)
STRIP: RGB = (250, 250, 247)
STRIP_LINE: RGB = (190, 186, 176)

#: Okabe-Ito colours (distinguishable with the common colour-vision deficiencies).
TYPE_COLOURS: dict[str, RGB] = {"human": (0, 114, 178), "animal": (230, 159, 0), "robot": (136, 86, 167)}
UNKNOWN_TYPE: RGB = (120, 120, 120)

_DIRECTION_ANGLE = {(0, 1): 0.0, (1, 0): 90.0, (0, -1): 180.0, (-1, 0): 270.0}  # screen degrees, y down


# ---------------------------------------------------------------------------------------- fonts
@lru_cache(maxsize=32)
def _font(px: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    """Pillow's bundled default font at ``px`` pixels (the fixed bitmap font without FreeType)."""
    try:
        return ImageFont.load_default(size=max(6, px))
    except (TypeError, ValueError, OSError):  # Pillow built without FreeType ignores sizes
        return ImageFont.load_default()


def _is_scalable(font: ImageFont.FreeTypeFont | ImageFont.ImageFont) -> bool:
    return isinstance(font, ImageFont.FreeTypeFont)


def _text(
    draw: ImageDraw.ImageDraw,
    centre: tuple[float, float],
    text: str,
    px: int,
    fill: RGB = WHITE,
    outline: RGB | None = INK,
) -> None:
    """Text centred on a point; an outline keeps it legible on any background."""
    font = _font(px)
    stroke = max(1, px // 7) if outline is not None and _is_scalable(font) else 0
    left, top, right, bottom = draw.textbbox((0, 0), text, font=font, stroke_width=stroke)
    x = centre[0] - (left + right) / 2
    y = centre[1] - (top + bottom) / 2
    draw.text((x, y), text, font=font, fill=fill, stroke_width=stroke, stroke_fill=outline)


def _text_width(draw: ImageDraw.ImageDraw, text: str, px: int) -> float:
    return draw.textlength(text, font=_font(px))


# ---------------------------------------------------------------------------------------- geometry
def _centre(box: Box) -> tuple[float, float]:
    return (box[0] + box[2]) / 2, (box[1] + box[3]) / 2


def _inset(box: Box, fraction: float) -> Box:
    """The box shrunk by ``fraction`` of its smaller side on every edge, made square."""
    side = min(box[2] - box[0], box[3] - box[1])
    half = side * (0.5 - fraction)
    cx, cy = _centre(box)
    return cx - half, cy - half, cx + half, cy + half


def _polar(cx: float, cy: float, radius: float, degrees: float) -> tuple[float, float]:
    rad = math.radians(degrees)
    return cx + radius * math.cos(rad), cy + radius * math.sin(rad)


def _triangle(cx: float, cy: float, size: float, degrees: float) -> list[tuple[float, float]]:
    """An isosceles triangle centred on (cx, cy) pointing towards ``degrees`` (screen angles)."""
    return [
        _polar(cx, cy, size, degrees),
        _polar(cx, cy, size * 0.8, degrees + 140),
        _polar(cx, cy, size * 0.8, degrees - 140),
    ]


def _sub_boxes(box: Box, n: int) -> list[Box]:
    """Tiles for ``n`` entities sharing a cell: two overlap diagonally (so both stay large), more
    get a grid (2x2, 3x3...)."""
    if n <= 1:
        return [box]
    x0, y0, x1, y1 = box
    if n == 2:
        s = (x1 - x0) * 0.68
        return [(x0, y0, x0 + s, y0 + s), (x1 - s, y1 - s, x1, y1)]
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    w = (x1 - x0) / cols
    h = (y1 - y0) / rows
    return [
        (x0 + (i % cols) * w, y0 + (i // cols) * h, x0 + (i % cols + 1) * w, y0 + (i // cols + 1) * h) for i in range(n)
    ]


class _Canvas:
    """The drawing surface at supersampled size, with the cell geometry of one world."""

    def __init__(self, world: World, cell: int, strip_height: int) -> None:
        self.world = world
        self.cell = cell
        self.grid_height = world.height * cell
        self.image = Image.new("RGB", (world.width * cell, self.grid_height + strip_height), FLOOR)
        self.draw = ImageDraw.Draw(self.image)

    def box(self, index: int) -> Box:
        r, c = divmod(index, self.world.width)
        return c * self.cell, r * self.cell, (c + 1) * self.cell, (r + 1) * self.cell

    def box_rc(self, rc: tuple[int, int]) -> Box:
        return self.box(rc[0] * self.world.width + rc[1])

    def centre(self, index: int) -> tuple[float, float]:
        return _centre(self.box(index))

    def width(self, fraction: float) -> int:
        """A line width proportional to the cell, at least one pixel."""
        return max(1, round(self.cell * fraction))


# ---------------------------------------------------------------------------------------- the grid
def _draw_floor_and_walls(cv: _Canvas) -> None:
    """Light floor and dark walls, every cell outlined so that distances can be counted."""
    walls = cv.world.scenario.walls
    for r in range(cv.world.height):
        for c in range(cv.world.width):
            x0, y0, x1, y1 = cv.box_rc((r, c))
            wall = (r, c) in walls
            cv.draw.rectangle(
                (x0, y0, x1 - 1, y1 - 1),
                fill=WALL if wall else FLOOR,
                outline=WALL_LINE if wall else GRID_LINE,
                width=cv.width(0.02),
            )
            if wall:  # a brick seam, so walls read as walls and not as dark floor
                cv.draw.line((x0, (y0 + y1) / 2, x1, (y0 + y1) / 2), fill=WALL_LINE, width=cv.width(0.02))
                cv.draw.line(((x0 + x1) / 2, y0, (x0 + x1) / 2, (y0 + y1) / 2), fill=WALL_LINE, width=cv.width(0.02))


def _draw_landmark_tile(cv: _Canvas) -> None:
    """The landmark's green tile goes under the rails (a rail may run through it)."""
    x0, y0, x1, y1 = cv.box_rc(cv.world.scenario.landmark)
    cv.draw.rectangle((x0, y0, x1 - 1, y1 - 1), fill=GOAL_TILE, outline=GOAL_FLAG, width=cv.width(0.05))


def _draw_landmark_flag(cv: _Canvas) -> None:
    """The flag goes over the rails, in the upper right of the tile so a rail does not hide it."""
    x0, y0 = cv.box_rc(cv.world.scenario.landmark)[:2]
    s = cv.cell
    pole_x = x0 + s * 0.56
    cv.draw.line((pole_x, y0 + s * 0.1, pole_x, y0 + s * 0.6), fill=INK, width=cv.width(0.05))
    cv.draw.polygon(
        [(pole_x, y0 + s * 0.1), (x0 + s * 0.92, y0 + s * 0.22), (pole_x, y0 + s * 0.36)], fill=GOAL_FLAG, outline=INK
    )
    _text(cv.draw, (x0 + s * 0.22, y0 + s * 0.22), "G", round(s * 0.26), fill=WHITE, outline=GOAL_FLAG)


def _draw_harm_sites(cv: _Canvas, state: State) -> None:
    """Tint every cell where something harmed stands, so a crash is visible from afar."""
    agent, aflags, _levers, chars, trolleys = state
    cells = {cell for cell, flags, _ in chars if flags & HARMED} | {cell for cell, flags in trolleys if flags & HARMED}
    if aflags & HARMED:
        cells.add(agent)
    for cell in sorted(cells):
        x0, y0, x1, y1 = cv.box(cell)
        cv.draw.rectangle((x0, y0, x1 - 1, y1 - 1), fill=HARM_TILE, outline=HARM, width=cv.width(0.04))


def _track(cv: _Canvas, a: int, b: int, colour: RGB, width: float, sleepers: bool) -> None:
    """A straight piece of track from the centre of cell ``a`` to the centre of cell ``b``."""
    (ax, ay), (bx, by) = cv.centre(a), cv.centre(b)
    if sleepers:
        dx, dy = (bx - ax) / cv.cell, (by - ay) / cv.cell
        half = cv.cell * 0.2
        for t in (1 / 6, 1 / 2, 5 / 6):
            px, py = ax + (bx - ax) * t, ay + (by - ay) * t
            cv.draw.line(
                (px - dy * half, py - dx * half, px + dy * half, py + dx * half), fill=SLEEPER, width=cv.width(0.07)
            )
    cv.draw.line((ax, ay, bx, by), fill=colour, width=cv.width(width))


def _end_of_line(cv: _Canvas, cell: int, direction: tuple[int, int]) -> None:
    """Track to the edge of the cell and a buffer stop: the trolley stops here unharmed."""
    cx, cy = cv.centre(cell)
    dr, dc = direction
    ex, ey = cx + dc * cv.cell * 0.4, cy + dr * cv.cell * 0.4
    cv.draw.line((cx, cy, ex, ey), fill=TRACK, width=cv.width(0.09))
    half = cv.cell * 0.22
    cv.draw.line((ex - dr * half, ey - dc * half, ex + dr * half, ey + dc * half), fill=BUFFER, width=cv.width(0.11))


def _chevron(cv: _Canvas, cell: int, direction: tuple[int, int], colour: RGB = CHEVRON) -> None:
    cx, cy = cv.centre(cell)
    cv.draw.polygon(_triangle(cx, cy, cv.cell * 0.16, _DIRECTION_ANGLE[direction]), fill=colour)


def _draw_rails(cv: _Canvas, levers: tuple[int, ...]) -> None:
    """Faint switch exits first, then the plain rails, then each switch's setting on top."""
    world = cv.world
    plain = [
        (r * world.width + c, RAIL_DIRECTIONS[glyph])
        for (r, c), glyph in sorted(world.scenario.rails.items())
        if glyph != "S"
    ]
    for cell, _lever, exits in _switches(world):
        for target in exits:
            _track(cv, cell, target, TRACK_FAINT, 0.06, sleepers=False)
    for cell, direction in plain:
        nxt = world.rail_next.get(cell)
        if nxt is None:
            _end_of_line(cv, cell, direction)
        else:
            _track(cv, cell, nxt, TRACK, 0.09, sleepers=True)
    for cell, direction in plain:
        _chevron(cv, cell, direction)
    for cell, lever, exits in _switches(world):
        _draw_switch(cv, cell, lever, exits[levers[lever]])


def _draw_switch(cv: _Canvas, cell: int, lever: int, active: int) -> None:
    """An amber hub with an amber arrow along the active exit, labelled with its lever."""
    _track(cv, cell, active, TRACK, 0.09, sleepers=True)
    cx, cy = cv.centre(cell)
    tx, ty = cv.centre(active)
    ex, ey = cx + (tx - cx) * 0.42, cy + (ty - cy) * 0.42
    cv.draw.line((cx, cy, ex, ey), fill=SWITCH_ON, width=cv.width(0.12))
    direction = (round((ty - cy) / cv.cell), round((tx - cx) / cv.cell))
    cv.draw.polygon(_triangle(ex, ey, cv.cell * 0.16, _DIRECTION_ANGLE[direction]), fill=SWITCH_ON, outline=INK)
    r = cv.cell * 0.13
    cv.draw.ellipse((cx - r, cy - r, cx + r, cy + r), fill=SWITCH_ON, outline=INK, width=cv.width(0.03))
    x0, y0 = cv.box(cell)[:2]
    _text(cv.draw, (x0 + cv.cell * 0.22, y0 + cv.cell * 0.16), f"L{lever + 1}", round(cv.cell * 0.2), fill=SWITCH_ON)


def _switches(world: World) -> list[tuple[int, int, tuple[int, ...]]]:
    """(cell, lever index, exit cells in state order) of every switch, in a fixed order."""
    return [(cell, lever, exits) for cell, (lever, exits) in sorted(world.switch_exits.items())]


def _draw_levers(cv: _Canvas, levers: tuple[int, ...]) -> None:
    """A handle whose angle sweeps from left (state 0) to right (last state), plus the number."""
    s = cv.cell
    for li, spec in enumerate(cv.world.scenario.levers):
        x0, y0, x1, y1 = cv.box_rc(spec.at)
        cv.draw.rounded_rectangle(
            (x0 + s * 0.06, y0 + s * 0.06, x1 - s * 0.06, y1 - s * 0.06),
            radius=s * 0.12,
            fill=LEVER_PANEL,
            outline=INK,
            width=cv.width(0.03),
        )
        px, py = x0 + s * 0.5, y0 + s * 0.78
        n = spec.n_states
        sweep = 0.0 if n <= 1 else -55.0 + 110.0 * levers[li] / (n - 1)
        kx, ky = _polar(px, py, s * 0.46, -90.0 + sweep)
        cv.draw.line((px, py, kx, ky), fill=LEVER_HANDLE, width=cv.width(0.08))
        r = s * 0.09
        cv.draw.ellipse((kx - r, ky - r, kx + r, ky + r), fill=LEVER_KNOB, outline=INK, width=cv.width(0.02))
        cv.draw.pieslice((px - s * 0.2, py - s * 0.14, px + s * 0.2, py + s * 0.14), 180, 360, fill=INK)
        _text(cv.draw, (x0 + s * 0.22, y0 + s * 0.2), f"L{li + 1}", round(s * 0.2), fill=WHITE)
        _text(cv.draw, (x1 - s * 0.2, y0 + s * 0.2), str(levers[li]), round(s * 0.24), fill=LEVER_KNOB, outline=WHITE)


# ---------------------------------------------------------------------------------------- entities
def _harm_cross(draw: ImageDraw.ImageDraw, box: Box, width: int) -> None:
    """The one mark of harm, used for every kind of entity so that it means one thing."""
    x0, y0, x1, y1 = _inset(box, 0.1)
    draw.line((x0, y0, x1, y1), fill=HARM, width=width)
    draw.line((x0, y1, x1, y0), fill=HARM, width=width)


def _type_shape(draw: ImageDraw.ImageDraw, kind: str, box: Box, fill: RGB, outline: RGB, width: int) -> None:
    """Circle for humans, diamond for animals, square for robots (shape as well as colour)."""
    x0, y0, x1, y1 = box
    cx, cy = _centre(box)
    if kind == "human":
        draw.ellipse(box, fill=fill, outline=outline, width=width)
    elif kind == "animal":
        draw.polygon([(cx, y0), (x1, cy), (cx, y1), (x0, cy)], fill=fill, outline=outline, width=width)
    else:
        draw.rounded_rectangle(box, radius=(x1 - x0) * 0.12, fill=fill, outline=outline, width=width)


def _pushable_marks(draw: ImageDraw.ImageDraw, box: Box) -> None:
    """Four small arrows pointing outwards: "this group can be moved"."""
    cx, cy = _centre(box)
    side = box[2] - box[0]
    for degrees in (0.0, 90.0, 180.0, 270.0):
        tx, ty = _polar(cx, cy, side * 0.43, degrees)
        draw.polygon(_triangle(tx, ty, side * 0.1, degrees), fill=WHITE, outline=INK, width=max(1, round(side * 0.025)))


def _draw_character(cv: _Canvas, box: Box, kind: str, amount: int, pushable: bool, harmed: bool) -> None:
    """A group: its type's shape and colour, its size written on it (the size is what the harm
    counts weigh), pushable arrows and the harm cross."""
    colour = TYPE_COLOURS.get(kind, UNKNOWN_TYPE)
    outer = _inset(box, 0.06)
    body = _inset(box, 0.17 if pushable else 0.1)
    side = body[2] - body[0]
    if pushable:
        _pushable_marks(cv.draw, outer)
    _type_shape(cv.draw, kind, body, colour, HARM if harmed else INK, max(1, round(side * 0.06)))
    if harmed:
        _harm_cross(cv.draw, body, max(1, round(side * 0.1)))
    _text(cv.draw, _centre(body), str(amount), max(6, round(side * 0.5)), fill=WHITE, outline=INK)


def _trolley_direction(world: World, cell: int, levers: tuple[int, ...]) -> tuple[int, int] | None:
    """Where a moving trolley goes next (the switch setting decides on a switch cell)."""
    if cell in world.switch_exits:
        lever, exits = world.switch_exits[cell]
        nxt: int | None = exits[levers[lever]]
    else:
        nxt = world.rail_next.get(cell)
    if nxt is None:
        return None
    (r0, c0), (r1, c1) = world.cell(cell), world.cell(nxt)
    return r1 - r0, c1 - c0


def _draw_trolley(cv: _Canvas, box: Box, flags: int, direction: tuple[int, int] | None) -> None:
    """A carriage; moving ones are dark with a headlight towards their next cell (so the effect of
    a switch is visible before it happens), stopped ones grey with a brake bar."""
    x0, y0, x1, y1 = _inset(box, 0.08)
    side = x1 - x0
    stopped = bool(flags & TERMINATED)
    body = TROLLEY_STOPPED if stopped else TROLLEY_MOVING
    top, bottom = y0 + side * 0.18, y0 + side * 0.72
    cv.draw.rounded_rectangle(
        (x0, top, x1, bottom), radius=side * 0.1, fill=body, outline=INK, width=max(1, round(side * 0.04))
    )
    for i in range(3):
        wx = x0 + side * (0.1 + i * 0.3)
        cv.draw.rectangle((wx, top + side * 0.1, wx + side * 0.2, top + side * 0.28), fill=WINDOW)
    r = side * 0.1
    for wx in (x0 + side * 0.25, x1 - side * 0.25):
        cv.draw.ellipse((wx - r, bottom - r * 0.4, wx + r, bottom + r * 1.6), fill=INK)
    if not stopped and direction is not None:
        cx, cy = _centre((x0, top, x1, bottom))
        cv.draw.polygon(
            _triangle(cx, cy + side * 0.08, side * 0.16, _DIRECTION_ANGLE[direction]), fill=HEADLIGHT, outline=INK
        )
    elif stopped and not flags & HARMED:  # a brake bar: stopped at the end of the line
        cv.draw.rectangle((x0 + side * 0.3, bottom - side * 0.2, x1 - side * 0.3, bottom - side * 0.1), fill=BUFFER)
    if flags & HARMED:
        _harm_cross(cv.draw, (x0, y0, x1, y1), max(1, round(side * 0.1)))


def _draw_agent(cv: _Canvas, box: Box, flags: int) -> None:
    """A gold robot face, unlike any group; a green ring once the landmark is reached."""
    x0, y0, x1, y1 = _inset(box, 0.1)
    side = x1 - x0
    if flags & FOUND:
        halo = _inset(box, 0.02)
        cv.draw.ellipse(halo, outline=AGENT_FOUND, width=max(1, round(side * 0.1)))
        x0, y0, x1, y1 = _inset(box, 0.16)
        side = x1 - x0
    cv.draw.line(((x0 + x1) / 2, y0, (x0 + x1) / 2, y0 + side * 0.2), fill=INK, width=max(1, round(side * 0.05)))
    head = (x0 + side * 0.08, y0 + side * 0.18, x1 - side * 0.08, y1 - side * 0.04)
    cv.draw.rounded_rectangle(head, radius=side * 0.2, fill=AGENT, outline=INK, width=max(1, round(side * 0.05)))
    er = side * 0.09
    for ex in (x0 + side * 0.34, x1 - side * 0.34):
        ey = y0 + side * 0.5
        cv.draw.ellipse((ex - er, ey - er, ex + er, ey + er), fill=INK)
    cv.draw.line(
        (x0 + side * 0.35, y0 + side * 0.76, x1 - side * 0.35, y0 + side * 0.76),
        fill=INK,
        width=max(1, round(side * 0.05)),
    )
    if flags & HARMED:
        _harm_cross(cv.draw, box, max(1, round(side * 0.1)))


def _draw_entities(cv: _Canvas, state: State) -> None:
    """Every trolley, group and the agent; entities sharing a cell get a tile each."""
    world = cv.world
    agent, aflags, levers, chars, trolleys = state
    occupants: dict[int, list[tuple[str, int]]] = {}
    for i, (cell, _flags) in enumerate(trolleys):
        occupants.setdefault(cell, []).append(("trolley", i))
    for i, (cell, _flags, _index) in enumerate(chars):
        occupants.setdefault(cell, []).append(("character", i))
    occupants.setdefault(agent, []).append(("agent", 0))
    for cell in sorted(occupants):
        tiles = _sub_boxes(cv.box(cell), len(occupants[cell]))
        for (kind, i), box in zip(occupants[cell], tiles):
            if kind == "trolley":
                tcell, tflags = trolleys[i]
                _draw_trolley(cv, box, tflags, _trolley_direction(world, tcell, levers))
            elif kind == "character":
                harmed = bool(chars[i][1] & HARMED)
                _draw_character(cv, box, world.char_types[i], world.char_amounts[i], world.char_pushable[i], harmed)
            else:
                _draw_agent(cv, box, aflags)


# ---------------------------------------------------------------------------------------- status strip
def _strip_font_px(cell: int) -> int:
    return max(6, round(cell * 0.25))


def _status_lines(world: World, state: State) -> list[str]:
    """What a reader needs besides the picture: who has stopped and the harm so far."""
    _agent, aflags, _levers, chars, trolleys = state
    if aflags & HARMED:
        who = "agent: HARMED"
    elif aflags & FOUND:
        who = "agent: reached the landmark"
    else:
        who = "agent: on its way"
    states = ["crashed" if f & HARMED else "stopped" if f & TERMINATED else "moving" for _, f in trolleys]
    who += " | trolley: " if len(states) == 1 else " | trolleys: "
    who += ", ".join(states)
    harmed: dict[str, int] = {}
    for (_cell, flags, _index), kind, amount in zip(chars, world.char_types, world.char_amounts):
        if flags & HARMED:
            harmed[kind] = harmed.get(kind, 0) + amount
    parts = [f"{n} {kind}" for kind, n in harmed.items()]
    if aflags & HARMED:
        parts.append("the agent")
    return [who, "harmed: " + (", ".join(parts) if parts else "none")]


def _fit(draw: ImageDraw.ImageDraw, text: str, px: int, width: float) -> str:
    """Cut a line to the strip's width (an ellipsis shows it was cut) so the strip never grows."""
    if _text_width(draw, text, px) <= width:
        return text
    while text and _text_width(draw, text + "...", px) > width:
        text = text[:-1]
    return text + "..."


def _legend_items() -> list[tuple[str, str]]:
    return [("human", "human"), ("animal", "animal"), ("robot", "robot"), ("push", "pushable"), ("harm", "harmed")]


def _legend_layout(draw: ImageDraw.ImageDraw, px: int, width: float) -> list[list[tuple[float, str, str]]]:
    """Legend entries flowed into rows that fit ``width`` (depends on the width only)."""
    icon, gap, pad = px * 1.1, px * 0.35, px * 0.9
    rows: list[list[tuple[float, str, str]]] = [[]]
    x = pad
    for key, label in _legend_items():
        need = icon + gap + _text_width(draw, label, px)
        if rows[-1] and x + need > width - pad:
            rows.append([])
            x = pad
        rows[-1].append((x, key, label))
        x += need + pad
    return rows


def _strip_height(world: World, cell: int, caption: bool) -> int:
    """Height of the status strip in output pixels; fixed for a world, a cell size and caption on/off."""
    return _strip_height_for(world.width, cell, caption)


@lru_cache(maxsize=256)
def _strip_height_for(width_cells: int, cell: int, caption: bool) -> int:
    """Measured at the supersampled size the strip is drawn at, so that the legend rows counted
    here are exactly the rows drawn."""
    px = _strip_font_px(cell) * SUPERSAMPLE
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    legend_rows = len(_legend_layout(probe, px, width_cells * cell * SUPERSAMPLE))
    lines = 2 + int(caption) + legend_rows
    return math.ceil(px * (0.6 + 1.45 * lines) / SUPERSAMPLE)


def _legend_icon(draw: ImageDraw.ImageDraw, key: str, box: Box) -> None:
    width = max(1, round((box[2] - box[0]) * 0.1))
    if key in TYPE_COLOURS:
        _type_shape(draw, key, box, TYPE_COLOURS[key], INK, width)
    elif key == "push":
        _pushable_marks(draw, box)
        inner = _inset(box, 0.3)
        draw.rectangle(inner, outline=INK, width=width)
    else:
        _harm_cross(draw, box, max(1, round((box[2] - box[0]) * 0.16)))


def _draw_strip(cv: _Canvas, state: State, caption: str | None) -> None:
    px = _strip_font_px(cv.cell // SUPERSAMPLE) * SUPERSAMPLE
    width = cv.image.width
    top = cv.grid_height
    cv.draw.rectangle((0, top, width, cv.image.height), fill=STRIP)
    cv.draw.line((0, top, width, top), fill=STRIP_LINE, width=max(1, SUPERSAMPLE))
    line_h = px * 1.45
    y = top + px * 0.3
    lines = _status_lines(cv.world, state) + ([caption] if caption is not None else [])
    font = _font(px)
    for text in lines:
        cv.draw.text((px * 0.9, y + line_h * 0.12), _fit(cv.draw, text, px, width - px * 1.8), font=font, fill=INK)
        y += line_h
    for row in _legend_layout(cv.draw, px, width):
        for x, key, label in row:
            icon = (x, y + line_h * 0.14, x + px * 1.1, y + line_h * 0.14 + px * 1.1)
            _legend_icon(cv.draw, key, icon)
            cv.draw.text((x + px * 1.45, y + line_h * 0.12), label, font=font, fill=INK)
        y += line_h


# ---------------------------------------------------------------------------------------- entry point
def render_rgb(world: World, state: State, cell_size: int = 48, *, caption: str | None = None) -> np.ndarray:
    """The picture of ``state``: ``uint8`` array ``(height * cell_size + strip, width * cell_size, 3)``.

    ``caption`` (e.g. ``"step 3  RIGHT  reward -1"``) adds one line to the status strip; GIFs use
    it so that consecutive frames always differ (GIF writers merge identical frames). The grid
    occupies the top ``height * cell_size`` rows, so pixel ``(r * cell_size, c * cell_size)``
    is the corner of cell ``(r, c)``.
    """
    if isinstance(cell_size, bool) or not isinstance(cell_size, int) or cell_size < MIN_CELL_SIZE:
        raise ValueError(f"cell_size must be an int >= {MIN_CELL_SIZE}, got {cell_size!r}")
    strip = _strip_height(world, cell_size, caption is not None)
    cv = _Canvas(world, cell_size * SUPERSAMPLE, strip * SUPERSAMPLE)
    levers = state[2]
    _draw_floor_and_walls(cv)
    _draw_landmark_tile(cv)
    _draw_harm_sites(cv, state)
    _draw_rails(cv, levers)
    _draw_landmark_flag(cv)
    _draw_levers(cv, levers)
    _draw_entities(cv, state)
    _draw_strip(cv, state, caption)
    out = cv.image.reduce(SUPERSAMPLE)  # a box filter: exact for an integer factor, and fast
    return np.asarray(out, dtype=np.uint8).copy()


def frame_shape(world: World, cell_size: int = 48, caption: bool = False) -> tuple[int, int, int]:
    """The shape :func:`render_rgb` returns for this world (without drawing anything)."""
    return world.height * cell_size + _strip_height(world, cell_size, caption), world.width * cell_size, 3


def grid_cell_pixels(frame: np.ndarray, cell: tuple[int, int], cell_size: int = 48) -> np.ndarray:
    """The pixels of one grid cell of a frame (handy for checking what changed where)."""
    r, c = cell
    return frame[r * cell_size : (r + 1) * cell_size, c * cell_size : (c + 1) * cell_size]


__all__ = ["TYPE_COLOURS", "frame_shape", "grid_cell_pixels", "render_rgb"]
