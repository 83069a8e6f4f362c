"""``python -m leaderboard.compare AFTER --before BEFORE``: Table 1 cell by cell, before vs after vs the paper.

A change to a learner (a fixed bug, a reproduced quirk, a new default) is judged by what it does to
Table 1: which cells moved, by how much, and whether towards the paper's published values. This
command answers that from two results directories (or one directory and a saved ``table1_all.csv``
of an earlier leaderboard build, when the earlier run files are gone), aggregated by exactly the
leaderboard's rules (:func:`leaderboard.runs.aggregate.aggregate`: one configuration per cell,
superseded runs left out, completeness per cell). It never writes into either results directory.

Output (Markdown, to stdout or ``--out``): per (protocol, preset) of AFTER, one row per Table 1 row
with, per learner, the before value, the after value, the paper's value and whether the cell moved
closer to the paper; an incomplete cell is shown with its counts and is left out of every
comparison (its mean is over other runs than the paper's). Then a summary per learner (rows closer
/ further, mean absolute distance to the paper before and after, over the rows complete on both
sides) and, for learners that write per-update diagnostics (``runs/<id>.updates.parquet``: PPO-Lag
and CPO), what their updates did: the share of one-pass updates, the final Lagrange multiplier,
CPO's case counts and the share of updates that accepted a step.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from leaderboard.build import load
from leaderboard.outputs.tables import fmt, md_escape
from leaderboard.runs.aggregate import aggregate, learner_order, row_order
from morality_gym.clitools import OneLineParser, UserError, run_cli
from morality_gym.results.schema import read_updates

#: The cell columns a side must provide (both a results directory and a table1_all.csv give them).
_CELL = ["protocol", "preset", "chain", "scenario", "learner"]
#: Distances to the paper that differ by less than this are "same": the table shows 3 decimals.
_SAME = 5e-4
_VALUES = ["mean", "paper", "complete", "n_variants", "n_variants_expected", "n_seeds", "n_seeds_expected"]


@dataclass
class Side:
    """One side of the comparison: its learner cells and, for a results directory, the runs counted."""

    source: Path
    cells: pd.DataFrame
    runs: pd.DataFrame | None  # None for a CSV side (no run files to read diagnostics from)


def load_side(path: Path) -> Side:
    """A results directory (aggregated here) or a ``table1_all.csv`` written by ``leaderboard.build``."""
    if path.is_dir():
        runs, planned, _skipped = load(path)  # the leaderboard build's own reader
        if runs.empty:
            raise UserError(f"{path}: no readable runs (expected run files in {path / 'runs'})")
        lb = aggregate(runs, planned)
        cells = lb.table.loc[lb.table["kind"] == "learner"]
        return Side(path, cells[_CELL + _VALUES].reset_index(drop=True), lb.runs)
    if path.suffix == ".csv" and path.is_file():
        frame = pd.read_csv(path)
        missing = [c for c in _CELL + ["mean"] if c not in frame.columns]
        if missing:
            raise UserError(
                f"{path}: not a table1_all.csv written by leaderboard.build (missing columns {', '.join(missing)}); "
                "pass a results directory or <site>/../table1_all.csv"
            )
        if "kind" in frame.columns:
            frame = frame.loc[frame["kind"] == "learner"]
        for column in _VALUES:
            if column not in frame.columns:
                frame[column] = True if column == "complete" else math.nan
        frame["complete"] = frame["complete"].astype(bool)
        return Side(path, frame[_CELL + _VALUES].reset_index(drop=True), None)
    raise UserError(f"{path}: neither a results directory nor a .csv file")


def _cell_text(row: pd.Series | None) -> str:
    if row is None or pd.isna(row["mean"]):
        return "–"
    text = fmt(row["mean"])
    if not bool(row["complete"]):
        text += f" ⚠ {row['n_variants']}/{row['n_variants_expected']} variants, {row['n_seeds']}/{row['n_seeds_expected']} seeds"
    return text


def _usable(row: pd.Series | None) -> bool:
    return row is not None and bool(row["complete"]) and not pd.isna(row["mean"])


def compare_group(before: pd.DataFrame | None, after: pd.DataFrame, learners: list[str]) -> tuple[list[str], pd.DataFrame]:
    """The Markdown table of one (protocol, preset) and the per-row distances used by the summary."""
    header = ["chain", "scenario"]
    for learner in learners:
        header += [f"{learner} before", f"{learner} after", f"{learner} paper", f"{learner} → paper"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * 2 + "---:|---:|---:|:---:|" * len(learners)]
    distances = []
    index_after = {tuple(r[c] for c in ("chain", "scenario", "learner")): r for _, r in after.iterrows()}
    index_before = ({tuple(r[c] for c in ("chain", "scenario", "learner")): r for _, r in before.iterrows()}
                    if before is not None else {})
    for chain, scenario in row_order(zip(after["chain"], after["scenario"])):
        cells = [md_escape(chain), md_escape(scenario)]
        for learner in learners:
            new, old = index_after.get((chain, scenario, learner)), index_before.get((chain, scenario, learner))
            paper = new["paper"] if new is not None else (old["paper"] if old is not None else math.nan)
            verdict = ""
            if _usable(new) and _usable(old) and not pd.isna(paper):
                d_old, d_new = abs(old["mean"] - paper), abs(new["mean"] - paper)
                verdict = _verdict(d_old, d_new)
                distances.append({"learner": learner, "before": d_old, "after": d_new, "verdict": verdict})
            cells += [_cell_text(old), _cell_text(new), fmt(paper), verdict]
        lines.append("| " + " | ".join(cells) + " |")
    return lines, pd.DataFrame(distances, columns=["learner", "before", "after", "verdict"])


def _verdict(d_old: float, d_new: float) -> str:
    """``same``, ``closer`` or ``further``: how the distance to the paper changed."""
    if abs(d_new - d_old) < _SAME:
        return "same"
    return "closer" if d_new < d_old else "further"


def summary_lines(distances: pd.DataFrame, learners: list[str]) -> list[str]:
    lines = []
    for learner in learners:
        d = distances.loc[distances["learner"] == learner]
        if d.empty:
            lines.append(f"- **{learner}**: no row complete on both sides.")
            continue
        counts = d["verdict"].value_counts()
        lines.append(
            f"- **{learner}** ({len(d)} rows complete on both sides): {counts.get('closer', 0)} closer to the paper, "
            f"{counts.get('further', 0)} further, {counts.get('same', 0)} unchanged; mean |value − paper| "
            f"{d['before'].mean():.3f} before, {d['after'].mean():.3f} after."
        )
    return lines


def diagnostics_lines(results: Path, runs: pd.DataFrame, protocol: str, preset: str) -> list[str]:
    """What the counted runs' updates did (only learners that write ``.updates.parquet``)."""
    chosen = runs.loc[(runs["protocol"] == protocol) & (runs["preset"] == preset) & runs["ok"]]
    lines = []
    for learner in learner_order(chosen["learner"].unique()):
        frames = []
        for run_id in chosen.loc[chosen["learner"] == learner, "run_id"]:
            try:
                frames.append(read_updates(results, run_id).assign(run_id=run_id))
            except (FileNotFoundError, OSError, ValueError):
                continue
        frames = [frame for frame in frames if len(frame)]
        if not frames:
            continue
        u = pd.concat(frames, ignore_index=True)
        last = u.sort_values("update").groupby("run_id").tail(1)
        parts = [f"{len(u):,} updates in {u['run_id'].nunique()} runs"]
        if u["passes"].notna().any():
            parts.append(f"{(u['passes'] == 1).mean():.1%} of updates ran one pass (mean {u['passes'].mean():.2f}, "
                         f"max {int(u['passes'].max())})")
        if last["lagrange_multiplier"].notna().any():
            lm = last["lagrange_multiplier"]
            parts.append(f"final multiplier mean {lm.mean():.3f} (range {lm.min():.3f}-{lm.max():.3f})")
        if u["cpo_case"].notna().any():
            cases = {int(k): int(v) for k, v in u["cpo_case"].value_counts().sort_index().items()}
            accepted = u["accept_step"] > 0
            by_case = ", ".join(f"case {int(k)}: {v:.1%}" for k, v in accepted.groupby(u["cpo_case"]).mean().items())
            steps = u.loc[accepted, "accept_step"]
            parts.append(f"cases {cases}; {accepted.mean():.1%} of updates accepted a step ({by_case})"
                         + (f", at backtracking step {steps.mean():.2f} on average" if len(steps) else ""))
        if last["ep_cost"].notna().any():
            parts.append(f"final J_c mean {last['ep_cost'].mean():.3f}")
        lines.append(f"- **{learner}**: " + "; ".join(parts) + ".")
    return lines


