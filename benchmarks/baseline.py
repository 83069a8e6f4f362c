"""Before/after figures: the same benchmark sections measured at another git revision, in the same run.

Why: a change that is meant to alter speed (or that might, by accident) is judged by a ratio, and a
ratio is only honest when both of its figures come from one sitting on one machine: numbers copied
from an older ``BENCHMARKS.md`` were taken under another load, perhaps on another machine. So
``python -m benchmarks.run --baseline REV`` checks ``REV`` out into a temporary git worktree, runs
*that revision's own* benchmark script for the selected sections (its code measuring itself, with
the same repeats and CPU pinning), reads the tables back from the Markdown it writes and sets them
beside the current figures. The old revision is measured with its own benchmark code on purpose:
the section's API may have changed in between, its output format has not.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from benchmarks import Section

_NUMBER = re.compile(r"^-?[\d,]*\.?\d+")


@dataclass
class Table:
    """One section's table as printed: its headers and rows of cell strings."""

    headers: list[str]
    rows: list[list[str]]


def parse_sections(markdown: str) -> dict[str, Table]:
    """The first table of every ``## title`` section of a ``BENCHMARKS.md``-style document."""
    tables: dict[str, Table] = {}
    title: str | None = None
    for line in markdown.splitlines():
        if line.startswith("## "):
            title = line[3:].strip()
            continue
        if title is None or not line.startswith("|"):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if title not in tables:
            tables[title] = Table(cells, [])
        elif not set("".join(cells)) <= set("-:"):  # skip the alignment row
            tables[title].rows.append(cells)
    return tables


def number(cell: str) -> float | None:
    """The leading number of a table cell (``3,275``, ``1.05x``, ``12.3 (wall 14.0)``), if any."""
    match = _NUMBER.match(cell.replace("**", "").strip())
    if not match:
        return None
    try:
        return float(match.group(0).replace(",", ""))
    except ValueError:
        return None


def measure_at(rev: str, keys: list[str], repeats: int, cpu: int | None, quick: bool) -> tuple[str, dict[str, Table]]:
    """Run ``REV``'s ``benchmarks.run --only KEY...`` in a temporary worktree; (commit, its tables by title).

    The old code is imported through ``PYTHONPATH`` pointing at the worktree, which takes precedence
    over the editable install of the current checkout.
    """
    repo = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--verify", "--short", f"{rev}^{{commit}}"],
            cwd=repo, check=True, capture_output=True, text=True,
        ).stdout.strip()
    except subprocess.CalledProcessError as exc:
        raise SystemExit(f"--baseline: {rev!r} is not a commit of this repository ({exc.stderr.strip()})") from None
    tmp = Path(tempfile.mkdtemp(prefix="morality-gym-baseline-"))
    tree = tmp / "tree"
    subprocess.run(["git", "worktree", "add", "--detach", "--quiet", str(tree), commit], cwd=repo, check=True)
    try:
        out = tmp / "baseline.md"
        cmd = [sys.executable, "-m", "benchmarks.run", "--output", str(out), "--no-progress", "--repeats", str(repeats)]
        cmd += ["--cpu", str(cpu if cpu is not None else -1)]
        if quick:
            cmd.append("--quick")
        for key in keys:
            cmd += ["--only", key]
        env = dict(os.environ, PYTHONPATH=str(tree))
        done = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            tail = "\n".join(done.stderr.strip().splitlines()[-5:])
            raise SystemExit(f"--baseline: the benchmark at {commit} failed (exit {done.returncode}):\n{tail}")
        return commit, parse_sections(out.read_text())
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=repo, check=False, capture_output=True)
        shutil.rmtree(tmp, ignore_errors=True)


def comparison(section: Section, before: Table | None, commit: str) -> Section:
    """A section setting ``section``'s compared columns beside the same rows measured at ``commit``.

    Rows are matched on their first cell; a row or column the old revision did not have is shown
    as "—" (new in this revision) rather than dropped, so nothing silently disappears.
    """
    columns = section.compare or [h for h in section.headers[1:]]
    headers = [section.headers[0]]
    for col in columns:
        headers += [f"{col} at {commit}", f"{col} now", "now / before"]
    old_rows = {row[0]: row for row in before.rows} if before else {}
    rows = []
    for row in section.rows:
        out = [row[0]]
        old = old_rows.get(row[0])
        for col in columns:
            new_cell = row[section.headers.index(col)]
            old_cell = "—"
            if old is not None and before is not None and col in before.headers:
                old_cell = old[before.headers.index(col)]
            a, b = number(old_cell), number(new_cell)
            ratio = f"{b / a:.2f}x" if a and b is not None else "—"
            out += [old_cell, new_cell, ratio]
        rows.append(out)
    notes = [] if before is not None else [f"The revision {commit} has no section of this title."]
    return Section(
        intro=(
            f"The table above beside the same benchmark run at commit {commit} (its own benchmark code, checked out "
            "into a temporary worktree), measured in this same invocation right after it, on the same pinned core."
        ),
        headers=headers,
        rows=rows,
        notes=notes,
        title=f"{section.title}: before ({commit}) and now",
    )
