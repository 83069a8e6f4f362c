"""The ``ansi`` rendering: the current state as the ASCII picture of the scenario files.

Glyphs as in ``Scenario.picture`` (agent ``P``, trolley ``T``, groups ``h a r`` / ``H A R`` when
pushable, landmark ``G``, lever ``/``, switch ``S``, rails ``< > ^ v``, wall ``#``), with the
state on top: switches show the direction they are set to, harmed entities are marked ``x``
(``X`` for the agent), a stopped trolley is ``t``, and a status line lists lever states and the
group sizes. With ``colour=True`` ANSI colours make harmed entities red and the agent bold.
"""

from __future__ import annotations

from morality_gym.world.rules import FOUND, HARMED, TERMINATED, State, World

_SWITCH_GLYPH = {"L": "<", "R": ">", "U": "^", "D": "v"}
_RED, _BOLD, _GREEN, _YELLOW, _RESET = "\x1b[31m", "\x1b[1m", "\x1b[32m", "\x1b[33m", "\x1b[0m"


_Grid = list[list[str]]
_Paint = dict[tuple[int, int], str]


def render_ansi(world: World, state: State, colour: bool = True) -> str:
    """The picture of ``state`` plus one status line.

    Drawn in layers, each later one on top: the fixed scenery (walls, rails, switches, levers,
    landmark), then the moving entities (groups, trolleys, the agent last).
    """
    grid, paint = _scenery(world, state[2])
    _draw_entities(world, state, grid, paint)
    return "\n".join(_rows(grid, paint, colour)) + "\n" + " | ".join(_status(world, state)) + "\n"


def _scenery(world: World, levers: tuple[int, ...]) -> tuple[_Grid, _Paint]:
    """Walls, rails, switches (showing the direction their lever sets), levers and the landmark."""
    scn = world.scenario
    grid = [["#" if (r, c) in scn.walls else "." for c in range(world.width)] for r in range(world.height)]
    paint: _Paint = {}
    for (r, c), glyph in scn.rails.items():
        grid[r][c] = glyph
    for sw in scn.switches:
        r, c = sw.at
        grid[r][c] = _SWITCH_GLYPH[sw.exits[levers[sw.lever]]]
        paint[(r, c)] = _YELLOW
    for lever in scn.levers:
        grid[lever.at[0]][lever.at[1]] = "/"
        paint[lever.at] = _YELLOW
    lr, lc = scn.landmark
    grid[lr][lc] = "G"
    paint[(lr, lc)] = _GREEN
    return grid, paint


def _draw_entities(world: World, state: State, grid: _Grid, paint: _Paint) -> None:
    """Groups, trolleys and the agent on top of the scenery, harmed ones in red."""
    w = world.width
    agent, aflags, _, chars, trolleys = state
    for (cell, flags, _), kind, spec in zip(chars, world.char_types, world.scenario.characters):
        r, c = divmod(cell, w)
        letter = kind[0].upper() if spec.pushable else kind[0]
        grid[r][c] = "x" if flags & HARMED else letter
        paint[(r, c)] = _RED if flags & HARMED else ""
    for cell, flags in trolleys:
        r, c = divmod(cell, w)
        grid[r][c] = "T" if not flags & TERMINATED else "t"
        paint[(r, c)] = _RED if flags & HARMED else _BOLD
    r, c = divmod(agent, w)
    grid[r][c] = "X" if aflags & HARMED else "P"
    paint[(r, c)] = _RED if aflags & HARMED else _BOLD


def _rows(grid: _Grid, paint: _Paint, colour: bool) -> list[str]:
    """The picture's rows, each painted glyph wrapped in its colour when ``colour``."""
    if not colour:
        return ["".join(row) for row in grid]
    return ["".join(f"{paint[(r, c)]}{glyph}{_RESET}" if paint.get((r, c)) else glyph for c, glyph in enumerate(row))
            for r, row in enumerate(grid)]


def _status(world: World, state: State) -> list[str]:
    """The status line's parts: lever positions, the groups (harmed or not), the agent's end."""
    scn = world.scenario
    _, aflags, levers, chars, _ = state
    status = []
    if levers:
        status.append(" ".join(f"{lv.name}={s}" for lv, s in zip(scn.levers, levers)))
    status.append(
        " ".join(
            f"{spec.name[-1]}:{kind} {amount}{' harmed' if flags & HARMED else ''}"
            for spec, kind, amount, (_, flags, _) in zip(scn.characters, world.char_types, world.char_amounts, chars)
        )
    )
    if aflags & FOUND:
        status.append("landmark reached")
    elif aflags & HARMED:
        status.append("agent harmed")
    return status
