"""Conformance: every golden episode recorded from the reference replays exactly.

Compares, step by step, reward, terminated, truncated, every norm event, every utility value (a
missing key equals 0), termination statuses, goal_reached and the flat observation (1e-6), for the
1,406 episodes in ``../shared/conformance`` and the 25 golden traces of ``scenarios.json``.
"""

from __future__ import annotations

import gzip
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from morality_gym import TrolleyEnv, env_ids
from tests.conftest import SHARED

SCENARIO_FILES = sorted(p.name for p in (SHARED / "conformance").glob("*.jsonl.gz")) or ["<absent>"]


def _compare_step(where: str, expected: dict[str, Any], obs: np.ndarray, reward: float, terminated: bool,
                  truncated: bool, info: dict[str, Any]) -> None:
    assert reward == pytest.approx(expected["reward"], abs=1e-6), f"{where}: reward"
    assert terminated == expected["terminated"], f"{where}: terminated"
    assert truncated == expected["truncated"], f"{where}: truncated"
    ne, exp_ne = info["norm_events"], expected["norm_events"]
    for category in ("action", "outcome", "causal"):
        assert sorted(ne[category]) == sorted(exp_ne[category]), f"{where}: norm_events[{category}]"
    keys = set(ne["utility"]) | set(exp_ne["utility"])
    for key in keys:
        assert ne["utility"].get(key, 0) == exp_ne["utility"].get(key, 0), f"{where}: utility[{key}]"
    assert info["termination_statuses"] == expected["termination_statuses"], f"{where}: termination_statuses"
    assert info["goal_reached"] == expected["goal_reached"], f"{where}: goal_reached"
    np.testing.assert_allclose(obs, expected["obs"], atol=1e-6, rtol=0, err_msg=f"{where}: observation")


def _env(env_id: str, max_steps: int | None, overrides: dict[str, Any] | None = None) -> TrolleyEnv:
    return TrolleyEnv(env_id, max_steps=max_steps, obs_type="flat", overrides=overrides)


@pytest.mark.parametrize("filename", SCENARIO_FILES)
def test_conformance_episodes(shared_dir: Path, filename: str) -> None:
    """Every recorded episode of one scenario, on fresh and reused env instances."""
    envs: dict[tuple[str, Any], TrolleyEnv] = {}
    n = 0
    with gzip.open(shared_dir / "conformance" / filename, "rt") as fh:
        for line in fh:
            episode = json.loads(line)
            max_steps = episode["env_config"].get("max_timesteps")
            key = (episode["env_id"], max_steps)
            env = envs.setdefault(key, _env(episode["env_id"], max_steps))  # reused across episodes
            obs, info = env.reset(seed=episode["reset_seed"])
            np.testing.assert_allclose(obs, episode["reset"]["obs"], atol=1e-6, rtol=0)
            assert info["termination_statuses"] == episode["reset"]["termination_statuses"]
            assert info["goal_reached"] == episode["reset"]["goal_reached"]
            steps = episode["steps"]
            for t, action in enumerate(episode["actions"]):
                expected = {k: steps[k][t] for k in steps}
                _compare_step(f"{episode['episode_id']} step {t + 1}", expected, *env.step(action))
            n += 1
    assert n > 0


def test_conformance_covers_every_env(shared_dir: Path) -> None:
    index = json.loads((shared_dir / "conformance" / "INDEX.json").read_text())
    assert sorted(index["envs"]) == sorted(env_ids())
    for env_id, entry in index["envs"].items():
        env = _env(env_id, None)
        assert env.observation_space.shape == (entry["obs_dim"],), env_id
        assert env.codec.layout() == entry["obs_layout"], env_id


def _golden_traces() -> list[dict[str, Any]]:
    path = SHARED / "spec" / "scenarios.json"
    if not path.is_file():
        return []
    return json.loads(path.read_text())["golden_traces"]


GOLDEN = _golden_traces()


@pytest.mark.parametrize("k", range(len(GOLDEN)) if GOLDEN else [pytest.param(0, marks=pytest.mark.skip(reason="../shared absent"))])
def test_golden_trace(shared_dir: Path, k: int) -> None:
    trace = GOLDEN[k]
    raw = dict(trace["scenario_overrides"] or {})
    max_steps = raw.pop("max_timesteps", None)
    overrides: dict[str, Any] = {}
    if "player_pos" in raw:
        overrides["player_start"] = raw.pop("player_pos")
    if "character_positions" in raw:
        overrides["character_starts"] = raw.pop("character_positions")
    assert not raw, f"unhandled override {raw}"
    env = _env(trace["env_id"], max_steps, overrides or None)
    env.reset()
    for t, (action, expected) in enumerate(zip(trace["actions"], trace["steps"])):
        assert expected["action"] == action
        _compare_step(f"trace {k + 1} ({trace['description']}) step {t + 1}", expected, *env.step(action))


def test_initial_observations(shared_dir: Path) -> None:
    envs = json.loads((shared_dir / "spec" / "scenarios.json").read_text())["envs"]
    for env_id, entry in envs.items():
        obs, _ = _env(env_id, None).reset()
        np.testing.assert_allclose(obs, entry["initial_flat_obs_normalised"], atol=1e-9, err_msg=env_id)
