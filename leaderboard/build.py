"""``python -m leaderboard.build --results results``: aggregate -> tables -> figures -> site.

Missing or failed runs do not fail the build (they are the report's point: a partial sweep must
still be inspectable), and neither does a damaged file: a run file or manifest that cannot be read
is left out and listed (``table1.md``, the site's status, the summary), as are the files sweeps
moved to ``runs/.quarantine``. But a results directory that does not exist, or holds neither runs
nor manifests, fails the build: that is almost always a wrong path, and an empty leaderboard would
hide it. The build only reads ``<results>/runs``; it writes ``table1.*``, ``figures/`` and
``cache/`` into ``--out`` (default: the results directory; a read-only results directory needs
``--out``) and the site wherever ``--site`` points (default: ``site/`` in ``--out``, next to the
tables: never inside the installed package). User errors print one line and exit 2
(``--debug`` shows the traceback).

A rebuild is quick: ``cache/`` keeps the exact reference rows, the bootstrap statistics, Figure 2
and the radars, the statistics figures (:mod:`leaderboard.web.cached_stages`), the per-run SVG charts
(:mod:`leaderboard.web.run_figures`) and the run pages (:mod:`leaderboard.web.page_cache`), each keyed by a
digest of its inputs and code, so what is reused is what a fresh build would write, byte for byte.
Deleting ``cache/`` only makes the next build slower.

The stages themselves are :mod:`leaderboard.build_stages`; this module is the command around them.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from leaderboard.runs.aggregate import Leaderboard
from leaderboard.runs.releases import Release, ReleaseError, resolve
from leaderboard.runs.sources import RESULTS_SOURCE, Sources, load_sources
from leaderboard.runs.stamp import StampError, source_date_epoch
from leaderboard.web.site_target import SiteError, check_target
from morality_gym.clitools import OneLineParser, UserError, add_debug_flag, run_cli, writing
from morality_gym.results.quarantine import quarantined_files

EXIT_OK = 0


def build_parser() -> argparse.ArgumentParser:
    """The command's parser, apart from parsing: the docs' command-line reference is generated from it."""
    parser = OneLineParser(prog="python -m leaderboard.build", description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=Path("results"), help="results directory (default: results)")
    parser.add_argument("--out", type=Path, default=None,
                        help="where table1.*, figures/ and cache/ go (default: the results directory)")
    parser.add_argument("--site", type=Path, default=None, help="site output directory (default: site/ in --out)")
    parser.add_argument("--no-reference", action="store_true",
                        help="skip the exact Random and oracle reference rows (they are cached once computed)")
    parser.add_argument("--protocol", help="protocol of the primary table (table1.csv/.tex); default: that of the sweep "
                                           "of your newest run, else automatic")
    parser.add_argument("--preset", help="preset of the primary table; default: that of the sweep of your newest run, "
                                         "else automatic")
    parser.add_argument("--release", action="append", metavar="DIR|all",
                        help="also show a results release (releases/<name>; 'all': every release in releases/); "
                             "repeatable. Runs of the results directory win over a release's copy of the same run")
    add_debug_flag(parser)
    return parser


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    args = build_parser().parse_args(argv)
    if args.out is None:
        args.out = args.results
    if args.site is None:
        args.site = args.out / "site"
    return args


def check_writable(directory: Path, what: str, fix: str) -> None:
    """Raise :class:`UserError` unless ``directory`` (or the nearest existing parent) can be written."""
    probe = directory
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    try:
        if not probe.is_dir():
            raise OSError(f"{probe} is not a directory")
        with tempfile.NamedTemporaryFile(dir=probe, prefix=".write-probe-"):
            pass
    except OSError as exc:
        raise UserError(f"{what} {directory} is not writable ({exc.strerror or exc}); {fix}") from exc


def load(results: Path) -> tuple[Any, dict[str, dict[str, Any]], list[dict[str, str]]]:
    """All readable run rows, all planned runs of a results directory, and what could not be read."""
    sources = load_sources(results, [])
    return sources.runs.drop(columns="source"), sources.planned, sources.skipped


def releases_of(args: argparse.Namespace) -> list[Release]:
    """The releases named by ``--release``; a damaged or edited one stops the build with one line."""
    try:
        return resolve(args.release or [])
    except ReleaseError as exc:
        raise UserError(str(exc)) from exc


def summary(lb: Leaderboard, out: dict[str, Any], args: argparse.Namespace) -> str:
    """The few lines a person needs after a build: counts, problems, where things are.

    In reading order: what the table holds, where its runs came from, what went wrong, what was written.
    """
    lines = _count_lines(lb)
    lines += _release_lines(lb, out["sources"], args)
    lines += _reference_lines(out["reference"])
    lines += _problem_lines(lb, args)
    lines += _output_lines(out, args)
    return "\n".join(lines)


def _count_lines(lb: Leaderboard) -> list[str]:
    """Rows, cells and sweeps of Table 1, and the runs behind them."""
    learner_rows = lb.table.loc[lb.table["kind"] == "learner"]
    return [
        (f"Table 1: {len(lb.pairs())} (chain, scenario) row(s), {len(learner_rows)} learner cell(s) "
        f"in {len(lb.groups)} sweep(s); primary: {lb.primary.label if lb.primary else 'none'}"),
        (f"runs: {lb.n_ok} with a result, {len(lb.problems)} failed, {len(lb.missing)} missing "
        f"(of {len(set(lb.planned) | set(lb.runs['run_id']))} planned or produced)"
        + (f"; {len(lb.superseded)} superseded by a newer run of the same slot, not counted (see table1.md)"
           if len(lb.superseded) else "")),
    ]


def _release_lines(lb: Leaderboard, sources: Sources, args: argparse.Namespace) -> list[str]:
    """How many of each merged release's runs are shown (the rest were replaced or superseded)."""
    lines = []
    for release in sources.releases:
        shown = int((lb.runs["source"] == release.name).sum()) if "source" in lb.runs.columns else 0
        lines.append(f"{release.label}: {shown} of its {len(release.runs)} run(s) shown"
                     + sources.replaced_note(release, shown, lambda source: _source_word(source, args)))
    return lines


