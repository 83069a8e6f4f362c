"""The static leaderboard site: plain HTML pages that work from ``file://`` without a server.

Why static and inline: the site is opened from a results checkout or a CI artefact, where there
is no server and browsers refuse ``fetch`` of local files. So every number is written into the
HTML itself (the small script only sorts and filters existing rows), every link is relative, and
every image, GIF and download the pages show is copied into the site directory, which can then be
zipped or moved as a whole.

This module assembles the site: it copies files and writes pages. What a page shows is built by
:mod:`leaderboard.web.pages` and :mod:`leaderboard.web.ranking_page`, how it looks lives in
``leaderboard/web/templates`` (Jinja2, autoescaped) and ``leaderboard/web/static`` (CSS, JS), rendered by
:mod:`leaderboard.web.render`.

Layout of ``<site>``::

    index.html                   Table 1 as the paper's grid (the user's newest sweep, a release's beside it),
                                 status, the long Table 1 (sortable, filterable), Figure 2
    ranking.html                 aggregate scores with intervals, probability of improvement, profiles
    track.html                   the generalisation track: seen vs unseen vs built-in (leaderboard.track)
    runs/index.html              every run with its status
    runs/<run_id>.html           one run: metrics, per-norm functions, config, curve, MLflow, error
    scenarios/<Scenario>.html    layout, variants, curves, return vs cost, violations, breakdown, GIFs
    assets/ figures/ gifs/ (every run's episode, hard-linked) scenarios/img/ runs/img/ data/ (CSV and Parquet downloads)

The directory is rebuilt from scratch into a temporary sibling and swapped in at the end, so a
failed build leaves the previous site intact; a directory that was not made by this module is
never deleted (it must carry the marker file). The same results give the same bytes: pages carry
the build stamp of :mod:`leaderboard.runs.stamp`, never the clock.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from PIL import Image

from leaderboard.outputs.downloads import write_downloads
from leaderboard.outputs.paper_figures import FigureSet
from leaderboard.runs.aggregate import Group, Leaderboard, safe_name
from leaderboard.runs.sources import Sources
from leaderboard.track import track_source
from leaderboard.track import write_page as write_track_page
from leaderboard.web.leftovers import building_in
from leaderboard.web.page_cache import PageCache, link_or_copy
from leaderboard.web.pages import index_context, run_context, runs_context, scenario_context
from leaderboard.web.ranking_page import ranking_context
from leaderboard.web.render import STATIC, STATIC_FILES, render
from leaderboard.web.site_state import SiteBuild
from leaderboard.web.site_target import SITE_MARKER, check_target
from morality_gym.clitools import public_mode, writing
from morality_gym.envs.registry import scenario_named
from morality_gym.envs.trolley import TrolleyEnv
from morality_gym.render.rgb import render_rgb

Progress = Callable[[Iterable[Any], str, int], Iterable[Any]]


def _copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src, dst)



def copy_figures(sb: SiteBuild) -> None:
    """Copy the figures the pages show into ``figures/`` and the learn curves into ``runs/img``."""
    for (group, chain), path in sb.figures.bars.items():
        _copy(path, sb.out / "figures" / group.slug / path.name)
    for (group, chain, scenario), path in sb.figures.radars.items():
        _copy(path, sb.out / "figures" / group.slug / path.name)
    for run_id, path in sb.figures.learn.items():  # charts are written atomically: a link is safe
        if path.is_file():
            target = f"runs/img/{path.name}"
            link_or_copy(path, sb.out / target)
            sb.learn[run_id] = target
    for run_id, path in sb.figures.updates.items():
        if path.is_file():
            target = f"runs/img/{path.name}"
            link_or_copy(path, sb.out / target)
            sb.updates[run_id] = target


def copy_stat_figures(sb: SiteBuild, stat_figures: Any) -> None:
    """Copy the statistics figures (ranking per sweep, curves and return-cost per row) into ``figures/``."""
    if stat_figures is None:
        return

    def place(group: Group, path: Path) -> str:
        target = f"figures/{group.slug}/stats/{path.name}"
        _copy(path, sb.out / target)
        return target

    for group, items in stat_figures.ranking.items():
        sb.ranking_figures[group] = [(kind, place(group, path)) for kind, path in items]
    for key, path in stat_figures.curves.items():
        sb.row_figures.setdefault(key, {})["curves"] = place(key[0], path)
        if key in stat_figures.curves_notes:
            sb.row_figures[key]["curves_note"] = stat_figures.curves_notes[key]
    for key, path in stat_figures.tradeoffs.items():
        sb.row_figures.setdefault(key, {})["tradeoff"] = place(key[0], path)


def gif_choices(lb: Leaderboard, sources: Sources) -> dict[tuple[Group, str, str, str], dict[str, Any]]:
    """One evaluation-episode GIF per (group, chain, scenario, learner): first variant, lowest seed.

    Only runs whose GIF exists inside their results directory or release qualify (a path pointing
    elsewhere is ignored rather than copied: the site must not pick up arbitrary files).
    """
    chosen: dict[tuple[Group, str, str, str], dict[str, Any]] = {}
    runs = lb.runs.loc[lb.runs["ok"] & lb.runs["gif_path"].notna()]
    variant_rank: dict[str, dict[str, int]] = {}
    for record in runs.to_dict("records"):
        scenario = str(record["scenario"])
        if scenario not in variant_rank:
            try:
                variant_rank[scenario] = {v: i for i, v in enumerate(scenario_named(scenario).variants)}
            except KeyError:
                variant_rank[scenario] = {}
        path = sources.gif_of(str(record["run_id"]), record["gif_path"])
        if path is None:
            continue
        key = (Group(record["protocol"], record["preset"]), str(record["chain"]), scenario, str(record["learner"]))
        rank = (variant_rank[scenario].get(record["variant"], 999), str(record["variant"]), int(record["seed"]))
        if key not in chosen or rank < chosen[key]["_rank"]:
            chosen[key] = record | {"_rank": rank, "_path": path}
    return chosen


def copy_gifs(sb: SiteBuild, choices: dict[tuple[Group, str, str, str], dict[str, Any]]) -> None:
    """Every run's evaluation-episode GIF into ``gifs/`` (its run page shows it), hard-linked where
    the file system allows (a GIF is written once and never changed, so a link is safe and costs
    no bytes); ``choices`` are the ones the scenario pages show (:func:`gif_choices`)."""
    sb.gif_choices = choices
    for record in choices.values():
        _place_gif(sb, str(record["run_id"]), record["_path"])
    runs = sb.lb.runs.loc[sb.lb.runs["ok"] & sb.lb.runs["gif_path"].notna(), ["run_id", "gif_path"]]
    for run_id, gif_path in zip(runs["run_id"].astype(str), runs["gif_path"]):
        if run_id not in sb.gifs and (path := sb.sources.gif_of(run_id, gif_path)) is not None:
            _place_gif(sb, run_id, path)


def _place_gif(sb: SiteBuild, run_id: str, path: Path) -> None:
    target = f"gifs/{safe_name(run_id)}.gif"
    link_or_copy(path, sb.out / target)
    sb.gifs[run_id] = target


def render_layouts(sb: SiteBuild, scenarios: list[str]) -> None:
    """A PNG of each scenario's initial state (first variant); the reason when it cannot be drawn."""
    for scenario in scenarios:
        try:
            env_id = scenario_named(scenario).env_ids[0]
            env = TrolleyEnv(env_id)
            env.reset(seed=0)
            frame = render_rgb(env.world, env.state, 40, caption=f"{env_id}, initial state")
            target = f"scenarios/img/{safe_name(scenario)}.png"
            (sb.out / target).parent.mkdir(parents=True, exist_ok=True)
            Image.fromarray(frame).save(sb.out / target)
            sb.layouts[scenario] = target
            env.close()
        except Exception as exc:  # noqa: BLE001 - reported on the page, the build goes on
            sb.layout_notes[scenario] = f"rendering failed ({type(exc).__name__}: {exc}); ASCII picture only"


