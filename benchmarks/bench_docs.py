"""The documentation site's build (``make docs``): how long a writer waits to see a change.

Why: the site is built with ``--strict`` by ``make docs`` and by CI (tests/test_docs_site.py), and
its hook generates the scenario catalogue, the CLI and configuration references, the results schema
and the module map on every build (docs/_hooks/generate.py), so a build is never incremental: the
second build costs what the first does. Measured as a user runs it, a subprocess on both cores.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from tempfile import TemporaryDirectory

from benchmarks import Context, Section, register, timed_command

REPO = Path(__file__).resolve().parents[1]


def timed_docs_build(site: Path) -> tuple[float, float]:
    """Wall and CPU seconds of ``mkdocs build --strict --site-dir site`` (as ``make docs`` runs it)."""
    run = timed_command([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "--site-dir", str(site)], cwd=REPO,
                        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    return run.wall, run.cpu


@register("docs", "Documentation site build (make docs): first build and rebuild", order=90)
def docs_build(ctx: Context) -> Section:
    with TemporaryDirectory(prefix="bench-docs-") as tmp:
        site = Path(tmp) / "site"
        first = timed_docs_build(site)  # an empty site directory
        again = timed_docs_build(site)  # the same sources again
        pages = sum(1 for _ in site.rglob("*.html"))
    return Section(
        intro="""
`python -m mkdocs build --strict --site-dir DIR` (what `make docs` runs; a subprocess, not pinned: both cores), into an
empty directory and then again over it. The hook (docs/_hooks/generate.py) regenerates the scenario catalogue, the CLI and
configuration references, the results schema and the module map on every build, and the formulas are rendered to
MathML, so a rebuild costs about what a first build does. One run each; wall-clock and CPU (user + system) seconds.
""",
        headers=["build", "HTML pages", "wall (s)", "CPU (s)"],
        rows=[["first (empty site directory)", f"{pages}", f"{first[0]:.1f}", f"{first[1]:.1f}"],
              ["again (nothing changed)", f"{pages}", f"{again[0]:.1f}", f"{again[1]:.1f}"]],
        compare=["wall (s)", "CPU (s)"],
    )
