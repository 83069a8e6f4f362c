"""Where a leaderboard build's runs come from: a results directory, releases, or both.

Why one place: every later stage (aggregation, statistics, per-run figures, GIFs, run pages) must
not care whether a run was computed on this machine or shipped in a release. A release's rows are
the same run rows (:mod:`leaderboard.runs.releases`), so they join the results directory's rows in one
DataFrame with a ``source`` column; only the side files (learn-time evaluations, update diagnostics,
GIFs, MLflow links) are found differently, and :class:`Sources` answers those per run.

A run id names a configuration, env and seed (:mod:`morality_gym.results.identity`), so a run present in the
results directory and in a release is the same run computed twice: the results directory's copy is
counted (it is the user's own, and may be newer code), the release's is dropped and counted in
:attr:`Sources.shadowed`. The first release listed wins over later ones likewise.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from leaderboard.runs.releases import Release
from morality_gym.results.manifest import planned_runs
from morality_gym.results.schema import (
    LEARN_FIELDS,
    RUN_COLUMNS,
    learn_path,
    read_learn,
    read_runs,
    read_small_table,
    runs_dir,
    updates_path,
)

#: ``source`` of runs read from the results directory (a release's runs carry the release's name).
RESULTS_SOURCE = "results"


@dataclass(frozen=True)
class SideFile:
    """One run's side table (learn-time evaluations or update diagnostics): a digest of its content
    (a chart cached under another digest is redrawn) and how to read it.

    The digest is cheaper than reading the table: the file's bytes hashed for a results directory,
    the release's own checksum of its table plus the run id for a release."""

    name: str  # the file (a release's table names its release), for error messages
    digest: Callable[[], str]
    read: Callable[[], pd.DataFrame]


def _split_by_run(frame: pd.DataFrame) -> dict[str, pd.DataFrame]:
    if frame.empty or "run_id" not in frame.columns:
        return {}
    return {str(k): part.reset_index(drop=True) for k, part in frame.groupby("run_id", sort=False)}


