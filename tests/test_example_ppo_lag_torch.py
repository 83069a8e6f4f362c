"""examples/ppo_lag_torch trains on the device vector env and lands on the leaderboard's run files.

A short run (two variants of a Table 1 cell, 4,096 steps each, the smoke preset's one seed) of the
script as its README runs it, from outside the repository: it must train, evaluate each run's
policy with the project's Monte Carlo and exact evaluation and write one submitted run per
(variant, seed), all of one configuration, which a second identical training and an evaluation of
the saved weights (``--load``) do not duplicate.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from morality_gym.results.identity import configuration_key
from morality_gym.results.schema import read_runs

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "examples" / "ppo_lag_torch" / "ppo_lag.py"
NAME = "PPO-Lag torch smoke"


def _run(results: Path, cwd: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    args = ["--cells", "Utility/SwitchStandard", "--variants", "HumanA", "AnimalB", "--preset", "smoke",
            "--total-steps", "4096", "--num-envs", "8", "--num-steps", "64", "--name", NAME, "--results", str(results), *extra]
    return subprocess.run([sys.executable, str(SCRIPT), *args], cwd=cwd, env=env, capture_output=True, text=True, check=False)


def test_the_example_trains_and_writes_submitted_runs(tmp_path: Path) -> None:
    out = _run(tmp_path / "results", tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "training 2 runs" in out.stdout and "env steps/s" in out.stdout
    runs = read_runs(tmp_path / "results")
    assert len(runs) == 2
    assert set(runs["env_id"]) == {"SwitchStandard-HumanA-v1", "SwitchStandard-AnimalB-v1"}
    assert set(runs["learner"]) == {NAME} and set(runs["algo"]) == {"submitted"} and set(runs["seed"]) == {41}
    assert runs["metric"].between(0, 1).all() and runs["exact_metric"].between(0, 1).all()  # a stationary policy: exact too
    assert set(runs["chain"]) == {"Utility"} and set(runs["status"]) == {"ok"}
    again = _run(tmp_path / "results", tmp_path)  # same script, same weights (seeded): the same runs, not new ones
    assert again.returncode == 0, again.stdout + again.stderr
    assert len(read_runs(tmp_path / "results")) == 2
    keys = {configuration_key(json.loads(c)) for c in runs["config"]}
    assert len(keys) == 1  # one entry's runs are one configuration of the cell (else the leaderboard counts one)
    loaded = _run(tmp_path / "results", tmp_path, "--load", str(tmp_path / "results" / "ppo_lag_torch_actor.pt"))
    assert loaded.returncode == 0, loaded.stdout + loaded.stderr
    assert "training" not in loaded.stdout and len(read_runs(tmp_path / "results")) == 2  # the saved weights: the same runs
