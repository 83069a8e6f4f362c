"""The import graph of the code base has no cycle, and every import points down the layers.

Layers, lowest first (docs/architecture.md explains each placement):

    support -> world -> render -> envs -> norms -> evaluation -> api -> llm -> baselines -> runners
            -> leaderboard -> cli -> benchmarks

A module may import modules of its own layer or of a lower one, never of a higher one. Every
import counts: module level, inside a function, under ``if TYPE_CHECKING:``, and
``importlib.import_module("...")`` or a string that names a module (Gymnasium entry points, lazy
attribute tables). Moving an import into a function hides a cycle from the interpreter, not from
this test. Imports of parent packages that Python performs implicitly (importing
``morality_gym.envs.trolley`` runs ``morality_gym/__init__.py``) are not edges: only what a file
names is.
"""

from __future__ import annotations

import ast
import re
from collections import defaultdict, deque
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("morality_gym", "runners", "leaderboard", "benchmarks")

#: (layer, module prefixes). A prefix matches the module itself and everything below it; the most
#: specific prefix wins. ``morality_gym`` alone (the package's ``__init__``) is matched exactly, so
#: a new top-level module must be placed here on purpose.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("support", ("morality_gym.clitools", "morality_gym.constants")),
    ("world", ("morality_gym.world", "morality_gym.generator.draws", "morality_gym.generator.rail_networks",
               "morality_gym.generator.grammar", "morality_gym.generator.writer", "morality_gym.generator.measure")),
    ("render", ("morality_gym.render",)),
    ("envs", ("morality_gym.envs",)),
    ("norms", ("morality_gym.norms",)),
    ("evaluation", ("morality_gym.evaluation", "morality_gym.generator")),
    ("api", ("morality_gym", "morality_gym.api", "morality_gym.paper", "morality_gym.generalisation")),
    ("llm", ("morality_gym.llm",)),
    ("baselines", ("morality_gym.baselines",)),
    ("results", ("morality_gym.results",)),
    ("runners", ("runners",)),
    ("leaderboard", ("leaderboard",)),
    ("cli", ("morality_gym.__main__", "morality_gym.play")),
    ("benchmarks", ("benchmarks",)),
)
EXACT = {"morality_gym"}
#: A string constant that names a project module, optionally with ``:attribute`` (entry points).
MODULE_STRING = re.compile(rf"^((?:{'|'.join(PACKAGES)})(?:\.\w+)*)(?::\w+)?$")


@dataclass(frozen=True)
class Edge:
    source: str
    target: str
    path: Path
    line: int

    def where(self) -> str:
        return f"{self.path}:{self.line}: {self.source} -> {self.target}"


def discover(root: Path, packages: tuple[str, ...] = PACKAGES) -> dict[str, Path]:
    """Every module of ``packages`` under ``root`` by dotted name (a package is its ``__init__``)."""
    modules: dict[str, Path] = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = path
    return modules