def _source_word(source: str, args: argparse.Namespace) -> str:
    """A run source as the build's log names it: the results directory's path, or ``release X``."""
    return str(args.results) if source == RESULTS_SOURCE else f"release {source}"


def _reference_lines(ref: Any) -> list[str]:
    """The reference rows: skipped, or computed / cached / failed (with each failure)."""
    if ref is None:
        return ["reference rows: skipped (--no-reference)"]
    return ([f"reference rows: {ref.computed} computed, {ref.cached} from cache"
             + (f", {len(ref.errors)} failed (their rows have no Random exact / Oracle columns):" if ref.errors else "")]
            + [f"  REFERENCE {key}: {reason}" for key, reason in sorted(ref.errors.items())])


def _problem_lines(lb: Leaderboard, args: argparse.Namespace) -> list[str]:
    """Unreadable and quarantined files, incomplete cells, and the first failed runs."""
    lines = []
    if lb.skipped:
        lines.append(f"unreadable files left out: {len(lb.skipped)} (listed in table1.md and on the site)")
        lines += [f"  SKIPPED {item['file']}: {item['reason']}" for item in lb.skipped[:5]]
    if lb.quarantined:
        lines.append(f"files moved aside by sweeps: {len(lb.quarantined)} in {args.results / 'runs' / '.quarantine'}")
    learner_rows = lb.table.loc[lb.table["kind"] == "learner"]
    incomplete = learner_rows.loc[~learner_rows["complete"].astype(bool)] if len(learner_rows) else learner_rows
    if len(incomplete):
        lines.append(f"incomplete cells: {len(incomplete)} of {len(learner_rows)} (marked; no bold, no paper delta)")
    for row in lb.problems.head(5).to_dict("records"):
        lines.append(f"  FAILED {row['run_id']} {row['chain']}/{row['env_id']} {row['learner']} seed {row['seed']}: {row['error']}")
    if len(lb.problems) > 5:
        lines.append(f"  ... and {len(lb.problems) - 5} more failed run(s), see table1.md")
    return lines


def _output_lines(out: dict[str, Any], args: argparse.Namespace) -> list[str]:
    """What was written where, what the caches saved, and the time of each stage."""
    lines = [f"wrote {path}" for path in out["tables"]]
    lines.append(f"figures: {out['figures'].count} + {out['stat_figures'].count} statistics figure(s) "
                 f"under {args.out / 'figures'}")
    lines.append(f"site: {out['site'].pages} page(s) in {args.site} (open {args.site / 'index.html'})")
    reused = [stage for stage, hit in out["cached"].items() if hit]
    charts = len(out["figures"].learn) + len(out["figures"].updates)
    lines.append(f"cache: {', '.join(reused) or 'nothing'} reused; {out['charts_drawn']} of {charts} run chart(s) drawn, "
                 f"{out['site'].pages_reused} run page(s) reused")
    lines.append("time: " + ", ".join(f"{k} {v:.1f}s" for k, v in out["timings"].items()))
    return lines


def run(args: argparse.Namespace) -> int:
    """The build, with every user error raised as :class:`UserError` (one line, exit 2)."""
    try:
        source_date_epoch()  # before scipy is imported: numpy.f2py reads the variable too and crashes on it
    except StampError as exc:
        raise UserError(str(exc)) from exc
    # The stages load matplotlib, Jinja and SciPy: not before --help, and SciPy not before
    # SOURCE_DATE_EPOCH was checked (numpy.f2py reads it at SciPy's import and dies on a bad one)
    from leaderboard.build_stages import build

    results: Path = args.results
    releases = releases_of(args)
    if not results.is_dir() and not releases:
        raise UserError(f"results directory {results} does not exist (pass --results DIR)")
    try:
        check_target(args.site)  # a wrong --site must fail before anything is written
    except SiteError as exc:
        raise UserError(str(exc)) from exc
    check_writable(args.out, "output directory", "pass --out DIR to write the tables, figures and cache elsewhere")
    check_writable(args.site.parent if not args.site.exists() else args.site, "site directory",
                   "pass --site DIR to write the site elsewhere")
    sources = load_sources(results, releases)
    runs, planned, skipped = sources.runs, sources.planned, sources.skipped
    if len(runs) == 0 and not planned:
        if skipped:
            raise UserError(f"{results}: no readable run and no readable manifest ({len(skipped)} file(s) unreadable, "
                            f"first: {skipped[0]['file']}: {skipped[0]['reason']})")
        raise UserError(f"{results} holds no runs ({results / 'runs'}/*.parquet) and no sweep manifests "
                        f"({results / 'manifests'}/*.json): nothing to build")
    try:
        with writing(args.out):  # a full disk: one line naming the file (or the output directory) and the free space
            lb, out = build(args, sources, quarantined_files(results) if results.is_dir() else [])
    except (SiteError, StampError) as exc:
        raise UserError(str(exc)) from exc
    except PermissionError as exc:
        raise UserError(f"cannot write {exc.filename or exc} ({exc.strerror}); pass --out DIR / --site DIR "
                        "to write elsewhere") from exc
    print(summary(lb, out, args))
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    return run_cli(lambda: run(parse_args(argv)), (), argv)


if __name__ == "__main__":
    sys.exit(main())
