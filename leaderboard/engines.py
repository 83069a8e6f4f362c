"""``python -m leaderboard.engines SINGLE FLEET``: the same Table 1 trained by two engines, side by side.

The fleet engine (``engine=fleet``) trains many runs at once and reproduces each run's arithmetic to
float tolerance, not bit for bit (batched products round differently; a near-tie in an action draw
can then go the other way, and the two trainings part). So the claim to check on real sweeps is
statistical: a Table 1 trained by the fleet is the single engine's Table 1 up to seed noise. A
fleet run has the run id of its single run (the engine is not part of a run's identity), so the two
results directories of the same plan pair up run by run.

Output (Markdown, to stdout or ``--out``), per (protocol, preset):

* per Table 1 cell (complete on both sides): each engine's mean with its spread over seeds (the
  standard deviation of the per-seed means, as the leaderboard computes it), the difference, how
  many of the paired runs ended at the same metric (to 3 decimals), and a two-sided Wilcoxon
  signed-rank test of the paired runs' differences (``scipy.stats.wilcoxon``);
* per learner: mean and largest |difference| over its cells, the cells whose difference exceeds
  the larger of the two seed spreads, the share of identical runs, the test over all its paired
  runs, and the compute each engine spent on the runs both sides finished (the runs' core-seconds
  summed, :func:`~morality_gym.results.schema.compute_seconds`: CPU time where a run recorded it,
  else wall time; a fleet run's is its share of the fleet's training plus its own evaluation), so
  an unfinished side is compared on what it did, and a side that shared its machine is not
  charged for the wait;
* the wall-clock span of each side's sweep (first run started to last run finished).

Either side may also be a release (``releases/<name>``) and the two sides any two sweeps of the
same plan: ``--names`` labels them (default ``single`` and ``fleet``). So the same report checks
that a newer fleet engine reproduces a shipped Table 1, e.g.
``python -m leaderboard.engines releases/paper-table1-v1 RESULTS --names release main``. Rows that
only one side has (a release holds the whole table, a rerun a few rows) are left out and counted
in one line.

Neither side is written to.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from leaderboard.build import load
from leaderboard.outputs.tables import fmt, md_escape
from leaderboard.runs.aggregate import aggregate, learner_order, row_order
from leaderboard.runs.releases import MANIFEST, ReleaseError
from leaderboard.runs.releases import load as load_release
from leaderboard.runs.sources import load_sources
from morality_gym.clitools import OneLineParser, UserError, duration, run_cli
from morality_gym.results.schema import compute_seconds

_CELL = ["protocol", "preset", "chain", "scenario", "learner"]
#: The two sides' labels unless ``--names`` says otherwise: the comparison this tool was made for.
NAMES = ("single", "fleet")
#: Two metrics closer than this print the same at 3 decimals: the runs are counted as identical.
SAME = 5e-4


@dataclass
class Results:
    """One engine's results: its Table 1 learner cells and its counted runs."""

    source: Path
    cells: pd.DataFrame
    runs: pd.DataFrame


def load_results(path: Path) -> Results:
    """A results directory or a release, aggregated by the leaderboard's own rules."""
    if (path / MANIFEST).is_file():
        try:
            sources = load_sources(None, [load_release(path)])
        except ReleaseError as exc:
            raise UserError(str(exc)) from exc
        runs, planned = sources.runs.drop(columns="source"), sources.planned
    elif path.is_dir():
        runs, planned, _skipped = load(path)
    else:
        raise UserError(f"{path}: not a results directory (nor a release: no {MANIFEST})")
    if runs.empty:
        raise UserError(f"{path}: no readable runs (expected run files in {path / 'runs'})")
    lb = aggregate(runs, planned)
    cells = lb.table.loc[lb.table["kind"] == "learner"].reset_index(drop=True)
    counted = lb.runs.loc[lb.runs["ok"]].copy()
    return Results(path, cells, counted)


def paired_runs(single: pd.DataFrame, fleet: pd.DataFrame) -> pd.DataFrame:
    """The runs both sides counted, by run id: cell keys, seed, both metrics, both computes (core-seconds)."""
    single, fleet = single.assign(compute_s=compute_seconds(single)), fleet.assign(compute_s=compute_seconds(fleet))
    keep = [*_CELL, "run_id", "seed", "metric", "compute_s", "engine"]
    merged = single[keep].merge(fleet[["run_id", "metric", "compute_s", "engine"]], on="run_id", suffixes=("_single", "_fleet"))
    merged["diff"] = merged["metric_fleet"] - merged["metric_single"]
    return merged


def wilcoxon_p(diffs: np.ndarray) -> float:
    """Two-sided Wilcoxon signed-rank p-value of paired differences (1.0 when all are zero, NaN
    with fewer than two non-zero differences)."""
    nonzero = diffs[np.abs(diffs) > 0]
    if len(nonzero) == 0:
        return 1.0
    if len(nonzero) < 2:
        return math.nan
    return float(stats.wilcoxon(nonzero).pvalue)


