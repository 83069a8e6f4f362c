"""The Generalisation page's learning curves: env steps vs the seen set's exact mean range score.

Why: issue 44 chooses each learner's budget where its curve on seen dilemmas flattens; the page
shows the curves the budget was read from, so a reader can judge whether a learner had flattened.
One line per learner (the mean over its seeds at each recorded step count), a band from the lowest
to the highest seed (the seeds' spread), in Table 1's colours. A learner whose runs are incomplete
(:mod:`leaderboard.track_status`) is labelled so in the legend.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from leaderboard.track_status import CURVES_DIR, CurveError, read_curve


def read_curves(root: Path, track: str) -> tuple[pd.DataFrame, list[str]]:
    """Every curve of ``track`` under ``root/curves`` (``<track>-<learner>.csv``) as one frame, and
    one line per curve file that could not be read (shown on the page, not fatal: the scores stand)."""
    frames, problems = [], []
    folder = root / CURVES_DIR
    for path in sorted(folder.glob(f"{track}-*.csv")) if folder.is_dir() else []:
        try:
            rows = read_curve(path)
        except CurveError as exc:
            problems.append(str(exc))
            continue
        if rows:
            frames.append(pd.DataFrame(rows).assign(file=path.name))
    return (pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()), problems


def draw_curves(curves: pd.DataFrame, path: Path, labels: Mapping[str, str], colours: Mapping[str, str],
                marked: Callable[[str], str], title: str, random_seen: float | None = None) -> None:
    """One line per learner (mean over seeds) with the seeds' min-max band; ``marked(learner)``: the
    legend's suffix (``" ⚠ incomplete"``) or ``""``; ``random_seen``: Random's exact score on the
    seen set, drawn as the reference a curve must rise above."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 3.8), dpi=110)
    for learner, mine in curves.groupby("learner", sort=False):
        by_steps = mine.groupby("steps")["mean_range_score"]
        mean, low, high = by_steps.mean(), by_steps.min(), by_steps.max()
        colour = colours.get(str(learner), "#999999")
        seeds = mine["seed"].nunique()
        ax.plot(mean.index, mean.to_numpy(), color=colour, lw=1.6,
                label=f"{labels.get(str(learner), learner)} ({seeds} seed{'s' if seeds != 1 else ''}){marked(str(learner))}")
        if seeds > 1:
            ax.fill_between(mean.index, low.to_numpy(), high.to_numpy(), color=colour, alpha=0.18, lw=0)
    if random_seen is not None:
        ax.axhline(random_seen, color=colours.get("random", "#777777"), lw=1, ls="--",
                   label=f"{labels.get('random', 'Random')} (exact, untrained)")
    ax.set_xlabel("env steps per run")
    ax.set_ylabel("seen set: mean range score")
    ax.set_title(f"{title}\nlearning curves: line = mean over seeds, band = lowest to highest seed", fontsize=9)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def curve_summary(curves: pd.DataFrame) -> list[dict[str, Any]]:
    """Per learner: seeds and the last point's steps and mean score (the page's caption under the figure)."""
    out = []
    for learner, mine in curves.groupby("learner", sort=False):
        last = mine[mine["steps"] == mine["steps"].max()]
        out.append({"learner": str(learner), "seeds": int(mine["seed"].nunique()), "steps": int(last["steps"].iloc[0]),
                    "score": float(last["mean_range_score"].mean())})
    return out
