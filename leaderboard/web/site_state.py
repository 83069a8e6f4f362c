"""What the page builders share during one site build: inputs, and which files ended up in the site."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from leaderboard.outputs.marks import MARKS
from leaderboard.outputs.paper_figures import FigureSet
from leaderboard.runs.aggregate import Group, Leaderboard
from leaderboard.runs.sources import Sources

#: The pages every page links to in its header (path from the site root, label).
NAV = (("index.html", "Table 1"), ("index.html#table1-section", "Long table"), ("ranking.html", "Ranking"),
       ("track.html", "Generalisation"), ("runs/index.html", "All runs"))


@dataclass
class SiteBuild:
    """Inputs of the build and the site-relative paths of everything copied or drawn into it."""

    lb: Leaderboard
    sources: Sources
    results_name: str
    figures: FigureSet
    out: Path
    stamp: str = ""
    stats: Any = None  # leaderboard.stats.LeaderboardStats, or None when the statistics were not computed
    gifs: dict[str, str] = field(default_factory=dict)  # run id -> path relative to site root
    gif_choices: dict[tuple[Group, str, str, str], dict[str, Any]] = field(default_factory=dict)
    layouts: dict[str, str] = field(default_factory=dict)  # scenario -> image path relative to site root
    layout_notes: dict[str, str] = field(default_factory=dict)  # scenario -> why there is no image
    learn: dict[str, str] = field(default_factory=dict)  # run id -> curve path relative to site root
    updates: dict[str, str] = field(default_factory=dict)  # run id -> diagnostics image relative to site root
    #: (group, chain, scenario) -> {"curves": path, "curves_note": text, "tradeoff": path}
    row_figures: dict[tuple[Group, str, str], dict[str, str]] = field(default_factory=dict)
    #: group -> [(kind, path relative to site root)] of the ranking figures
    ranking_figures: dict[Group, list[tuple[str, str]]] = field(default_factory=dict)
    #: page kind ("table1", "ranking", "scenario", "runs") -> [(label, path relative to site root)]
    downloads: dict[str, list[tuple[str, str]]] = field(default_factory=dict)
    pages: int = 0
    pages_reused: int = 0  # run pages linked from the page cache instead of rendered

    def colour(self, learner: str) -> str:
        return self.figures.colours.get(learner, "#999999")

    def resamples(self, part: str) -> str:
        """The bootstrap resamples of one statistic (``cells``, ``aggregates``, ``improvement``, ...) as the pages say it."""
        count = (self.stats.resamples if self.stats is not None else {}).get(part)
        return f"{count:,}" if count else "no"

    def downloads_of(self, kind: str) -> list[tuple[str, str]]:
        return list(self.downloads.get(kind, []))

    def common(self, title: str, root: str, current: str) -> dict[str, Any]:
        """The context every page's frame (``base.html``) needs."""
        return {"title": title, "root": root, "current": current, "nav": NAV, "stamp": self.stamp,
                "results_name": self.results_name, "source_parts": self.source_parts(), "marks": MARKS}

    def source_parts(self) -> list[tuple[str, str]]:
        """Where the shown runs come from, for page headers: (``your runs`` | ``release``, the path or name)."""
        parts = [("your runs", str(self.sources.results))] if self.sources.has_results_runs else []
        return parts + [("release", release.name) for release in self.sources.releases]
