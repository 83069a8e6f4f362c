"""The build's slow stages behind content-keyed caches in ``<out>/cache``: the bootstrap statistics,
their figures, and Figure 2 with the radars.

Why: after a sweep that changed nothing these take most of a rebuild (up to 20,000 bootstrap
resamples per interval; dozens of matplotlib figures at a fraction of a second each), and their
results depend only on a few frames. Each stage's key is a digest of those frames, its
parameters, the source code that computes it and the versions of the numerical libraries; a
stored result is reused only under the same key and, for figures, only while every file it lists
still has the bytes it was written with. So a rebuild writes what a fresh build would, byte for
byte, and any edit to a run changes the keys of exactly the stages whose inputs it changes.
"""

from __future__ import annotations

import importlib.metadata
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from leaderboard.outputs import paper_figures as figures_module
from leaderboard.outputs import stats_figures as stat_figures_module
from leaderboard.outputs.paper_figures import FigureSet, write_figures
from leaderboard.outputs.stats_figures import StatFigures, write_stat_figures
from leaderboard.runs import display_order as display_module
from leaderboard.runs.aggregate import Leaderboard
from leaderboard.runs.sources import Sources
from leaderboard.stats import LeaderboardStats, compute_stats, resample_counts
from leaderboard.web.content_cache import cached_outputs, digest, frame_digest

Progress = Callable[[Iterable[Any], str, int], Iterable[Any]]
CACHE = Path("cache")
#: Libraries whose upgrade can change a number or a figure's bytes.
LIBRARIES = ("numpy", "scipy", "pandas", "matplotlib")


def library_versions() -> str:
    out = []
    for name in LIBRARIES:
        try:
            out.append(f"{name}=={importlib.metadata.version(name)}")
        except importlib.metadata.PackageNotFoundError:
            out.append(f"{name} absent")
    return ";".join(out)


def code_digest(*files: Path) -> str:
    """Source files, in order, and the library versions."""
    return digest([library_versions(), *(p.read_bytes() for p in files)])


def stats_code() -> str:
    stats_dir = Path(compute_stats.__code__.co_filename).parent
    return code_digest(*sorted(stats_dir.glob("*.py")))


def stats_key(lb: Leaderboard, with_reference: bool, sources: Sources, resamples: int | None = None) -> str:
    return digest([stats_code(), frame_digest(lb.runs), frame_digest(lb.table) if with_reference else "no reference",
                   sources.learn_digest(), repr(sorted(resample_counts(resamples).items()))])


def statistics(lb: Leaderboard, with_reference: bool, sources: Sources, out_dir: Path, resamples: int | None = None,
               ) -> tuple[LeaderboardStats, str, bool]:
    """:func:`compute_stats` of the build, cached; returns the statistics, their key and whether they were cached.

    ``resamples``: of every interval; None: each statistic's own (:data:`leaderboard.stats.RESAMPLES`).
    The learn-time tables are read only when the statistics are computed (their digest is the key's part)."""
    key = stats_key(lb, with_reference, sources, resamples)
    stats, hit = cached_outputs(
        out_dir / CACHE / "statistics.json", key,
        lambda: compute_stats(lb.runs, lb.table if with_reference else None, sources.learn(), n_resamples=resamples),
        lambda _: [])
    return stats, key, hit


def _files_of_figures(found: FigureSet) -> list[Path]:
    return [*found.bars.values(), *found.radars.values()]


def paper_figures(lb: Leaderboard, out_dir: Path, progress: Progress | None = None) -> tuple[FigureSet, bool]:
    """Figure 2 per (sweep, chain) and a radar per (sweep, chain, scenario) (:func:`write_figures`), cached."""
    figures_dir = out_dir / "figures"
    key = digest([code_digest(Path(figures_module.__file__), Path(display_module.__file__)), frame_digest(lb.norms_by_chain),
                  frame_digest(lb.norms_by_scenario), repr(lb.learners), repr(lb.groups), str(figures_dir.resolve())])
    found, hit = cached_outputs(
        out_dir / CACHE / "figures.json", key, lambda: write_figures(lb, figures_dir, progress),
        lambda f: [*_files_of_figures(f), figures_dir / "figure2_data.csv", figures_dir / "radar_data.csv"])
    return found, hit


def statistics_figures(lb: Leaderboard, stats: LeaderboardStats, key: str, out_dir: Path, colours: dict[str, str],
                       progress: Progress | None = None) -> tuple[StatFigures, bool]:
    """Every statistics figure (:func:`write_stat_figures`), cached under the statistics' key."""
    figures_dir = out_dir / "figures"
    stat_key = digest([key, code_digest(Path(stat_figures_module.__file__),
                                        Path(stat_figures_module.sf.__file__)),
                       frame_digest(lb.table), repr(lb.groups), repr(sorted(colours.items())),
                       str(figures_dir.resolve())])

    def files(found: StatFigures) -> list[Path]:
        return [*(p for items in found.ranking.values() for _, p in items), *found.curves.values(),
                *found.tradeoffs.values()]

    return cached_outputs(out_dir / CACHE / "stat_figures.json", stat_key,
                          lambda: write_stat_figures(lb, stats, figures_dir, colours, progress), files)
