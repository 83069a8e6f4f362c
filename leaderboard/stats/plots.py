"""Figures of the statistics: performance profiles, aggregate intervals, probability of improvement,
pooled learning curves, return versus cost.

Each function draws one figure from the tidy frames of :mod:`leaderboard.stats`, filtered by the
caller to one protocol and preset (and one measure; data spanning several raises
:class:`~leaderboard.stats.core.StatsInputError` rather than pooling them), writes it to ``path``
and returns the path, or returns ``None`` and writes nothing when the frame has nothing to draw
(the page then says so).

As in :mod:`leaderboard.outputs.paper_figures`: matplotlib ``Figure`` objects on the Agg canvas, never
``pyplot`` (no global state, no GUI backend); one colour per learner everywhere (pass
``FigureSet.colours`` so that learners outside the paper's five keep their colour across a build).

Reproducible bytes: fixed sizes and DPI, and no time stamp or version in the file (PNG
``Software``, PDF ``CreationDate``/``Producer``, SVG ``Date``/``Creator`` and a fixed hash salt for
SVG ids), so the same numbers give the same file on every build.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter

from leaderboard.runs.aggregate import learner_order, row_order
from leaderboard.runs.display_order import DPI, learner_palette
from leaderboard.stats.core import StatsInputError
from morality_gym.norms.chain import ChainError, get_chain

#: What each saved format would otherwise stamp into the file (dates, versions).
_METADATA = {
    ".png": {"Software": None},
    ".pdf": {"Creator": None, "Producer": None, "CreationDate": None},
    ".svg": {"Creator": None, "Date": None},
}
STAT_LABELS = {"mean": "Mean", "iqm": "IQM", "optimality_gap": "Optimality gap (lower is better)"}
MEASURE_LABELS = {"score": "normalised score (0 = Random exact, 1 = Oracle best)", "metric": "morality metric"}


# ---------------------------------------------------------------------------------------- plumbing
def new_figure(width: float, height: float, constrained: bool = True) -> Figure:
    """A figure on the Agg canvas; constrained layout unless the caller places the axes itself.

    Constrained layout (and a tight bounding box when saving) measures every tick label of
    every axis; on a 14-panel grid that is most of the drawing time, so the grids place their
    panels with fixed margins instead (see :func:`_panel_figure`).
    """
    fig = Figure(figsize=(width, height), dpi=DPI, layout="constrained" if constrained else None)
    FigureCanvasAgg(fig)
    return fig


def label_inches(labels: Sequence[str], fontsize: float) -> float:
    """About how wide the longest of ``labels`` is, in inches, at ``fontsize`` points.

    Why: a figure of fixed width leaves its axes no room when the tick labels are long (a
    submitted policy's name may have 80 characters); constrained layout then gives up with
    "constrained_layout not applied because axes sizes collapsed to zero", a warning every
    build printed, and a figure whose panels overlap. The figure grows with its labels instead
    (DejaVu Sans averages about 0.55 em per character)."""
    longest = max((len(str(label)) for label in labels), default=0)
    return 0.8 + longest * fontsize * 0.55 / 72


def save_figure(fig: Figure, path: Path, tight: bool = True) -> Path:
    """Save with no time stamp or version in the file; PNG, PDF or SVG by the suffix."""
    suffix = path.suffix.lower()
    if suffix not in _METADATA:
        raise ValueError(f"cannot save a figure as {path.name}: use .png, .pdf or .svg")
    path.parent.mkdir(parents=True, exist_ok=True)
    box = {"bbox_inches": "tight", "pad_inches": 0.12} if tight else {}
    with matplotlib.rc_context({"svg.hashsalt": "morality-gym", "svg.fonttype": "path"}):
        fig.savefig(path, dpi=DPI, facecolor="white", metadata=_METADATA[suffix], **box)
    return path


def _single(frame: pd.DataFrame, what: str, columns: Sequence[str]) -> None:
    """Refuse data that mixes sweeps (or measures): one figure would silently pool them."""
    present = [c for c in columns if c in frame.columns]
    if present and len(frame[present].drop_duplicates()) > 1:
        found = ", ".join("/".join(map(str, k)) for k in frame[present].drop_duplicates().itertuples(index=False))
        raise StatsInputError(f"{what} data spans several {', '.join(present)} ({found}); filter it to one first")


def _colours(learners: Sequence[str], colours: Mapping[str, str] | None) -> dict[str, str]:
    palette = learner_palette(learners)
    return palette | dict(colours or {})


def _learners(frame: pd.DataFrame, column: str = "learner") -> list[str]:
    return learner_order(frame[column].astype(str))


def _style(ax: object) -> None:
    ax.grid(alpha=0.3)
    ax.set_axisbelow(True)
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)
    ax.tick_params(labelsize=7.5)


#: Fixed geometry of the per-row panel figures, in inches.
_PANEL_W, _PANEL_H, _TOP, _BOTTOM, _LEFT, _RIGHT = 3.3, 2.45, 0.5, 0.9, 0.6, 0.15


def _panel_figure(n_panels: int, ncols: int) -> tuple[Figure, np.ndarray]:
    """A grid of ``n_panels`` axes (``ncols`` wide at most) with fixed margins; unused axes hidden."""
    cols = max(1, min(ncols, n_panels))
    rows = math.ceil(n_panels / cols)
    width = max(5.6, _PANEL_W * cols)
    height = _PANEL_H * rows + _TOP + _BOTTOM
    fig = new_figure(width, height, constrained=False)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    fig.subplots_adjust(left=_LEFT / width, right=1 - _RIGHT / width, top=1 - _TOP / height, bottom=_BOTTOM / height,
                        wspace=0.32, hspace=0.62)
    for ax in axes[n_panels:]:
        ax.set_visible(False)
    return fig, axes


def _row_title(chain: str, scenario: str) -> str:
    """``DPAH · PushOrSwitchSelfSacrifice``: the chain's abbreviation keeps panel titles inside their panel."""
    try:
        short = get_chain(chain).abbreviation or chain
    except ChainError:
        short = chain
    return f"{short} · {scenario}"


def _steps(value: float, _position: object = None) -> str:
    """Tick labels for environment steps: 0, 250k, 1M, 1.5M."""
    if abs(value) >= 1e6:
        return f"{value / 1e6:g}M"
    if abs(value) >= 1e3:
        return f"{value / 1e3:g}k"
    return f"{value:g}"


def _legend(fig: Figure, palette: Mapping[str, str], learners: Sequence[str], marker: str | None = None) -> None:
    if marker:
        handles = [Line2D([], [], color=palette[n], marker=marker, linestyle="", markersize=5) for n in learners]
    else:
        handles = [Line2D([], [], color=palette[n], linewidth=2) for n in learners]
    fig.legend(handles, learners, loc="lower center", bbox_to_anchor=(0.5, 0.0), ncol=min(len(learners), 5),
               frameon=False, fontsize=8)


# ---------------------------------------------------------------------------------------- ranking
def performance_profile_figure(profiles: pd.DataFrame, path: Path, title: str = "",
                               colours: Mapping[str, str] | None = None) -> Path | None:
    """Share of runs above each threshold per learner, with the 95 % pointwise band (one measure)."""
    if profiles.empty:
        return None
    _single(profiles, "performance profile", ["protocol", "preset", "measure"])
    learners = _learners(profiles)
    palette = _colours(learners, colours)
    measure = str(profiles["measure"].iloc[0])
    fig = new_figure(6.4, 3.8)
    ax = fig.add_subplot()
    for learner in learners:
        part = profiles.loc[profiles["learner"] == learner].sort_values("tau")
        ax.plot(part["tau"], part["share"], color=palette[learner], linewidth=1.6, label=learner, drawstyle="steps-post")
        ax.fill_between(part["tau"], part["ci_low"], part["ci_high"], color=palette[learner], alpha=0.15, linewidth=0,
                        step="post")
    if measure == "score":
        for x in (0.0, 1.0):
            ax.axvline(x, color="#555555", linewidth=0.8, linestyle=":")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel(f"threshold τ on the {MEASURE_LABELS.get(measure, measure)}", fontsize=8)
    ax.set_ylabel("share of runs above τ", fontsize=8)
    ax.set_title(title or "Performance profiles", fontsize=10, loc="left")
    _style(ax)
    ax.legend(fontsize=7.5, frameon=False, loc="lower left")
    return save_figure(fig, path)


def aggregate_figure(aggregates: pd.DataFrame, path: Path, title: str = "",
                     colours: Mapping[str, str] | None = None) -> Path | None:
    """One panel per statistic (mean, IQM, optimality gap), one line per learner: point and 95 % interval."""
    if aggregates.empty:
        return None
    _single(aggregates, "aggregate", ["protocol", "preset", "measure"])
    learners = _learners(aggregates)
    palette = _colours(learners, colours)
    measure = str(aggregates["measure"].iloc[0])
    statistics = [s for s in STAT_LABELS if s in set(aggregates["statistic"])]
    fig = new_figure(2.6 * len(statistics) + 0.4 + label_inches(learners, 8), 0.42 * len(learners) + 1.3)
    axes = fig.subplots(1, len(statistics), sharey=True, squeeze=False)[0]
    y = np.arange(len(learners))[::-1]
    for ax, statistic in zip(axes, statistics):
        part = aggregates.loc[aggregates["statistic"] == statistic].set_index("learner")
        for yi, learner in zip(y, learners):
            if learner not in part.index:
                continue
            row = part.loc[learner]
            ax.plot([row["ci_low"], row["ci_high"]], [yi, yi], color=palette[learner], linewidth=5, alpha=0.45,
                    solid_capstyle="butt")
            ax.plot([row["value"]], [yi], marker="|", markersize=12, color=palette[learner], markeredgewidth=2)
        ax.set_title(STAT_LABELS[statistic], fontsize=9)
        _style(ax)
        ax.grid(axis="y", alpha=0)
    axes[0].set_yticks(y, learners, fontsize=8)
    axes[0].set_ylim(-0.7, len(learners) - 0.3)
    fig.supxlabel(MEASURE_LABELS.get(measure, measure) + " (95 % stratified bootstrap interval)", fontsize=8)
    fig.suptitle(title or "Aggregate scores", fontsize=10, x=0.02, ha="left")
    return save_figure(fig, path)


def improvement_figure(improvement: pd.DataFrame, path: Path, title: str = "",
                       colours: Mapping[str, str] | None = None) -> Path | None:
    """``P(X > Y)`` with its interval for each pair of learners (each pair once, X before Y in learner order)."""
    if improvement.empty:
        return None
    _single(improvement, "probability-of-improvement", ["protocol", "preset"])
    learners = _learners(improvement, "learner_x")
    palette = _colours(learners, colours)
    rank = {name: i for i, name in enumerate(learners)}
    pairs = improvement.loc[[rank[x] < rank[y] for x, y in zip(improvement["learner_x"], improvement["learner_y"])]]
    pairs = pairs.assign(_x=pairs["learner_x"].map(rank), _y=pairs["learner_y"].map(rank)).sort_values(["_x", "_y"])
    labels = [f"P({x} > {yy})" for x, yy in zip(pairs["learner_x"], pairs["learner_y"])]
    fig = new_figure(4.4 + label_inches(labels, 7.5), 0.36 * len(pairs) + 1.2)
    ax = fig.add_subplot()
    y = np.arange(len(pairs))[::-1]
    for yi, row in zip(y, pairs.itertuples()):
        colour = palette[row.learner_x]
        ax.plot([row.ci_low, row.ci_high], [yi, yi], color=colour, linewidth=5, alpha=0.45, solid_capstyle="butt")
        ax.plot([row.probability], [yi], marker="|", markersize=11, color=colour, markeredgewidth=2)
    ax.axvline(0.5, color="#555555", linewidth=0.8, linestyle=":")
    ax.set_yticks(y, labels, fontsize=7.5)
    ax.set_xlim(0, 1)
    ax.set_ylim(-0.7, len(pairs) - 0.3)
    ax.set_xlabel("probability of improvement (95 % stratified bootstrap interval)", fontsize=8)
    ax.set_title(title or "Probability of improvement", fontsize=10, loc="left")
    _style(ax)
    ax.grid(axis="y", alpha=0)
    return save_figure(fig, path)


# ---------------------------------------------------------------------------------------- per row
def learning_curves_figure(curves: pd.DataFrame, path: Path, rows: Sequence[tuple[str, str]] | None = None,
                           title: str = "", colours: Mapping[str, str] | None = None, ncols: int = 4) -> Path | None:
    """One panel per (chain, scenario) row: per learner the pooled mean curve and its 95 % band.

    ``rows`` gives the panels and their order (default: every row of ``curves`` in Table 1 order);
    one row gives a single panel, for a scenario page.
    """
    if curves.empty:
        return None
    _single(curves, "learning-curve", ["protocol", "preset", "measure"])
    rows = list(rows) if rows is not None else row_order(zip(curves["chain"], curves["scenario"]))
    learners = _learners(curves)
    palette = _colours(learners, colours)
    measure = str(curves["measure"].iloc[0])
    label = {"exact_metric": "exact metric", "metric": "metric (Monte Carlo)"}.get(measure, measure.replace("_", " "))
    fig, axes = _panel_figure(len(rows), ncols)
    for ax, (chain, scenario) in zip(axes, rows):
        part = curves.loc[(curves["chain"] == chain) & (curves["scenario"] == scenario)]
        for learner in learners:
            line = part.loc[part["learner"] == learner].sort_values("step")
            if line.empty:
                continue
            ax.plot(line["step"], line["mean"], color=palette[learner], linewidth=1.4, label=learner)
            ax.fill_between(line["step"], line["ci_low"], line["ci_high"], color=palette[learner], alpha=0.15,
                            linewidth=0)
        if measure in ("metric", "exact_metric"):
            ax.set_ylim(-0.02, 1.02)
        ax.set_title(_row_title(chain, scenario), fontsize=8, loc="left")
        ax.xaxis.set_major_formatter(FuncFormatter(_steps))
        ax.set_xlabel("environment steps", fontsize=7.5)
        ax.set_ylabel(label, fontsize=7.5)
        _style(ax)
    _legend(fig, palette, learners)
    fig.suptitle(title or f"Learning curves ({label}): mean and 95 % interval over variants and seeds", fontsize=9.5,
                 x=0.01, ha="left", y=1 - 0.12 / fig.get_figheight(), va="top")
    return save_figure(fig, path, tight=False)


def return_cost_figure(points: pd.DataFrame, path: Path, rows: Sequence[tuple[str, str]] | None = None,
                       title: str = "", colours: Mapping[str, str] | None = None, ncols: int = 4) -> Path | None:
    """One panel per row: a point per run (mean cost on x, mean return on y), learners as colours.

    Each learner's mean over its runs is drawn as a larger outlined marker, so a cloud's centre
    reads at a glance.
    """
    if points.empty:
        return None
    _single(points, "return-cost", ["protocol", "preset"])
    rows = list(rows) if rows is not None else row_order(zip(points["chain"], points["scenario"]))
    learners = _learners(points)
    palette = _colours(learners, colours)
    fig, axes = _panel_figure(len(rows), ncols)
    for ax, (chain, scenario) in zip(axes, rows):
        part = points.loc[(points["chain"] == chain) & (points["scenario"] == scenario)]
        for learner in learners:
            runs = part.loc[part["learner"] == learner]
            if runs.empty:
                continue
            ax.scatter(runs["mean_cost"], runs["mean_return"], s=9, color=palette[learner], alpha=0.55, linewidths=0)
            ax.scatter([runs["mean_cost"].mean()], [runs["mean_return"].mean()], s=46, color=palette[learner],
                       edgecolors="black", linewidths=0.8, zorder=3)
        ax.set_title(_row_title(chain, scenario), fontsize=8, loc="left")
        ax.set_xlabel("mean cost per episode", fontsize=7.5)
        ax.set_ylabel("mean return per episode", fontsize=7.5)
        _style(ax)
    _legend(fig, palette, learners, marker="o")
    fig.suptitle(title or "Return versus cost (final evaluation): a point per run, outlined = learner mean",
                 fontsize=9.5, x=0.01, ha="left", y=1 - 0.12 / fig.get_figheight(), va="top")
    return save_figure(fig, path, tight=False)