def _cell(row: pd.Series | None) -> str:
    if row is None or pd.isna(row["mean"]):
        return "–"
    spread = "" if pd.isna(row["std"]) else f" ± {row['std']:.3f}"
    text = f"{row['mean']:.3f}{spread}"
    if not bool(row["complete"]):
        text += f" ⚠ {row['n_variants']}/{row['n_variants_expected']} variants, {row['n_seeds']}/{row['n_seeds_expected']} seeds"
    return text


def _usable(row: pd.Series | None) -> bool:
    return row is not None and bool(row["complete"]) and not pd.isna(row["mean"])


def _span(runs: pd.DataFrame) -> float:
    if runs.empty:
        return math.nan
    start = pd.to_datetime(runs["started_at"], utc=True).min()
    end = pd.to_datetime(runs["finished_at"], utc=True).max()
    return float((end - start).total_seconds())


def group_report(single: Results, fleet: Results, protocol: str, preset: str,
                 names: tuple[str, str] = NAMES) -> list[str]:
    """The table, the per-learner summary and the wall times of one (protocol, preset)."""
    def select(frame: pd.DataFrame) -> pd.DataFrame:
        return frame.loc[(frame["protocol"] == protocol) & (frame["preset"] == preset)]

    s_cells, f_cells = select(single.cells), select(fleet.cells)
    rows = _common_rows(s_cells, f_cells)
    pairs = paired_runs(select(single.runs), select(fleet.runs))
    learners = learner_order(set(s_cells["learner"]) | set(f_cells["learner"]))
    lines, verdicts = _cell_table(s_cells, f_cells, pairs, learners, rows, names)
    lines += _one_sided_line(s_cells, f_cells, rows, names)
    lines += ["", "Per learner (cells complete on both sides; runs paired by run id):", ""]
    lines += _learner_table(pairs, pd.DataFrame(verdicts, columns=["learner", "diff", "spread"]), learners, names)
    lines += _span_lines(select(single.runs), select(fleet.runs), names)
    return lines


def _rows(cells: pd.DataFrame) -> set[tuple[str, str]]:
    return set(zip(cells["chain"], cells["scenario"]))


def _common_rows(s_cells: pd.DataFrame, f_cells: pd.DataFrame) -> list[tuple[str, str]]:
    """The Table 1 rows (chain, scenario) both sides have cells of, in the table's order."""
    return row_order(sorted(_rows(s_cells) & _rows(f_cells)))


def _one_sided_line(s_cells: pd.DataFrame, f_cells: pd.DataFrame, rows: list[tuple[str, str]],
                    names: tuple[str, str]) -> list[str]:
    """One line counting the rows left out because only one side has them (none: no line)."""
    only = [(name, len(_rows(cells) - set(rows))) for name, cells in zip(names, (s_cells, f_cells))]
    parts = [f"{n} only in {name}" for name, n in only if n]
    return ["", f"Rows left out, one side has none of their cells: {', '.join(parts)}."] if parts else []


def _cell_table_head(names: tuple[str, str]) -> list[str]:
    a, b = (md_escape(n) for n in names)
    return [f"| chain | scenario | learner | {a} mean ± seed sd | {b} mean ± seed sd | {b} − {a} | runs identical | Wilcoxon p |",
            "|---|---|---|---:|---:|---:|---:|---:|"]


def _cell_table(s_cells: pd.DataFrame, f_cells: pd.DataFrame, pairs: pd.DataFrame, learners: list[str],
                rows: list[tuple[str, str]], names: tuple[str, str] = NAMES) -> tuple[list[str], list[dict[str, object]]]:
    """The per-cell table of ``rows``, and each cell usable on both sides as ``{learner, diff, spread}``."""
    index_s = {tuple(r[c] for c in ("chain", "scenario", "learner")): r for _, r in s_cells.iterrows()}
    index_f = {tuple(r[c] for c in ("chain", "scenario", "learner")): r for _, r in f_cells.iterrows()}
    lines = _cell_table_head(names)
    verdicts = []
    for chain, scenario in rows:
        for learner in learners:
            s, f = index_s.get((chain, scenario, learner)), index_f.get((chain, scenario, learner))
            if s is None and f is None:
                continue
            mine = pairs.loc[(pairs["chain"] == chain) & (pairs["scenario"] == scenario) & (pairs["learner"] == learner)]
            diff_text = ""
            if _usable(s) and _usable(f):
                diff = float(f["mean"] - s["mean"])
                diff_text = f"{diff:+.3f}"
                spread = np.nanmax([s["std"], f["std"]]) if not (pd.isna(s["std"]) and pd.isna(f["std"])) else math.nan
                verdicts.append({"learner": learner, "diff": diff, "spread": spread})
            same_text, p_text = _paired_texts(mine)
            lines.append(f"| {md_escape(chain)} | {md_escape(scenario)} | {md_escape(learner)} | {_cell(s)} | {_cell(f)} | "
                         f"{diff_text} | {same_text} | {p_text} |")
    return lines, verdicts


