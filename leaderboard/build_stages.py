"""The stages of ``python -m leaderboard.build``: aggregate, statistics, tables, figures, run charts, site.

Apart from the command (:mod:`leaderboard.build`) because they load matplotlib, Jinja and SciPy:
the command parses its arguments, checks ``SOURCE_DATE_EPOCH`` and its output directories in well
under a second, and only then imports this module (SciPy's import reads ``SOURCE_DATE_EPOCH``
through numpy.f2py and dies on a malformed one with a traceback instead of one line).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path
from typing import Any, TypeVar

from rich.console import Console
from rich.progress import track

from leaderboard.outputs.intervals import with_intervals
from leaderboard.outputs.tables import write_tables
from leaderboard.runs.aggregate import (
    Leaderboard,
    aggregate,
    chain_definitions,
    choose_primary,
    compute_reference,
    reference_requests,
    with_reference,
)
from leaderboard.runs.opening import primary_choice
from leaderboard.runs.sources import Sources
from leaderboard.runs.stamp import stamp_text
from leaderboard.web.cached_stages import paper_figures, statistics, statistics_figures
from leaderboard.web.run_figures import write_run_charts
from leaderboard.web.site import build_site
from morality_gym.clitools import UserError, did_you_mean

REFERENCE_CACHE = Path("cache") / "reference_rows.json"
T = TypeVar("T")


def progress(items: Iterable[T], description: str, total: int) -> Iterable[T]:
    """A rich progress bar on a terminal; one line per stage otherwise (logs stay readable)."""
    console = Console(stderr=True)
    if console.is_terminal:
        return track(items, description=description, total=total, console=console, transient=True)
    print(f"  {description}: {total} item(s)", file=sys.stderr, flush=True)
    return items


def check_primary_choice(args: argparse.Namespace, lb: Leaderboard) -> None:
    """``--protocol`` / ``--preset`` must name a sweep of the results (a typo silently chose none)."""
    for flag, wanted, have in (("--protocol", args.protocol, {g.protocol for g in lb.groups}),
                               ("--preset", args.preset, {g.preset for g in lb.groups})):
        if wanted is not None and wanted not in have:
            hint = did_you_mean(wanted, sorted(have), quote=False)
            raise UserError(f"{flag} {wanted}: no sweep in the results has it{hint}; they have: {', '.join(sorted(have))}")


def build(args: argparse.Namespace, sources: Sources, quarantined: list[dict[str, str]] | None = None,
          ) -> tuple[Leaderboard, dict[str, Any]]:
    """Run every stage on loaded runs; returns the leaderboard and what was written (for the summary)."""
    runs, planned, skipped = sources.runs, sources.planned, sources.skipped
    out_dir: Path = args.out
    timings: dict[str, float] = {}
    cached: dict[str, bool] = {}  # stage -> reused from <out>/cache
    start = time.perf_counter()
    lb = aggregate(runs, planned, primary_protocol=args.protocol, primary_preset=args.preset)
    check_primary_choice(args, lb)
    protocol, preset = primary_choice(lb, args.protocol, args.preset)  # the user's newest sweep, issue 36
    lb = replace(lb, primary=choose_primary(lb.table, lb.groups, protocol, preset))
    reference = None
    if not args.no_reference:
        reference = compute_reference(reference_requests(lb.table), out_dir / REFERENCE_CACHE, progress,
                                      chain_definitions(lb.runs))
        lb = with_reference(lb, reference.entries, reference.errors, protocol, preset)
    lb.skipped, lb.quarantined = list(skipped or []), list(quarantined or [])
    stamp = stamp_text(lb.runs)
    timings["aggregate"] = time.perf_counter() - start

    start = time.perf_counter()
    stats, stats_key, cached["statistics"] = statistics(lb, reference is not None, sources, out_dir)
    lb = with_intervals(lb, stats.cells)
    timings["statistics"] = time.perf_counter() - start

    start = time.perf_counter()
    tables = write_tables(lb, out_dir, sources.name, stamp)
    timings["tables"] = time.perf_counter() - start

    start = time.perf_counter()
    figures, cached["figures"] = paper_figures(lb, out_dir, progress)
    timings["figures"] = time.perf_counter() - start

    start = time.perf_counter()
    drawn = write_run_charts(lb, sources, out_dir / "figures" / "learn", figures, out_dir, progress)
    timings["run charts"] = time.perf_counter() - start

    start = time.perf_counter()
    stat_figures, cached["statistics figures"] = statistics_figures(lb, stats, stats_key, out_dir, figures.colours,
                                                                    progress)
    timings["statistics figures"] = time.perf_counter() - start

    start = time.perf_counter()
    site = build_site(lb, sources, args.site, figures, sources.name, progress, stats=stats, stat_figures=stat_figures,
                      stamp=stamp, cache_dir=out_dir / "cache" / "pages")
    timings["site"] = time.perf_counter() - start
    return lb, {"tables": tables, "figures": figures, "stat_figures": stat_figures, "site": site,
                "reference": reference, "timings": timings, "sources": sources, "cached": cached,
                "charts_drawn": drawn}
