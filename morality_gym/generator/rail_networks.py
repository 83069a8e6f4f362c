"""Rail networks: the junction trees of the grammar and where their rails go on the grid.

Every built-in scenario's rails are one shape: a trolley comes along a line from the right, meets
a switch near the left edge, and each of the switch's exits leads either to the end of a line
(where a group stands) or to a further switch one column to the left (Switch5, Switch7). A
:class:`Junction` is such a switch and :class:`Leaf` the end of a line; :func:`place` draws a tree
on a :class:`Canvas` as the built-in files draw theirs:

* exit ``L`` continues on the switch's row, one column to the left;
* exit ``U`` (``D``) enters a rail ``<`` just above (below) the switch, which leads one column left;
* a leaf is a run of ``<`` to column 0, whose last cell is the end of the line.

So that subtrees never overlap, only the ``U`` and ``D`` children of a switch may be switches
themselves, and those have the exits ``L``/``U`` (above) or ``L``/``D`` (below) only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

Cell = tuple[int, int]


@dataclass(frozen=True)
class Leaf:
    """The end of a line."""


@dataclass(frozen=True)
class Junction:
    """A switch: its exits in state order (state 0, the default route, first) and the tree behind each."""

    exits: tuple[str, ...]
    children: tuple[tuple[str, Leaf | Junction], ...]

    def child(self, exit_letter: str) -> Leaf | Junction:
        return dict(self.children)[exit_letter]


Node = Leaf | Junction


def depth(node: Node) -> int:
    """Switches on the longest route: the column a tree's root switch stands in."""
    if isinstance(node, Leaf):
        return 0
    return 1 + max(depth(child) for _, child in node.children)


def extent_up(node: Node) -> int:
    """Rows the tree reaches above its root's row."""
    if isinstance(node, Leaf) or "U" not in node.exits:
        return 0
    return 1 + extent_up(node.child("U"))


def extent_down(node: Node) -> int:
    """Rows the tree reaches below its root's row."""
    if isinstance(node, Leaf) or "D" not in node.exits:
        return 0
    return 1 + extent_down(node.child("D"))


def switch_count(node: Node) -> int:
    if isinstance(node, Leaf):
        return 0
    return 1 + sum(switch_count(child) for _, child in node.children)


@dataclass
class Canvas:
    """The rails and things of a layout being drawn, cell by cell; a cell is drawn once."""

    rails: dict[Cell, str] = field(default_factory=dict)
    things: dict[Cell, str] = field(default_factory=dict)
    switches: list[tuple[Cell, tuple[str, ...]]] = field(default_factory=list)
    leaves: list[Cell] = field(default_factory=list)

    def rail(self, cell: Cell, glyph: str) -> None:
        if self.rails.get(cell, glyph) != glyph:
            raise AssertionError(f"grammar bug: rail {cell} drawn as {self.rails[cell]!r} and {glyph!r}")
        self.rails[cell] = glyph

    def thing(self, cell: Cell, glyph: str) -> None:
        if cell in self.things:
            raise AssertionError(f"grammar bug: {cell} holds {self.things[cell]!r} and {glyph!r}")
        self.things[cell] = glyph


def place(node: Node, row: int, col: int, canvas: Canvas) -> None:
    """Draw ``node`` with its entry cell (the switch, or a leaf's first rail) at ``(row, col)``."""
    if isinstance(node, Leaf):
        for c in range(col, -1, -1):
            canvas.rail((row, c), "<")
        canvas.leaves.append((row, 0))
        return
    canvas.rail((row, col), "S")
    canvas.switches.append(((row, col), node.exits))
    for letter, child in node.children:
        if letter == "L":
            place(child, row, col - 1, canvas)
        else:
            side = row - 1 if letter == "U" else row + 1
            canvas.rail((side, col), "<")
            place(child, side, col - 1, canvas)


def run_left(canvas: Canvas, row: int, first: int, last: int) -> None:
    """A straight line leaving left on ``row`` from column ``last`` down to ``first``."""
    for c in range(first, last + 1):
        canvas.rail((row, c), "<")
