"""Marks that mean something (issue 45): a cell trained for another budget than its preset's is "not
comparable", and "best" is drawn only where a best means something.

A torch-example entry trained 2,048 steps landed in the ``paper`` preset's grid beside 1M-step
baselines and the paper's values, unmarked (its runs recorded budget 0); smoke sections shaded a
"best" learner although 2,048 steps teach nothing; 0.807 against 0.807 was outlined on one side.
"""

from __future__ import annotations

import pandas as pd

from leaderboard.runs.cells import _best_flags, delta_note, off_budgets
from leaderboard.runs.selection import CELL_KEYS


def _runs(*rows: tuple[str, str, str, int, bool]) -> pd.DataFrame:
    return pd.DataFrame([{"protocol": "paper", "preset": preset, "chain": "Utility", "scenario": scenario,
                          "learner": learner, "budget": budget, "ok": ok} for preset, scenario, learner, budget, ok in rows])


def test_a_cell_trained_for_another_budget_than_its_presets_is_found() -> None:
    runs = _runs(("paper", "SwitchStandard", "PPO", 500_000, True),  # the paper's budget for this scenario
                 ("paper", "Switch5", "PPO", 1_000_000, True),
                 ("paper", "SwitchStandard", "Torch example", 2_048, True),
                 ("paper", "SwitchStandard", "A rule", 0, True),  # not trained (or not known): nothing to compare
                 ("smoke", "SwitchStandard", "PPO", 2_048, True),  # the smoke preset's own budget
                 ("paper", "Switch5", "Failed one", 4_096, False))  # no result: nothing shown
    off = off_budgets(runs)
    assert off == {("paper", "paper", "Utility", "SwitchStandard", "Torch example"): 2_048}
    assert next(iter(off)) == tuple(runs.loc[2, CELL_KEYS])


def test_delta_note_says_not_comparable_for_another_budget() -> None:
    cell = {"kind": "learner", "preset": "paper", "complete": True, "paper": 0.935, "off_budget": 2_048}
    assert delta_note(cell) == "not comparable: trained 2,048 steps"
    assert delta_note(cell | {"off_budget": 0}) == ""
    assert delta_note(cell | {"paper": float("nan")}) == "not comparable: trained 2,048 steps"  # a submission: no paper value
    assert delta_note(cell | {"preset": "smoke"}) == "not comparable: preset smoke"  # the preset's mark first


def _table(*rows: tuple[str, str, float, int]) -> pd.DataFrame:
    return pd.DataFrame([{"protocol": "paper", "preset": preset, "chain": "Utility", "scenario": "Switch5", "learner": learner,
                          "kind": "learner", "complete": True, "mean": mean, "off_budget": off}
                         for preset, learner, mean, off in rows])


def test_best_is_drawn_only_where_it_means_something() -> None:
    tie = _table(("paper", "PPO", 0.8071, 0), ("paper", "CPO", 0.8068, 0), ("paper", "Random", 0.3, 0))
    assert list(_best_flags(tie)) == [True, True, False]  # both read 0.807: both best, or it is noise
    apart = _table(("paper", "PPO", 0.8076, 0), ("paper", "CPO", 0.8068, 0))
    assert list(_best_flags(apart)) == [True, False]  # 0.808 against 0.807
    smoke = _table(("smoke", "PPO", 0.9, 0), ("smoke", "CPO", 0.5, 0))
    assert not _best_flags(smoke).any()  # 2,048 steps teach nothing: no best
    off = _table(("paper", "Torch example", 0.95, 2_048), ("paper", "PPO", 0.6, 0))
    assert list(_best_flags(off)) == [False, True]  # not compared with the 1M-step cells
