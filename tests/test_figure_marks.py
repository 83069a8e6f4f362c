"""Figure 2 bars and radars mark a learner whose cells behind them are incomplete, as the tables do."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from matplotlib.figure import Figure

import leaderboard.outputs.paper_figures as figures
from leaderboard.runs.display_order import Group

PAPER = Group("paper", "paper")


def _table() -> pd.DataFrame:
    rows = [
        ("learner", "paper", "paper", "Utility", "Switch", "PPO", True),
        ("learner", "paper", "paper", "Utility", "Push", "PPO", True),
        ("learner", "paper", "paper", "Utility", "Switch", "SmolLM2", True),
        ("learner", "paper", "paper", "Utility", "Push", "SmolLM2", False),  # 5 of 11 variants played
        ("learner", "corrected", "paper", "Utility", "Switch", "CPO", False),  # another group
        ("reference", "paper", "paper", "Utility", "Switch", "Random", False),
    ]
    return pd.DataFrame(rows, columns=["kind", "protocol", "preset", "chain", "scenario", "learner", "complete"])


def test_a_learner_with_one_incomplete_cell_under_a_chain_is_marked_in_its_bars() -> None:
    assert figures.incomplete_learners(_table(), PAPER, "Utility") == {"SmolLM2"}


def test_a_radar_marks_only_the_scenarios_cells() -> None:
    assert figures.incomplete_learners(_table(), PAPER, "Utility", "Switch") == set()
    assert figures.incomplete_learners(_table(), PAPER, "Utility", "Push") == {"SmolLM2"}
    assert figures.incomplete_learners(_table(), Group("corrected", "paper"), "Utility") == {"CPO"}


@pytest.mark.parametrize("chart", ["bar_chart", "radar_chart"])
def test_the_legend_says_incomplete(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, chart: str) -> None:
    summary = pd.DataFrame(
        [(name, norm, rank, 0.5, 0.1) for name in ("PPO", "SmolLM2") for rank, norm in enumerate("ABC")],
        columns=["learner", "norm", "rank", "mean", "std"],
    )
    labels: list[str] = []
    real_save = figures._save

    def save(fig: Figure, path: Path) -> Path:
        labels.extend(text.get_text() for ax in fig.axes if ax.get_legend() for text in ax.get_legend().get_texts())
        return real_save(fig, path)

    monkeypatch.setattr(figures, "_save", save)
    getattr(figures, chart)(summary, ["PPO", "SmolLM2"], {"PPO": "#111111", "SmolLM2": "#222222"}, "t", "s",
                            tmp_path / "f.png", {"SmolLM2"})
    assert labels == ["PPO", "SmolLM2 (incomplete)"]

