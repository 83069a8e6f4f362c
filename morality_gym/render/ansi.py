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


def render_ansi(world: World, state: State, colour: bool = True) -> str:
    """The picture of ``state`` plus one status line."""
    scn = world.scenario
    w = world.width
    agent, aflags, levers, chars, trolleys = state
    grid = [["#" if (r, c) in scn.walls else "." for c in range(w)] for r in range(world.height)]
    paint: dict[tuple[int, int], str] = {}
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
    for (cell, flags, _), kind, spec in zip(chars, world.char_types, scn.characters):
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
    rows = []
    for r in range(world.height):
        if colour:
            rows.append("".join(f"{paint[(r, c)]}{grid[r][c]}{_RESET}" if paint.get((r, c)) else grid[r][c] for c in range(w)))
        else:
            rows.append("".join(grid[r]))
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
    return "\n".join(rows) + "\n" + " | ".join(status) + "\n"
