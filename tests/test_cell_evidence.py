"""``leaderboard.judging.cell_evidence``: what the update records of some runs say, and from how
many of their updates. A page reads every paired run's records once and cuts them per chain and per
cell; a cut must say "one update in N" only when its own runs were thinned, not because some other
run in the page came from a release."""

from __future__ import annotations

import pandas as pd

from leaderboard.judging.cell_evidence import (
    Updates,
    accepted_share,
    cpo_case_shares,
    final_multipliers,
    is_cpo,
    is_ppo_lag,
    mean_passes,
    one_pass_share,
    updates_summary,
)


def _lag() -> Updates:
    frame = pd.DataFrame({
        "run_id": ["released"] * 3 + ["local"] * 2,
        "update": [0, 8, 16, 0, 1],
        "passes": [1, 1, 40, 3, 1],
        "lagrange_multiplier": [0.5, 0.7, 0.9, 0.1, 0.2],
    })
    return Updates(frame, {"released": 8, "local": 1})


def test_a_cut_keeps_the_stride_of_its_own_runs() -> None:
    updates = _lag()
    assert updates.stride == 8 and "one update in 8" in updates.kept
    local = updates.of_runs(["local"])
    assert local is not None and local.stride == 1 and local.kept == ""
    assert list(local.frame["update"]) == [0, 1]
    assert updates.of_runs(["never-ran"]) is None


def test_ppo_lag_records_give_passes_and_final_multipliers() -> None:
    updates = _lag()
    assert is_ppo_lag(updates) and not is_cpo(updates)
    assert one_pass_share(updates) == 3 / 5
    assert mean_passes(updates) == 46 / 5
    assert sorted(final_multipliers(updates)) == [0.2, 0.9]  # each run's last update, not its largest
    line = updates_summary(updates)
    assert line.startswith("PPO-Lag updates (over one update in 8, as the release keeps them): 60% stopped after one pass")
    assert updates_summary(None) == ""


def test_cpo_records_give_dual_cases_and_accepted_steps() -> None:
    frame = pd.DataFrame({"run_id": ["r"] * 4, "update": [0, 1, 2, 3], "cpo_case": [0, 0, 1, 3],
                          "accept_step": [1, 0, 2, 1], "lagrange_multiplier": [None] * 4})
    updates = Updates(frame, {"r": 1})
    assert is_cpo(updates) and not is_ppo_lag(updates)
    assert cpo_case_shares(updates) == {0: 0.5, 1: 0.25, 3: 0.25}
    assert accepted_share(updates) == 0.75
    assert updates_summary(updates) == ("CPO updates: case 0 50%, case 1 25%, case 3 25%; "
                                        "a line-search step accepted in 75% of updates")
