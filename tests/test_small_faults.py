"""The small faults of issue 33, each with its fix: one rule for actions, no step before reset, one
warning line per bad user scenario file, and no constrained-layout warning from the build's figures."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from gymnasium.error import ResetNeeded

import morality_gym
from morality_gym import exact_evaluate
from morality_gym.envs.trolley import InvalidActionError, TrolleyEnv
from morality_gym.evaluation.montecarlo import evaluate

REPO = Path(__file__).resolve().parents[1]
ENV = "SwitchStandard-HumanA-v1"


@pytest.mark.parametrize("action", [2.0, np.float32(2.0), np.array([2.0]), True])
def test_the_evaluators_refuse_what_env_step_refuses(action: object) -> None:
    """Before: ``exact_evaluate(lambda obs: 2.0)`` scored the policy, ``env.step(2.0)`` refused it."""
    env = TrolleyEnv(ENV)
    env.reset()
    with pytest.raises(InvalidActionError, match="expected an integer in 0..5"):
        env.step(action)
    bound = morality_gym.bind_chain("Utility", ENV)
    with pytest.raises(InvalidActionError, match="valid actions are the integers 0-5"):
        exact_evaluate(lambda obs: action, ENV, bound)
    with pytest.raises(InvalidActionError, match="valid actions are the integers 0-5"):
        evaluate(lambda obs: action, ENV, bound, n_episodes=2, seed=0)


@pytest.mark.parametrize("action", [2, np.int64(2), np.array([2]), np.array(2, dtype=np.int8)])
def test_integer_actions_are_taken_by_both(action: object) -> None:
    env = TrolleyEnv(ENV)
    env.reset()
    env.step(action)
    bound = morality_gym.bind_chain("Utility", ENV)
    assert exact_evaluate(lambda obs: action, ENV, bound).metric == exact_evaluate(lambda obs: 2, ENV, bound).metric


def test_a_raw_env_refuses_to_step_before_reset() -> None:
    env = TrolleyEnv(ENV)
    with pytest.raises(ResetNeeded, match=f"{ENV}: call reset\\(\\) before step\\(\\)"):
        env.step(0)
    env.reset()
    obs, _reward, _terminated, truncated, _info = env.step(0)
    assert obs.shape == env.observation_space.shape and not truncated
    copy = TrolleyEnv(ENV)
    copy.__setstate__(env.__getstate__())  # a pickled env that was reset steps on
    copy.step(0)


def test_a_bad_user_scenario_file_is_one_warning_line(tmp_path: Path) -> None:
    """Before: PyYAML's 5-line message made the promised one-line warning 4 lines and more."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "not_yaml.yaml").write_text("name: [unclosed\n")
    out = subprocess.run([sys.executable, "-m", "morality_gym", "list"], cwd=REPO, check=False, capture_output=True,
                         text=True, timeout=300, env={**os.environ, "MORALITY_GYM_SCENARIOS": str(mine)})
    assert out.returncode == 0, out.stderr
    expected = (f"{mine / 'not_yaml.yaml'}: ScenarioFileWarning: skipped this scenario file: not valid YAML: while parsing "
                "a flow sequence: expected ',' or ']', but got '<stream end>' at line 2, column 1")
    assert out.stderr.splitlines() == [expected], out.stderr


@pytest.mark.parametrize("name", ["Random", "A submitted policy with a display name of eighty characters, the longest allowed"])
def test_aggregate_and_improvement_figures_leave_room_for_their_labels(tmp_path: Path, name: str) -> None:
    """Before: a narrow figure with a long learner name made constrained layout give up (a warning)."""
    from leaderboard.stats.plots import STAT_LABELS, aggregate_figure, improvement_figure

    for statistics in (["mean"], list(STAT_LABELS)):
        rows = [{"protocol": "paper", "preset": "smoke", "measure": "score", "learner": name, "statistic": s, "value": 0.5,
                 "ci_low": 0.4, "ci_high": 0.6} for s in statistics]
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert aggregate_figure(pd.DataFrame(rows), tmp_path / "aggregate.png") is not None
    pairs = pd.DataFrame([{"protocol": "paper", "preset": "smoke", "learner_x": x, "learner_y": y, "probability": 0.5,
                           "ci_low": 0.4, "ci_high": 0.6} for x, y in ((name, "PPO"), ("PPO", name))])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert improvement_figure(pairs, tmp_path / "improvement.png") is not None