def _paired_texts(mine: pd.DataFrame) -> tuple[str, str]:
    """A cell's paired runs: how many ended identical, and the Wilcoxon p ("" for both when none)."""
    if not len(mine):
        return "", ""
    p = wilcoxon_p(mine["diff"].to_numpy())
    return f"{int((mine['diff'].abs() < SAME).sum())}/{len(mine)}", "–" if math.isnan(p) else f"{p:.2f}"


def _learner_table(pairs: pd.DataFrame, table: pd.DataFrame, learners: list[str],
                   names: tuple[str, str] = NAMES) -> list[str]:
    """One row per learner over its usable cells and all its paired runs, compute included."""
    a, b = (md_escape(n) for n in names)
    lines = [
        (f"| learner | cells | mean abs({b} − {a}) | largest | cells beyond the seed spread | runs identical | "
         f"Wilcoxon p (all runs) | {a} compute (paired runs) | {b} compute (paired runs) | {a} / {b} |"),
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for learner in learners:
        mine = table.loc[table["learner"] == learner]
        runs = pairs.loc[pairs["learner"] == learner]
        beyond = int((mine["diff"].abs() > mine["spread"]).sum())
        p = wilcoxon_p(runs["diff"].to_numpy()) if len(runs) else math.nan
        # over the paired runs only: a side that has not finished must not look cheaper or dearer
        s_time, f_time = float(runs["compute_s_single"].sum()), float(runs["compute_s_fleet"].sum())
        cells = [
            md_escape(learner),
            str(len(mine)),
            fmt(mine["diff"].abs().mean()) if len(mine) else "–",
            fmt(mine["diff"].abs().max()) if len(mine) else "–",
            str(beyond),
            f"{int((runs['diff'].abs() < SAME).sum())}/{len(runs)}" if len(runs) else "–",
            "–" if math.isnan(p) else f"{p:.2f}",
            duration(s_time),
            duration(f_time),
            f"{s_time / f_time:.1f}x" if f_time > 0 else "–",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _span_lines(single_runs: pd.DataFrame, fleet_runs: pd.DataFrame, names: tuple[str, str] = NAMES) -> list[str]:
    """Each sweep's wall-clock span, with its run count, engines and fleet sizes."""
    engines_s = ", ".join(sorted(single_runs["engine"].dropna().unique()))
    engines_f = sorted(fleet_runs["engine"].dropna().unique())
    fleets = [e for e in engines_f if e.startswith("fleet:")]
    sizes = sorted(int(e.split(":")[1]) for e in fleets)
    return [
        "",
        f"Wall-clock span of the sweeps (first run started to last finished): {names[0]} "
        f"{duration(_span(single_runs))} ({len(single_runs)} runs; engines: {engines_s}), {names[1]} "
        f"{duration(_span(fleet_runs))} ({len(fleet_runs)} runs"
        + (f"; fleets of {sizes[0]}-{sizes[-1]} runs" if sizes else "") + "). A span includes any time a sweep "
        "was paused or stopped before it was resumed; the compute columns do not.",
        "",
    ]


def report(single: Results, fleet: Results, protocols: Sequence[str] | None = None,
           names: tuple[str, str] = NAMES) -> str:
    """The whole Markdown report (see the module docstring); ``names`` label the two sides."""
    lines = [f"# Table 1 by engine: {single.source} ({names[0]}) and {fleet.source} ({names[1]})", ""]
    groups = pd.concat([single.cells, fleet.cells])[["protocol", "preset"]].drop_duplicates().sort_values(["protocol", "preset"])
    if protocols:
        groups = groups.loc[groups["protocol"].isin(protocols)]
    if groups.empty:
        raise UserError("no learner cells" + (f" for protocol {', '.join(protocols)}" if protocols else ""))
    for protocol, preset in groups.itertuples(index=False):
        lines += [f"## Protocol `{protocol}`, preset `{preset}`", ""]
        lines += group_report(single, fleet, protocol, preset, names)
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """The command's parser, apart from parsing: the docs' command-line reference is generated from it."""
    parser = OneLineParser(prog="python -m leaderboard.engines", description=__doc__.split("\n\n")[0])
    parser.add_argument("single", type=Path,
                        help="results directory (or release) of the sweep run with engine=single, or of any first sweep")
    parser.add_argument("fleet", type=Path,
                        help="results directory (or release) of the same sweep run with engine=fleet, or of any second one")
    parser.add_argument("--names", nargs=2, metavar=("FIRST", "SECOND"), default=list(NAMES),
                        help="labels of the two sides (default: single fleet), e.g. --names release main")
    parser.add_argument("--protocol", action="append", help="protocol to show (repeatable); default: all")
    parser.add_argument("--out", type=Path, help="write the Markdown here instead of stdout")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error")
    return parser


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def run(args: argparse.Namespace) -> int:
    text = report(load_results(args.single), load_results(args.fleet), args.protocol, tuple(args.names))
    if args.out:
        args.out.write_text(text + "\n")
        print(f"wrote {args.out}")
    else:
        print(text)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run_cli(lambda: run(parse_args(argv)), (), argv)


if __name__ == "__main__":
    raise SystemExit(main())
