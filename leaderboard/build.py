"""``python -m leaderboard.build --results results``: aggregate -> tables -> figures -> site.

Missing or failed runs do not fail the build (they are the report's point: a partial sweep must
still be inspectable), but a results directory that does not exist, or holds neither runs nor
manifests, does: that is almost always a wrong path, and an empty leaderboard would hide it.
The build only reads ``<results>/runs``; it writes ``table1.*``, ``figures/`` and ``cache/`` next
to it and the site wherever ``--site`` points.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, TypeVar

from leaderboard.aggregate import Leaderboard, aggregate, compute_reference, reference_requests, with_reference

DEFAULT_SITE = Path(__file__).resolve().parent / "site"
REFERENCE_CACHE = Path("cache") / "reference_rows.json"
EXIT_OK, EXIT_ERROR, EXIT_NO_RESULTS = 0, 1, 2
T = TypeVar("T")


def progress(items: Iterable[T], description: str, total: int) -> Iterable[T]:
    """A rich progress bar on a terminal; one line per stage otherwise (logs stay readable)."""
    from rich.console import Console
    from rich.progress import track

    console = Console(stderr=True)
    if console.is_terminal:
        return track(items, description=description, total=total, console=console, transient=True)
    print(f"  {description}: {total} item(s)", file=sys.stderr, flush=True)
    return items


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m leaderboard.build", description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=Path("results"), help="results directory (default: results)")
    parser.add_argument("--site", type=Path, default=DEFAULT_SITE, help=f"site output directory (default: {DEFAULT_SITE})")
    parser.add_argument("--no-reference", action="store_true",
                        help="skip the exact Random and oracle reference rows (they are cached once computed)")
    parser.add_argument("--protocol", help="protocol of the primary table (table1.csv/.tex); default: automatic")
    parser.add_argument("--preset", help="preset of the primary table; default: automatic")
    return parser.parse_args(argv)


def load(results: Path) -> tuple[Any, dict[str, dict[str, Any]]]:
    """All run rows and all planned runs of a results directory."""
    from runners.manifest import planned_runs
    from runners.schema import read_runs

    return read_runs(results), planned_runs(results)


def build(args: argparse.Namespace, runs: Any, planned: dict[str, dict[str, Any]]) -> tuple[Leaderboard, dict[str, Any]]:
    """Run every stage on loaded runs; returns the leaderboard and what was written (for the summary)."""
    from leaderboard.figures import write_figures, write_learn_curves
    from leaderboard.site import build_site
    from leaderboard.tables import write_tables

    results: Path = args.results
    timings: dict[str, float] = {}
    start = time.perf_counter()
    lb = aggregate(runs, planned, primary_protocol=args.protocol, primary_preset=args.preset)
    reference = None
    if not args.no_reference:
        reference = compute_reference(reference_requests(lb.table), results / REFERENCE_CACHE, progress)
        lb = with_reference(lb, reference.entries, reference.errors, args.protocol, args.preset)
    timings["aggregate"] = time.perf_counter() - start

    start = time.perf_counter()
    tables = write_tables(lb, results, str(results))
    timings["tables"] = time.perf_counter() - start

    start = time.perf_counter()
    figures = write_figures(lb, results / "figures", progress)
    write_learn_curves(lb, results, results / "figures" / "learn", figures, progress)
    timings["figures"] = time.perf_counter() - start

    start = time.perf_counter()
    site = build_site(lb, results, args.site, figures, str(results), progress)
    timings["site"] = time.perf_counter() - start
    return lb, {"tables": tables, "figures": figures, "site": site, "reference": reference, "timings": timings}


def summary(lb: Leaderboard, out: dict[str, Any], args: argparse.Namespace) -> str:
    """The few lines a person needs after a build: counts, problems, where things are."""
    learner_rows = lb.table.loc[lb.table["kind"] == "learner"]
    lines = [
        (f"Table 1: {len(lb.pairs())} (chain, scenario) row(s), {len(learner_rows)} learner cell(s) "
        f"in {len(lb.groups)} sweep(s); primary: {lb.primary.label if lb.primary else 'none'}"),
        (f"runs: {lb.n_ok} with a result, {len(lb.problems)} failed, {len(lb.missing)} missing "
        f"(of {len(set(lb.planned) | set(lb.runs['run_id']))} planned or produced)"
        + (f"; {len(lb.superseded)} superseded by a newer run of the same slot, not counted (see table1.md)"
           if len(lb.superseded) else "")),
    ]
    ref = out["reference"]
    if ref is None:
        lines.append("reference rows: skipped (--no-reference)")
    else:
        lines.append(f"reference rows: {ref.computed} computed, {ref.cached} from cache"
                     + (f", {len(ref.errors)} failed" if ref.errors else ""))
    for row in lb.problems.head(5).to_dict("records"):
        lines.append(f"  FAILED {row['run_id']} {row['chain']}/{row['env_id']} {row['learner']} seed {row['seed']}: {row['error']}")
    if len(lb.problems) > 5:
        lines.append(f"  ... and {len(lb.problems) - 5} more failed run(s), see table1.md")
    lines += [f"wrote {path}" for path in out["tables"]]
    lines.append(f"figures: {out['figures'].count} under {args.results / 'figures'}")
    lines.append(f"site: {out['site'].pages} page(s) in {args.site} (open {args.site / 'index.html'})")
    lines.append("time: " + ", ".join(f"{k} {v:.1f}s" for k, v in out["timings"].items()))
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    results: Path = args.results
    if not results.is_dir():
        print(f"error: results directory {results} does not exist (pass --results DIR)", file=sys.stderr)
        return EXIT_NO_RESULTS
    from leaderboard.site import SiteError, check_target

    try:
        check_target(args.site)  # a wrong --site must fail before anything is written
    except SiteError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    try:
        runs, planned = load(results)
    except Exception as exc:  # noqa: BLE001 - a broken results file must stop the build with its name
        print(f"error: cannot read the results in {results}: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_ERROR
    if len(runs) == 0 and not planned:
        print(f"error: {results} holds no runs ({results / 'runs'}/*.parquet) and no sweep manifests "
              f"({results / 'manifests'}/*.json): nothing to build", file=sys.stderr)
        return EXIT_NO_RESULTS
    try:
        lb, out = build(args, runs, planned)
    except SiteError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    print(summary(lb, out, args))
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
