"""The paper's figures from the aggregated numbers: Figure 2 bars and radar plots (per-run charts: :mod:`leaderboard.web.run_charts`).

Figures are drawn on :class:`matplotlib.figure.Figure` objects with the Agg canvas directly, never
through ``pyplot``: no global figure state, no GUI backend picked up from the environment, and
nothing left open when a build draws hundreds of small plots.

Each learner keeps one colour in every figure (and on the site, which shows the same colours
next to learner names), so a reader can follow a learner from the bar charts to the radars.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from leaderboard.runs.aggregate import Group, Leaderboard, safe_name
from leaderboard.runs.display_order import DPI, EXTRA_COLOURS, LEARNER_COLOURS, learner_palette  # noqa: F401 - re-exported
from morality_gym.norms.catalogue import CATALOGUE
from morality_gym.norms.chain import ChainError, get_chain

Progress = Callable[[Iterable[Any], str, int], Iterable[Any]]


def norm_abbreviation(norm: str) -> str:
    """The paper's short label of a norm (MHH, APHH, AAgH, ...), or the name itself."""
    info = CATALOGUE.get(norm)
    return info.abbreviation if info else norm


def norm_label(norm: str) -> str:
    info = CATALOGUE.get(norm)
    return info.label if info else norm


def chain_title(chain: str) -> str:
    """``Utility (U)``: the chain's name and the abbreviation the paper uses."""
    try:
        abbreviation = get_chain(chain).abbreviation
    except ChainError:
        return chain
    return f"{chain} ({abbreviation})" if abbreviation else chain


def _new_figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    # no "Software: Matplotlib version ..." chunk: the same data gives the same bytes after an upgrade too
    fig.savefig(path, dpi=DPI, facecolor="white", bbox_inches="tight", pad_inches=0.12, metadata={"Software": None})
    return path