@dataclass
class Sources:
    """The runs of one build, with the answers the later stages need per run."""

    results: Path | None
    releases: list[Release]
    runs: pd.DataFrame
    planned: dict[str, dict[str, Any]]
    skipped: list[dict[str, str]]
    origin: dict[str, str]  # run id -> RESULTS_SOURCE or a release name
    shadowed: int = 0  # release runs dropped because the results directory (or an earlier release) has them
    results_planned: int = 0  # runs the results directory's own manifests plan
    _learn: dict[str, dict[str, pd.DataFrame]] = field(default_factory=dict)
    _updates: dict[str, dict[str, pd.DataFrame]] = field(default_factory=dict)
    _digests: dict[Path, str] = field(default_factory=dict)

    # -------------------------------------------------------------------------------- labels
    @property
    def name(self) -> str:
        """How pages name where the numbers come from: ``results + release X (commit, date)``."""
        parts = [str(self.results)] if self.results is not None and self.has_results_runs else []
        parts += [r.label for r in self.releases]
        return " + ".join(parts) if parts else str(self.results or "no runs")

    @property
    def has_results_runs(self) -> bool:
        return RESULTS_SOURCE in self.origin.values() or self.results_planned > 0

    def replaced_note(self, release: Release, shown: int, name: Callable[[str], str]) -> str:
        """Why a release shows only ``shown`` of its runs: `` (N replaced by the runs of the same
        configuration in <who>)``, or ``""`` when it shows them all. The winners are the sources that
        took its run ids (the results directory first, then the releases listed before it), so an
        earlier release is never credited as "your runs"; ``name`` words a source for the reader (the
        page says "your runs", the build log the directory's path). One wording for both."""
        hidden = len(release.runs) - shown
        if hidden <= 0:
            return ""
        winners = {self.origin.get(str(i)) for i in release.runs["run_id"]} - {release.name, None}
        who = " and ".join(name(w) for w in sorted(winners, key=lambda w: (w != RESULTS_SOURCE, w)))
        return f" ({hidden} replaced by {f'the runs of the same configuration in {who}' if who else 'newer runs of the same slot'})"

    def release_of(self, run_id: str) -> Release | None:
        name = self.origin.get(run_id)
        return next((r for r in self.releases if r.name == name), None)

    # -------------------------------------------------------------------------------- side files
    def learn(self) -> pd.DataFrame:
        """Every counted run's learn-time evaluations (the statistics' learning curves)."""
        frames = [read_learn(self.results)] if self.results is not None and self.results.is_dir() else []
        for release in self.releases:
            if not release.learn.empty:
                keep = [i for i, origin in self.origin.items() if origin == release.name]
                frames.append(release.learn.loc[release.learn["run_id"].isin(keep)])
        frames = [f for f in frames if not f.empty]
        if not frames:
            return pd.DataFrame(columns=[f.name for f in LEARN_FIELDS])
        return pd.concat(frames, ignore_index=True, sort=False)

    def file_digest(self, path: Path) -> str:
        """SHA-256 of a file's bytes, once per build (the per-run charts and the statistics both ask)."""
        if path not in self._digests:
            self._digests[path] = hashlib.sha256(path.read_bytes()).hexdigest()
        return self._digests[path]

    def learn_digest(self) -> str:
        """A digest of what :meth:`learn` returns, without reading the tables: every learn-time
        file of the results directory by name and content, and per release its table's checksum
        and the runs it contributes. The statistics are cached under it."""
        parts: list[str] = []
        if self.results is not None and self.results.is_dir():
            for path in sorted(runs_dir(self.results).glob("*.learn.parquet")):
                parts += [path.name, self.file_digest(path)]
        for release in self.releases:
            keep = sorted(i for i, origin in self.origin.items() if origin == release.name)
            parts += [release.name, str(release.manifest["files"].get("learn.parquet", {}).get("sha256", "")), *keep]
        return hashlib.sha256("\0".join(parts).encode("utf-8")).hexdigest()

    def _release_side(self, run_id: str, kind: str) -> SideFile | None:
        release = self.release_of(run_id)
        if release is None:
            return None
        cache = self._learn if kind == "learn" else self._updates
        if release.name not in cache:
            cache[release.name] = _split_by_run(release.learn if kind == "learn" else release.updates)
        frame = cache[release.name].get(run_id)
        if frame is None:
            return None
        file = "learn.parquet" if kind == "learn" else "updates.parquet"
        checksum = str(release.manifest["files"].get(file, {}).get("sha256", ""))
        return SideFile(f"{file} of release {release.name}", lambda: f"{release.name}/{checksum}/{run_id}", lambda: frame)

    def _results_side(self, path: Path) -> SideFile | None:
        if not path.is_file():
            return None
        return SideFile(path.name, lambda: self.file_digest(path), lambda: read_small_table(path).to_pandas())

    def learn_of(self, run_id: str) -> SideFile | None:
        if self.origin.get(run_id) == RESULTS_SOURCE and self.results is not None:
            return self._results_side(learn_path(self.results, run_id))
        return self._release_side(run_id, "learn")

    def updates_of(self, run_id: str) -> SideFile | None:
        if self.origin.get(run_id) == RESULTS_SOURCE and self.results is not None:
            return self._results_side(updates_path(self.results, run_id))
        return self._release_side(run_id, "updates")

    def gif_of(self, run_id: str, gif_path: Any) -> Path | None:
        """The run's GIF if it exists inside its source's directory (a path pointing elsewhere is
        ignored rather than copied: the site must not pick up arbitrary files)."""
        if gif_path is None or (isinstance(gif_path, float) and pd.isna(gif_path)):
            return None
        release = self.release_of(run_id)
        base = release.path if release is not None else self.results
        if base is None:
            return None
        path = (base / str(gif_path)).resolve()
        return path if path.is_file() and path.is_relative_to(base.resolve()) else None

    def tracking_dir(self, run_id: str) -> Path | None:
        """``<results>/tracking`` for the results directory's runs; a release has no MLflow store."""
        if self.origin.get(run_id) == RESULTS_SOURCE and self.results is not None:
            return self.results / "tracking"
        return None


def load_sources(results: Path | None, releases: list[Release]) -> Sources:
    """All readable run rows and planned runs of ``results`` and ``releases``, one row per run id."""
    skipped: list[dict[str, str]] = []
    frames: list[pd.DataFrame] = []
    origin: dict[str, str] = {}
    planned: dict[str, dict[str, Any]] = {}
    shadowed = 0
    if results is not None and results.is_dir():
        own = read_runs(results, skipped=skipped)
        frames.append(own.assign(source=RESULTS_SOURCE))
        origin.update(dict.fromkeys(own["run_id"].astype(str), RESULTS_SOURCE))
        planned = planned_runs(results, skipped=skipped)
    n_own = len(planned)
    for release in releases:
        fresh = ~release.runs["run_id"].astype(str).isin(origin)
        shadowed += int((~fresh).sum())
        mine = release.runs.loc[fresh]
        frames.append(mine.assign(source=release.name))
        origin.update(dict.fromkeys(mine["run_id"].astype(str), release.name))
        for run_id, plan in planned_runs(release.path, skipped=skipped).items():
            planned.setdefault(run_id, plan)
    frames = [f for f in frames if not f.empty]
    runs = pd.concat(frames, ignore_index=True, sort=False) if frames else pd.DataFrame(columns=[*RUN_COLUMNS, "source"])
    return Sources(results, releases, runs, planned, skipped, origin, shadowed, n_own)