# ---------------------------------------------------------------------------------------- build
def _prepare_target(site_dir: Path) -> Path:
    """A fresh temporary directory next to ``site_dir``, where the new site is assembled."""
    check_target(site_dir)
    site_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{site_dir.name}.build-", dir=site_dir.parent))
    tmp.chmod(public_mode(directory=True))  # it becomes the site: not mkdtemp's 0700, or no web server can read it
    return tmp


def _swap_in(tmp: Path, site_dir: Path) -> None:
    if site_dir.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{site_dir.name}.old-", dir=site_dir.parent))
        old.rmdir()
        os.replace(site_dir, old)
        os.replace(tmp, site_dir)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, site_dir)


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")


def build_site(lb: Leaderboard, sources: Sources, site_dir: Path, figures: FigureSet, results_name: str | None = None,
               progress: Progress | None = None, *, stats: Any = None, stat_figures: Any = None, stamp: str = "",
               cache_dir: Path | None = None) -> SiteBuild:
    """Write the whole site into ``site_dir`` (replacing a previous build); returns what was written.

    ``stats``: :class:`leaderboard.stats.LeaderboardStats` (ranking page, matrix colours, curves,
    violations; without it those parts say there is nothing to show); ``stat_figures``:
    :class:`leaderboard.outputs.stats_figures.StatFigures`; ``stamp``: the build date shown in the footer;
    ``cache_dir``: where run pages are kept between builds (:mod:`leaderboard.web.page_cache`; None: render all).
    """
    check_target(site_dir)
    leftover = (f".{site_dir.name}.build-", f".{site_dir.name}.old-")
    with building_in(site_dir.parent, lambda name: name.startswith(leftover)), writing(site_dir):
        return _build_site(lb, sources, site_dir, figures, results_name, progress, stats=stats, stat_figures=stat_figures,
                           stamp=stamp, cache_dir=cache_dir)


