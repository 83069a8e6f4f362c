"""Every table of the site as CSV, and all runs as one Parquet file, under ``<site>/data/``.

Why: a reader who wants to re-plot or re-test a number should not have to scrape HTML or re-run
the build; the files hold exactly what the pages show (the same frames), with full precision.
The pages link to them (:attr:`SiteBuild.downloads`).

Bytes are reproducible: CSV is text with a fixed float format, and the Parquet file is written
by pyarrow without a time stamp (its footer names the pyarrow version, as any Parquet writer does).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from leaderboard.runs.aggregate import Leaderboard

DATA_DIR = "data"
FLOAT_FORMAT = "%.6f"


def _csv(frame: pd.DataFrame, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    frame.to_csv(path, index=False, float_format=FLOAT_FORMAT, lineterminator="\n")


def runs_parquet(runs: pd.DataFrame, path: Path) -> None:
    """All runs (failed ones too, with their error), one row each, as the build read them."""
    path.parent.mkdir(parents=True, exist_ok=True)
    table = pa.Table.from_pandas(runs.reset_index(drop=True), preserve_index=False)
    pq.write_table(table, path, compression="zstd")


def write_downloads(lb: Leaderboard, stats: Any, site_dir: Path) -> dict[str, list[tuple[str, str]]]:
    """Write the files; returns, per page kind, the (label, site-relative path) links to show."""
    files: list[tuple[str, str, pd.DataFrame | None, tuple[str, ...]]] = [
        ("Table 1 (all sweeps, CSV)", "table1_all.csv", lb.table, ("table1", "scenario")),
        ("runs (CSV)", "runs.csv", lb.runs.drop(columns=[c for c in ("config", "versions", "traceback")
                                                          if c in lb.runs.columns]), ("runs",)),
        ("Figure 2 data (CSV)", "figure2_data.csv", lb.norms_by_chain.drop(columns="rank", errors="ignore"), ("table1",)),
        ("per-variant means (CSV)", "variants.csv",
         lb.variants.drop(columns=[c for c in ("run_ids", "seeds") if c in lb.variants.columns]), ("scenario",)),
        ("missing and failed runs (CSV)", "problems.csv",
         pd.concat([lb.problems.assign(problem="failed"), lb.missing.assign(problem="missing")], ignore_index=True),
         ("runs",)),
    ]
    if len(lb.superseded):
        files.append(("superseded runs (CSV)", "superseded.csv", lb.superseded, ("runs",)))
    if stats is not None:
        files += [
            ("cell intervals (CSV)", "cell_intervals.csv", stats.cells, ("table1", "ranking")),
            ("ranking aggregates (CSV)", "ranking_aggregates.csv", stats.aggregates, ("ranking",)),
            ("probability of improvement (CSV)", "probability_of_improvement.csv", stats.improvement, ("ranking",)),
            ("performance profiles (CSV)", "performance_profiles.csv", stats.profiles, ("ranking",)),
            ("rows in the ranking (CSV)", "ranking_rows.csv", stats.rows, ("ranking",)),
            ("pooled learning curves (CSV)", "learning_curves.csv", stats.curves, ("scenario",)),
            ("return and cost per run (CSV)", "return_cost.csv", stats.points, ("scenario",)),
            ("violation rates (CSV)", "violation_rates.csv", stats.violations, ("scenario",)),
        ]
    links: dict[str, list[tuple[str, str]]] = {}
    for label, name, frame, kinds in files:
        if frame is None:
            continue
        _csv(frame, site_dir / DATA_DIR / name)
        for kind in kinds:
            links.setdefault(kind, []).append((label, f"{DATA_DIR}/{name}"))
    runs_parquet(lb.runs, site_dir / DATA_DIR / "runs.parquet")
    for kind in ("table1", "runs", "ranking", "scenario"):
        links.setdefault(kind, []).append(("all runs (Parquet)", f"{DATA_DIR}/runs.parquet"))
    return links
