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
    # issue 45: the runs record the budget they trained for (they recorded 0), and the hint builds the site the user has
    assert set(runs["budget"]) == {4096} and set(runs["total_steps"]) == {4096}
    assert "4,096 steps each" in out.stdout and "1 torch thread(s)" in out.stdout
    assert "now: python -m leaderboard.build --results" in out.stdout  # outside a checkout: the build command
    again = _run(tmp_path / "results", tmp_path)  # same script, same weights (seeded): the same runs, not new ones
    assert again.returncode == 0, again.stdout + again.stderr
    assert len(read_runs(tmp_path / "results")) == 2
    keys = {configuration_key(json.loads(c)) for c in runs["config"]}
    assert len(keys) == 1  # one entry's runs are one configuration of the cell (else the leaderboard counts one)
    loaded = _run(tmp_path / "results", tmp_path, "--load", str(tmp_path / "results" / "ppo_lag_torch_actor.pt"))
    assert loaded.returncode == 0, loaded.stdout + loaded.stderr
    assert "training" not in loaded.stdout and len(read_runs(tmp_path / "results")) == 2  # the saved weights: the same runs


def test_the_examples_flags_are_described_and_a_budget_under_one_update_is_refused(tmp_path: Path) -> None:
    """Issue 45: ``--help`` listed 31 flags with no description or default, and ``--total-steps 1000``
    trained 2,048 steps without a word; a budget between two updates is rounded down, and said."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    helped = subprocess.run([sys.executable, str(SCRIPT), "--help"], cwd=tmp_path, env=env, capture_output=True, text=True,
                            check=False)
    assert helped.returncode == 0, helped.stderr
    flags = [line.split()[0] for line in helped.stdout.splitlines() if line.strip().startswith("--") and "--help" not in line]
    assert len(flags) >= 30
    text = " ".join(helped.stdout.split())
    assert "environment steps per run" in text and "(default: 200000)" in text and "(default: 0.99)" in text
    refused = _run(tmp_path / "results", tmp_path, "--total-steps", "300")
    assert refused.returncode == 2 and "Traceback" not in refused.stderr
    assert refused.stderr.strip().splitlines() == [
        "error: --total-steps 300 is less than one update (8 copies x 64 steps = 512 steps per run); ask at least that"]
    assert not (tmp_path / "results").exists()
