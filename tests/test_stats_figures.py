"""Figures of the statistics: every one draws from the realistic frame, the same numbers give the
same bytes, learners keep the leaderboard's colours, and an empty frame draws nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from leaderboard.outputs.paper_figures import LEARNER_COLOURS
from leaderboard.stats import LeaderboardStats, StatsInputError, compute_stats
from leaderboard.stats import plots as F
from tests.stats_data import reference_frame, synthetic_runs


@pytest.fixture(scope="module")
def stats() -> LeaderboardStats:
    runs, learn = synthetic_runs(seeds=(41, 42))
    return compute_stats(runs, reference_frame(), learn, rng=1, n_resamples=200)


def _drawers(s: LeaderboardStats) -> dict[str, Callable[[Path], Path | None]]:
    score = s.aggregates["measure"] == "score"
    return {
        "profiles": lambda p: F.performance_profile_figure(s.profiles.loc[s.profiles["measure"] == "score"], p),
        "aggregates": lambda p: F.aggregate_figure(s.aggregates.loc[score], p),
        "improvement": lambda p: F.improvement_figure(s.improvement, p),
        "curves": lambda p: F.learning_curves_figure(s.curves, p),
        "curves_one_row": lambda p: F.learning_curves_figure(s.curves, p, rows=[("Utility", "Switch5")]),
        "return_cost": lambda p: F.return_cost_figure(s.points, p),
        "return_cost_one_row": lambda p: F.return_cost_figure(s.points, p, rows=[("Utility", "Switch5")]),
    }


def _has_colour(path: Path, hex_colour: str) -> bool:
    rgb = tuple(int(hex_colour[i:i + 2], 16) for i in (1, 3, 5))
    pixels = np.asarray(Image.open(path).convert("RGB")).reshape(-1, 3)
    return bool((pixels == rgb).all(axis=1).any())


def test_every_figure_is_drawn_and_byte_reproducible(stats: LeaderboardStats, tmp_path: Path) -> None:
    for name, draw in _drawers(stats).items():
        first, second = tmp_path / f"{name}.png", tmp_path / "again" / f"{name}.png"
        assert draw(first) == first and draw(second) == second
        assert first.read_bytes() == second.read_bytes(), name
        with Image.open(first) as image:
            assert image.width > 300 and image.height > 200
            assert "Software" not in image.info  # no matplotlib version stamped into the file
        # the paper's learners keep the colours of the other figures
        assert _has_colour(first, LEARNER_COLOURS["CPO"]) and _has_colour(first, LEARNER_COLOURS["PPO Shaped"]), name


@pytest.mark.parametrize("suffix", [".pdf", ".svg"])
def test_vector_formats_carry_no_date(stats: LeaderboardStats, tmp_path: Path, suffix: str) -> None:
    draw = _drawers(stats)["aggregates"]
    first, second = draw(tmp_path / f"a{suffix}"), draw(tmp_path / f"b{suffix}")
    assert first is not None and second is not None
    assert first.read_bytes() == second.read_bytes()
    assert b"CreationDate" not in first.read_bytes() and b"<dc:date>" not in first.read_bytes()


def test_unknown_learners_take_the_builds_palette(stats: LeaderboardStats, tmp_path: Path) -> None:
    renamed = stats.aggregates.replace({"learner": {"Random": "My Agent"}})
    path = F.aggregate_figure(renamed.loc[renamed["measure"] == "metric"], tmp_path / "a.png",
                              colours={"My Agent": "#FF0000"})
    assert path is not None and _has_colour(path, "#FF0000")


def test_nothing_to_draw_writes_nothing(stats: LeaderboardStats, tmp_path: Path) -> None:
    for name, draw in _drawers(LeaderboardStats(*(frame.iloc[0:0] for frame in (
            stats.cells, stats.rows, stats.aggregates, stats.improvement, stats.profiles, stats.curves, stats.points,
            stats.violations)))).items():
        assert draw(tmp_path / f"{name}.png") is None
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="use .png, .pdf or .svg"):
        F.save_figure(F.new_figure(1, 1), tmp_path / "x.jpg")


def test_mixed_sweeps_or_measures_are_refused(stats: LeaderboardStats, tmp_path: Path) -> None:
    with pytest.raises(StatsInputError, match="spans several protocol, preset, measure"):
        F.aggregate_figure(stats.aggregates, tmp_path / "a.png")  # both measures
    two = pd.concat([stats.points, stats.points.assign(protocol="corrected")])
    with pytest.raises(StatsInputError, match="paper/paper, corrected/paper"):
        F.return_cost_figure(two, tmp_path / "b.png")
    assert not list(tmp_path.iterdir())


def test_frames_are_tidy(stats: LeaderboardStats) -> None:
    # one observation per line: no duplicated keys in any frame a page or a CSV download will use
    keys = {
        "cells": ["protocol", "preset", "chain", "scenario", "learner"],
        "rows": ["protocol", "preset", "chain", "scenario"],
        "aggregates": ["protocol", "preset", "measure", "learner", "statistic"],
        "improvement": ["protocol", "preset", "learner_x", "learner_y"],
        "profiles": ["protocol", "preset", "measure", "learner", "tau"],
        "curves": ["protocol", "preset", "chain", "scenario", "learner", "step"],
        "points": ["run_id"],
        "violations": ["protocol", "preset", "chain", "scenario", "learner", "norm"],
    }
    for name, columns in keys.items():
        frame: pd.DataFrame = getattr(stats, name)
        assert not frame.empty and not frame.duplicated(columns).any(), name