def _build_site(lb: Leaderboard, sources: Sources, site_dir: Path, figures: FigureSet, results_name: str | None,
                progress: Progress | None, *, stats: Any, stat_figures: Any, stamp: str,
                cache_dir: Path | None) -> SiteBuild:
    """:func:`build_site` while this build holds the site's parent (:mod:`leaderboard.web.leftovers`)."""
    tmp = _prepare_target(site_dir)
    try:
        sb = SiteBuild(lb=lb, sources=sources, results_name=results_name or sources.name,
                       figures=figures, out=tmp, stamp=stamp, stats=stats)
        (tmp / SITE_MARKER).write_text("built by leaderboard.web.site; this whole directory is replaced on every build\n")
        for name in STATIC_FILES:
            _copy(STATIC / name, tmp / "assets" / name)
        copy_figures(sb)
        copy_stat_figures(sb, stat_figures)
        copy_gifs(sb, gif_choices(lb, sources))
        sb.downloads = write_downloads(lb, stats, tmp)
        scenarios = sorted({s for _, s in lb.pairs()})
        render_layouts(sb, scenarios)
        _write(tmp / "index.html", render("index.html", **index_context(sb)))
        _write(tmp / "ranking.html", render("ranking.html", **ranking_context(sb)))
        track_dir, track_release = track_source(sources.results)
        write_track_page(tmp, track_dir, sb.common("Generalisation track", "", "track.html"), release=track_release)
        _write(tmp / "runs" / "index.html", render("runs.html", **runs_context(sb)))
        for scenario in scenarios:
            _write(tmp / "scenarios" / f"{safe_name(scenario)}.html", render("scenario.html", **scenario_context(sb, scenario)))
        records = lb.runs.to_dict("records")
        iterator: Iterable[Any] = progress(records, "run pages", len(records)) if progress and records else records
        pages = PageCache(cache_dir)
        for record in iterator:
            context = run_context(sb, record)
            pages.place(tmp / "runs" / f"{safe_name(str(record['run_id']))}.html", "run.html", context,
                        lambda context=context: render("run.html", **context))
        pages.prune()
        sb.pages = 4 + len(scenarios) + len(records)
        sb.pages_reused = pages.reused
        _swap_in(tmp, site_dir)
        sb.out = site_dir
        return sb
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