def report(after: Side, before: Side | None, learners: Sequence[str] | None = None,
           protocols: Sequence[str] | None = None) -> str:
    """The whole Markdown report (see the module docstring)."""
    lines = [f"# Table 1: {after.source}" + (f" against {before.source}" if before else ""), ""]
    groups = after.cells[["protocol", "preset"]].drop_duplicates().sort_values(["protocol", "preset"])
    if protocols:
        groups = groups.loc[groups["protocol"].isin(protocols)]
    if groups.empty:
        raise UserError(f"{after.source}: no learner cells" + (f" for protocol {', '.join(protocols)}" if protocols else ""))
    for protocol, preset in groups.itertuples(index=False):
        lines += _group_section(after, before, learners, protocol, preset)
    return "\n".join(lines)


def _group_section(after: Side, before: Side | None, learners: Sequence[str] | None, protocol: str,
                   preset: str) -> list[str]:
    """One (protocol, preset): the table, the summary against ``before``, and the update diagnostics."""
    mine = after.cells.loc[(after.cells["protocol"] == protocol) & (after.cells["preset"] == preset)]
    names = _chosen_learners(mine, learners, protocol, preset)
    mine = mine.loc[mine["learner"].isin(names)]
    theirs = None
    if before is not None:
        theirs = before.cells.loc[(before.cells["protocol"] == protocol) & (before.cells["preset"] == preset)]
    lines = [f"## Protocol `{protocol}`, preset `{preset}`", ""]
    if before is not None and theirs is not None and theirs.empty:
        lines += [f"{before.source} has no cells of this protocol and preset: the before columns are empty.", ""]
    table, distances = compare_group(theirs, mine, names)
    lines += table + [""]
    if before is not None:
        lines += ["Summary (rows complete on both sides; \"closer\" = |after − paper| < |before − paper|):", ""]
        lines += summary_lines(distances, names) + [""]
    if after.runs is not None:
        diag = diagnostics_lines(after.source, after.runs, protocol, preset)
        if diag:
            lines += ["Per-update diagnostics of the counted runs (`runs/<id>.updates.parquet`):", ""] + diag + [""]
    return lines