def _named(node: ast.AST, module: str, is_package: bool) -> list[str]:
    """The dotted names an import-like node refers to (candidates; resolved by the caller)."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if isinstance(node, ast.ImportFrom):
        if node.level:
            base = module.split(".") if is_package else module.split(".")[:-1]
            base = base[: len(base) - node.level + 1]
            origin = ".".join(base + ([node.module] if node.module else []))
        else:
            origin = node.module or ""
        # ``from pkg import name``: the submodule pkg.name if there is one, else pkg itself (unless
        # pkg.name is a namespace package, which has no code: see import_edges).
        return [f"{origin}.{alias.name}\0{origin}" for alias in node.names]
    if isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
        func = node.func
        name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
        if name in ("import_module", "__import__") and isinstance(node.args[0].value, str):
            return [node.args[0].value]
        return []
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        match = MODULE_STRING.match(node.value)
        return [match.group(1)] if match else []
    return []


def _subprocess_modules(tree: ast.AST) -> set[int]:
    """The string nodes that follow ``"-m"`` in a list or tuple: a command line that runs the module
    in another process (e.g. ``[sys.executable, "-m", "runners.sweep"]``), not an import."""
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.List, ast.Tuple)):
            for flag, value in zip(node.elts, node.elts[1:]):
                if isinstance(flag, ast.Constant) and flag.value == "-m":
                    skip.add(id(value))
    return skip


def import_edges(modules: dict[str, Path], root: Path) -> list[Edge]:
    """Every reference from one project module to another, with the file and line that makes it."""
    edges: list[Edge] = []
    for module, path in modules.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        is_package = path.name == "__init__.py"
        skip = _subprocess_modules(tree)
        for node in ast.walk(tree):
            if id(node) in skip:
                continue
            for name in _named(node, module, is_package):
                first, _, fallback = name.partition("\0")
                if first in modules:
                    target: str | None = first
                elif fallback in modules and not (root / first.replace(".", "/")).is_dir():
                    target = fallback
                else:
                    target = None  # another package, or a namespace package (a directory, no code)
                if target is not None and target != module:
                    edges.append(Edge(module, target, path.relative_to(root), getattr(node, "lineno", 0)))
    return edges


def layer_of(module: str) -> str | None:
    best, best_len = None, -1
    for layer, prefixes in LAYERS:
        for prefix in prefixes:
            matches = module == prefix or (prefix not in EXACT and module.startswith(prefix + "."))
            if matches and len(prefix) > best_len:
                best, best_len = layer, len(prefix)
    return best


def find_cycles(edges: list[Edge]) -> list[tuple[set[str], list[Edge]]]:
    """Per strongly connected component of more than one module: its modules and one shortest
    cycle through them (as edges; breaking it may leave another cycle of the component)."""
    graph: dict[str, dict[str, Edge]] = defaultdict(dict)
    for edge in edges:
        graph[edge.source].setdefault(edge.target, edge)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[set[str]] = []

    def strongconnect(start: str) -> None:  # iterative Tarjan (no recursion limit surprises)
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = set()
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.add(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        components.append(component)

    for node in sorted({e.source for e in edges} | {e.target for e in edges}):
        if node not in index:
            strongconnect(node)

    cycles = []
    for component in components:
        start = min(component)
        parent: dict[str, str | None] = {start: None}
        queue, last = deque([start]), start
        while queue:  # breadth first inside the component: the shortest way back to start
            last = queue.popleft()
            if start in graph[last]:
                break
            for child in sorted(graph[last]):
                if child in component and child not in parent:
                    parent[child] = last
                    queue.append(child)
        path = [last]
        while parent[path[-1]] is not None:
            path.append(parent[path[-1]])  # type: ignore[arg-type]
        path.reverse()
        cycles.append((component, [graph[a][b] for a, b in zip(path, [*path[1:], start])]))
    return cycles


def upward_imports(edges: list[Edge]) -> list[str]:
    order = {layer: i for i, (layer, _) in enumerate(LAYERS)}
    out = []
    for edge in edges:
        source, target = layer_of(edge.source), layer_of(edge.target)
        if source is not None and target is not None and order[target] > order[source]:
            out.append(f"{edge.where()} (layer {source} imports the higher layer {target})")
    return out


def check(root: Path) -> tuple[list[str], list[str], list[str], int]:
    """(cycles, upward imports, modules without a layer, number of edges) of the tree at ``root``."""
    modules = discover(root)
    edges = import_edges(modules, root)
    cycles = [
        "cycle " + " -> ".join([c[0].source, *(e.target for e in c)]) + "\n    " + "\n    ".join(e.where() for e in c)
        + (f"\n    (modules on some cycle with these: {', '.join(sorted(members))})" if len(members) > len(c) else "")
        for members, c in find_cycles(edges)
    ]
    unplaced = sorted(m for m in modules if layer_of(m) is None)
    return cycles, upward_imports(edges), unplaced, len(edges)


# ---------------------------------------------------------------------------------------- the code base
def test_every_module_has_a_layer() -> None:
    _, _, unplaced, _ = check(ROOT)
    assert not unplaced, "modules with no layer (add them to LAYERS in tests/test_layers.py and to docs/architecture.md): " + ", ".join(unplaced)


def test_no_import_cycles() -> None:
    cycles, _, _, n_edges = check(ROOT)
    assert n_edges > 200, f"only {n_edges} import edges found: the scan is broken"
    assert not cycles, "import cycles (break them by design, not by moving an import into a function):\n" + "\n".join(cycles)


def test_layers_import_downward_only() -> None:
    _, upward, _, _ = check(ROOT)
    assert not upward, "imports from a lower layer into a higher one:\n" + "\n".join(upward)


# ---------------------------------------------------------------------------------------- the checker itself
def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return tmp_path


@pytest.mark.parametrize("hidden", [
    "from morality_gym.envs.a import X",
    "def f():\n    from morality_gym.envs import a",
    "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from morality_gym.envs.a import X",
    "def f():\n    import importlib\n    importlib.import_module('morality_gym.envs.a')",
    "ENTRY = 'morality_gym.envs.a:X'",
    "def f():\n    from . import a",
])
def test_the_checker_finds_a_cycle_however_it_is_hidden(tmp_path: Path, hidden: str) -> None:
    root = _tree(tmp_path, {
        "morality_gym/__init__.py": "",
        "morality_gym/envs/a.py": "from morality_gym.envs.b import Y\nX = 1\n",
        "morality_gym/envs/b.py": f"{hidden}\nY = 2\n",
    })
    cycles, _, _, _ = check(root)
    assert len(cycles) == 1
    assert "morality_gym.envs.a -> morality_gym.envs.b -> morality_gym.envs.a" in cycles[0]
    assert "morality_gym/envs/b.py:" in cycles[0]


def test_the_checker_reports_an_upward_import_with_file_and_line(tmp_path: Path) -> None:
    root = _tree(tmp_path, {
        "morality_gym/__init__.py": "",
        "morality_gym/world/rules.py": "import os\n\ndef f():\n    from morality_gym.baselines.learners import L\n",
        "morality_gym/baselines/learners.py": "from morality_gym.world import rules\nL = 1\n",
        "morality_gym/envs/trolley.py": "from morality_gym import world\n",  # a namespace package: no edge
    })
    cycles, upward, unplaced, _ = check(root)
    assert len(cycles) == 1 and not unplaced
    assert upward == [("morality_gym/world/rules.py:4: morality_gym.world.rules -> morality_gym.baselines.learners "
                       "(layer world imports the higher layer baselines)")]


def test_a_new_top_level_module_needs_a_layer(tmp_path: Path) -> None:
    root = _tree(tmp_path, {"morality_gym/__init__.py": "", "morality_gym/newthing.py": ""})
    assert check(root)[2] == ["morality_gym.newthing"]
