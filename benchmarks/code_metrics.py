"""``python -m benchmarks.code_metrics [ROOT ...]``: how hard the code is to read, in three numbers.

Why: issue 23 compared the project with Stable-Baselines3, MiniGrid and lightning-hydra-template by
cyclomatic complexity per function and by imports hidden inside functions, and asked for the same
table before and after the redesign. The numbers are only comparable if they are measured the same
way every time, so the method lives here instead of in a note:

* complexity: radon's cyclomatic complexity of every function and method that ``radon cc -j``
  reports (class blocks left out: a class's figure is an average of its methods, counting them
  twice), over the packages ``morality_gym``, ``runners``, ``leaderboard`` and ``benchmarks``;
* functions above 20, and the highest with its name; and, named one by one, those above 15 (issue
  50's target: none above 15 on the sweep's path);
* imports inside functions: ``import`` / ``from ... import`` statements anywhere below a ``def``
  (each counted once, also in nested functions), by the standard library's :mod:`ast`; and how
  many of them import the project's own modules (one of :data:`PACKAGES`, or a relative import):
  those hide an import cycle or a misplaced module rather than wait for a heavy optional package.

Give several roots (e.g. a checkout of an older commit made with ``git worktree add``) to compare
them in one table.
"""

from __future__ import annotations

import argparse
import ast
import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

PACKAGES = ("morality_gym", "runners", "leaderboard", "benchmarks")
THRESHOLD = 20
#: Functions above this are listed by name (issue 50: none above 15 on the sweep's path).
LIST_ABOVE = 15


@dataclass(frozen=True)
class CodeMetrics:
    """The table's columns for one source tree."""

    root: Path
    functions: int
    mean_complexity: float
    above_threshold: int
    highest: int
    highest_name: str
    inner_imports: int
    inner_imports_by_package: dict[str, int]
    inner_own_imports: int = 0
    listed: tuple[tuple[int, str], ...] = ()  # (complexity, "path::name") above LIST_ABOVE, highest first


def complexities(root: Path, packages: tuple[str, ...] = PACKAGES) -> list[tuple[int, str]]:
    """(complexity, "path::name") of every function and method radon reports under ``packages``.

    radon's command line is used, not its Python API, so that the figure is exactly what ``radon
    cc -j`` prints for anyone who checks by hand."""
    out = subprocess.run([sys.executable, "-m", "radon", "cc", "-j", *packages], cwd=root,
                         capture_output=True, text=True, check=True).stdout
    blocks = json.loads(out)
    return [(block["complexity"], f"{path}::{block['name']}")
            for path, found in sorted(blocks.items()) if isinstance(found, list)
            for block in found if block.get("type") != "class"]


def _imports_below_def(path: Path) -> list[ast.Import | ast.ImportFrom]:
    """Import statements below a ``def`` in one file (each once, however deeply nested)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    inside: dict[int, ast.Import | ast.ImportFrom] = {}
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            inside.update((id(sub), sub) for sub in ast.walk(node) if isinstance(sub, (ast.Import, ast.ImportFrom)))
    return list(inside.values())


def inner_imports(path: Path) -> int:
    """Import statements below a ``def`` in one file (each once, however deeply nested)."""
    return len(_imports_below_def(path))


def _is_own(node: ast.Import | ast.ImportFrom, packages: tuple[str, ...]) -> bool:
    """Whether an import names one of the project's ``packages`` (a relative import always does)."""
    if isinstance(node, ast.ImportFrom):
        return node.level > 0 or (node.module or "").split(".")[0] in packages
    return any(alias.name.split(".")[0] in packages for alias in node.names)


def inner_own_imports(path: Path, packages: tuple[str, ...] = PACKAGES) -> int:
    """Of :func:`inner_imports`, those of the project's own modules."""
    return sum(_is_own(node, packages) for node in _imports_below_def(path))


def measure(root: Path, packages: tuple[str, ...] = PACKAGES) -> CodeMetrics:
    """All columns of the table for the tree at ``root``."""
    found = complexities(root, packages)
    if not found:
        raise SystemExit(f"no Python functions under {root} in {', '.join(packages)}")
    highest, highest_name = max(found)
    files = [p for package in packages for p in sorted((root / package).rglob("*.py"))]
    by_package = {package: sum(inner_imports(p) for p in sorted((root / package).rglob("*.py")))
                  for package in packages}
    return CodeMetrics(root=root, functions=len(found), mean_complexity=sum(c for c, _ in found) / len(found),
                       above_threshold=sum(c > THRESHOLD for c, _ in found), highest=highest,
                       highest_name=highest_name, inner_imports=sum(by_package.values()),
                       inner_imports_by_package=by_package,
                       inner_own_imports=sum(inner_own_imports(p, packages) for p in files),
                       listed=tuple(sorted(((c, n) for c, n in found if c > LIST_ABOVE), key=lambda f: (-f[0], f[1]))))


def markdown(rows: list[CodeMetrics]) -> str:
    """The comparison table, one column per tree, in the layout of issue 23."""
    lines = ["| | " + " | ".join(str(m.root) for m in rows) + " |",
             "|---|" + "---:|" * len(rows),
             "| functions and methods | " + " | ".join(str(m.functions) for m in rows) + " |",
             "| mean complexity per function | " + " | ".join(f"{m.mean_complexity:.2f}" for m in rows) + " |",
             f"| functions above {THRESHOLD} / highest | "
             + " | ".join(f"{m.above_threshold} / {m.highest}" for m in rows) + " |",
             "| highest is | " + " | ".join(f"`{m.highest_name}`" for m in rows) + " |",
             f"| functions above {LIST_ABOVE} | " + " | ".join(str(len(m.listed)) for m in rows) + " |",
             "| imports inside functions | " + " | ".join(str(m.inner_imports) for m in rows) + " |",
             "| ... of the project's own modules | " + " | ".join(str(m.inner_own_imports) for m in rows) + " |"]
    for package in PACKAGES:
        lines.append(f"| ... in `{package}` | "
                     + " | ".join(str(m.inner_imports_by_package.get(package, 0)) for m in rows) + " |")
    return "\n".join(lines)


def listing(m: CodeMetrics) -> str:
    """The functions above :data:`LIST_ABOVE` of one tree, one a line, highest first."""
    return "\n".join(f"{c:3d} {name}" for c, name in m.listed)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.code_metrics", description=__doc__.splitlines()[0])
    parser.add_argument("roots", nargs="*", type=Path, default=[Path(".")],
                        help="source trees to measure (default: the current directory)")
    parser.add_argument("--list", action="store_true", help=f"also name each function above {LIST_ABOVE}, per tree")
    args = parser.parse_args(argv)
    rows = [measure(root) for root in args.roots]
    print(markdown(rows))
    if args.list:
        for m in rows:
            print(f"\nabove {LIST_ABOVE} in {m.root}:\n{listing(m)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