def _chosen_learners(mine: pd.DataFrame, learners: Sequence[str] | None, protocol: str, preset: str) -> list[str]:
    """The learners to show: ``--learner``'s (each must have cells here), else all of the group's."""
    names = learner_order(mine["learner"].unique())
    if not learners:
        return names
    unknown = [name for name in learners if name not in names]
    if unknown:
        raise UserError(f"--learner {', '.join(unknown)}: not among the learners of protocol {protocol}, "
                        f"preset {preset} ({', '.join(names)})")
    return list(learners)


def build_parser() -> argparse.ArgumentParser:
    """The command's parser, apart from parsing: the docs' command-line reference is generated from it."""
    parser = OneLineParser(prog="python -m leaderboard.compare", description=__doc__.split("\n\n")[0])
    parser.add_argument("after", type=Path, help="results directory (or table1_all.csv) with the new runs")
    parser.add_argument("--before", type=Path, help="results directory or table1_all.csv of the earlier runs")
    parser.add_argument("--learner", action="append", help="learner label to show (repeatable), e.g. 'PPO Lag'")
    parser.add_argument("--protocol", action="append", help="protocol to show (repeatable); default: all")
    parser.add_argument("--out", type=Path, help="write the Markdown here instead of stdout")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error")
    return parser


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def run(args: argparse.Namespace) -> int:
    after = load_side(args.after)
    before = load_side(args.before) if args.before else None
    text = report(after, before, args.learner, args.protocol)
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