def _norm_matrix(summary: pd.DataFrame, learners: list[str]) -> tuple[list[str], dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Norms in chain order, and per learner the means and spreads aligned with them (NaN = no data)."""
    norms = list(dict.fromkeys(summary.sort_values(["rank", "norm"])["norm"]))
    means: dict[str, np.ndarray] = {}
    stds: dict[str, np.ndarray] = {}
    for learner in learners:
        part = summary.loc[summary["learner"] == learner].set_index("norm")
        means[learner] = np.array([part["mean"].get(n, np.nan) for n in norms], dtype=float)
        stds[learner] = np.array([part["std"].get(n, np.nan) for n in norms], dtype=float)
    return norms, means, stds


def legend_label(learner: str, incomplete: Collection[str]) -> str:
    """The learner's name, marked when its cells behind the figure are incomplete: a bar or polygon
    drawn from part of a column is never shown as if it were the whole."""
    return f"{learner} (incomplete)" if learner in incomplete else learner


def bar_chart(summary: pd.DataFrame, learners: list[str], colours: dict[str, str], title: str, subtitle: str,
              path: Path, incomplete: Collection[str] = ()) -> Path:
    """Grouped bars: norms on x in chain order, one bar per learner, error bars = seed spread."""
    present = [name for name in learners if name in set(summary["learner"])]
    norms, means, stds = _norm_matrix(summary, present)
    x = np.arange(len(norms))
    width = 0.82 / max(1, len(present))
    fig = _new_figure(7.2, 3.7)  # one size for every chain, so the charts line up on a page
    ax = fig.add_subplot()
    for i, learner in enumerate(present):
        offset = (i - (len(present) - 1) / 2) * width
        err = np.where(np.isnan(stds[learner]), 0.0, stds[learner])
        ax.bar(x + offset, np.nan_to_num(means[learner]), width, yerr=err, color=colours[learner],
               label=legend_label(learner, incomplete), edgecolor="white", linewidth=0.4, capsize=2, error_kw={"elinewidth": 0.9, "ecolor": "#333333"})
    ax.set_xticks(x, [norm_abbreviation(n) for n in norms])
    ax.set_ylim(0, 1.08)
    ax.set_ylabel("Morality function")
    ax.set_title(title, fontsize=11, loc="left")
    ax.text(1.0, 1.02, subtitle, transform=ax.transAxes, ha="right", va="bottom", fontsize=7.5, color="#666666")
    ax.grid(axis="y", alpha=0.3)
    ax.set_axisbelow(True)
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=min(len(present), 5), frameon=False, fontsize=8.5)
    fig.tight_layout()
    return _save(fig, path)


def radar_chart(summary: pd.DataFrame, learners: list[str], colours: dict[str, str], title: str, subtitle: str,
                path: Path, incomplete: Collection[str] = ()) -> Path:
    """One polygon per learner over the relevant norms; bars when there are fewer than 3 norms.

    A radar with one or two axes is a point or a line and reads worse than two bars, hence the
    fallback (the paper's radars all have at least three norms).
    """
    present = [name for name in learners if name in set(summary["learner"])]
    norms, means, _ = _norm_matrix(summary, present)
    if len(norms) < 3:
        return bar_chart(summary, learners, colours, title, subtitle, path, incomplete)
    angles = np.linspace(0, 2 * np.pi, len(norms), endpoint=False)
    closed = np.concatenate([angles, angles[:1]])
    fig = _new_figure(4.6, 4.9)
    ax = fig.add_subplot(projection="polar")
    ax.set_theta_offset(np.pi / 2)
    ax.set_theta_direction(-1)
    for learner in present:
        values = np.nan_to_num(means[learner])
        ring = np.concatenate([values, values[:1]])
        ax.plot(closed, ring, color=colours[learner], linewidth=1.6, label=legend_label(learner, incomplete))
        ax.fill(closed, ring, color=colours[learner], alpha=0.07)
    ax.set_xticks(angles, [norm_abbreviation(n) for n in norms], fontsize=9)
    ax.set_ylim(0, 1)
    ax.set_yticks([0.25, 0.5, 0.75, 1.0], ["0.25", "0.5", "0.75", "1"], fontsize=7, color="#777777")
    ax.set_rlabel_position(180 / len(norms))  # between the first two axes, off every polygon vertex
    fig.suptitle(title, fontsize=10.5, x=0.02, ha="left")
    fig.text(0.02, 0.915, subtitle, fontsize=7.5, color="#666666", ha="left")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.07), ncol=3, frameon=False, fontsize=8)
    fig.subplots_adjust(top=0.82, bottom=0.2)
    return _save(fig, path)


# ---------------------------------------------------------------------------------------- all figures
@dataclass
class FigureSet:
    """Where each figure was written (keys are what the site looks them up by)."""

    bars: dict[tuple[Group, str], Path] = field(default_factory=dict)
    radars: dict[tuple[Group, str, str], Path] = field(default_factory=dict)
    learn: dict[str, Path] = field(default_factory=dict)
    learn_errors: dict[str, str] = field(default_factory=dict)  # run id -> why its curve is missing
    updates: dict[str, Path] = field(default_factory=dict)  # run id -> per-update diagnostics
    updates_errors: dict[str, str] = field(default_factory=dict)
    colours: dict[str, str] = field(default_factory=dict)

    @property
    def count(self) -> int:
        return len(self.bars) + len(self.radars) + len(self.learn) + len(self.updates)


def figure_paths(out_dir: Path, group: Group) -> Path:
    return out_dir / group.slug


def incomplete_learners(table: pd.DataFrame, group: Group, chain: str, scenario: str | None = None) -> set[str]:
    """Learners with an incomplete Table 1 cell in ``group`` under ``chain`` (in ``scenario`` when
    given): their norm means average only the runs that exist."""
    if table.empty or "complete" not in table.columns:
        return set()
    rows = table.loc[(table["kind"] == "learner") & (table["protocol"] == group.protocol)
                     & (table["preset"] == group.preset) & (table["chain"] == chain)]
    if scenario is not None:
        rows = rows.loc[rows["scenario"] == scenario]
    return {str(name) for name in rows.loc[~rows["complete"].astype(bool), "learner"]}


def write_figures(lb: Leaderboard, out_dir: Path, progress: Progress | None = None) -> FigureSet:
    """Figure 2 per (group, chain) and a radar per (group, chain, scenario) under ``out_dir``."""
    figures = FigureSet(colours=learner_palette(lb.learners))
    out_dir.mkdir(parents=True, exist_ok=True)
    # the numbers behind the plots, for anyone who wants to re-plot them differently
    lb.norms_by_chain.drop(columns="rank").to_csv(out_dir / "figure2_data.csv", index=False, float_format="%.6f")
    lb.norms_by_scenario.drop(columns="rank").to_csv(out_dir / "radar_data.csv", index=False, float_format="%.6f")
    jobs: list[tuple[str, Group, str, str | None]] = []
    for group in lb.groups:
        part = lb.norms_by_chain
        part = part.loc[(part["protocol"] == group.protocol) & (part["preset"] == group.preset)]
        jobs += [("bar", group, chain, None) for chain in dict.fromkeys(part["chain"])]
        part = lb.norms_by_scenario
        part = part.loc[(part["protocol"] == group.protocol) & (part["preset"] == group.preset)]
        jobs += [("radar", group, c, s) for c, s in dict.fromkeys(zip(part["chain"], part["scenario"]))]
    iterator: Iterable[Any] = progress(jobs, "figures", len(jobs)) if progress and jobs else jobs
    for kind, group, chain, scenario in iterator:
        incomplete = incomplete_learners(lb.table, group, chain, scenario)
        if kind == "bar":
            t = lb.norms_by_chain
            data = t.loc[(t["protocol"] == group.protocol) & (t["preset"] == group.preset) & (t["chain"] == chain)]
            path = figure_paths(out_dir, group) / f"fig2_{safe_name(chain)}.png"
            figures.bars[(group, chain)] = bar_chart(
                data, lb.learners, figures.colours, chain_title(chain), group.label, path, incomplete)
        else:
            t = lb.norms_by_scenario
            data = t.loc[(t["protocol"] == group.protocol) & (t["preset"] == group.preset) & (t["chain"] == chain)
                         & (t["scenario"] == scenario)]
            path = figure_paths(out_dir, group) / f"radar_{safe_name(chain)}_{safe_name(str(scenario))}.png"
            figures.radars[(group, chain, str(scenario))] = radar_chart(
                data, lb.learners, figures.colours, f"{scenario} · {chain_title(chain)}", group.label, path, incomplete)
    return figures
