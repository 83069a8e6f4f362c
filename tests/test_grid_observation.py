"""The grid observation: one shape for every env, faithful to the state, and the same in every engine.

The flat observation stays the default and unchanged (tests/test_conformance.py replays the
reference's golden episodes on it); these tests cover ``obs_type="grid"``.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import morality_gym
from morality_gym.envs.batched import BatchedTrolleyEnv
from morality_gym.envs.mixed import MixedBatchedTrolleyEnv
from morality_gym.envs.registry import parse_env_id
from morality_gym.world.grid_observe import (
    CHANNEL,
    GRID_CHANNELS,
    GRID_HEIGHT,
    GRID_WIDTH,
    GridCodec,
    GridTooSmallError,
)
from morality_gym.world.layout import parse_scenario
from morality_gym.world.rules import World
from tests.helpers import INTERACT, STAY

SHAPE = (GRID_CHANNELS, GRID_HEIGHT, GRID_WIDTH)


def test_every_builtin_env_gives_one_shape_and_its_layout() -> None:
    for env_id in morality_gym.list_envs():
        env = gym.make(env_id, obs_type="grid")
        obs, _ = env.reset()
        assert obs.shape == SHAPE and obs.dtype == np.uint8 and env.observation_space.contains(obs), env_id
        scenario, variant = parse_env_id(env_id)
        h, w = scenario.height, scenario.width
        inside = obs[CHANNEL["wall"]] + obs[CHANNEL["floor"]]
        assert inside[:h, :w].min() == 1 and inside.sum() == h * w, f"{env_id}: the grid is not padded with zeros"
        assert obs[CHANNEL["agent"], scenario.player_start[0], scenario.player_start[1]] == 1
        assert obs[CHANNEL["landmark"]].sum() == 1
        rails = obs[CHANNEL["rail_left"]:CHANNEL["rail_down"] + 1].sum(axis=0)
        assert {tuple(map(int, c)) for c in np.argwhere(rails)} == set(scenario.rails), env_id
        amounts = scenario.variants[variant].amounts
        groups = obs[CHANNEL["human"]:CHANNEL["robot"] + 1].sum()
        assert groups == sum(amounts), env_id


def test_pulling_a_lever_turns_its_switch_in_the_grid() -> None:
    env = gym.make("MoralityGym/SwitchStandard-HumanA-v1", obs_type="grid")
    obs, _ = env.reset()
    assert obs[CHANNEL["rail_left"], 3, 1] == 1 and obs[CHANNEL["rail_down"], 3, 1] == 0  # state 0: exit L
    assert obs[CHANNEL["switch"], 3, 1] == obs[CHANNEL["lever"], 0, 2] == 1  # wired to lever 1
    obs, *_ = env.step(INTERACT)  # the agent starts under the lever
    assert obs[CHANNEL["lever_state"], 0, 2] == 1
    assert obs[CHANNEL["rail_left"], 3, 1] == 0 and obs[CHANNEL["rail_down"], 3, 1] == 1


def test_harm_and_pushes_show_in_the_grid() -> None:
    env = gym.make("MoralityGym/PushStandard-HumanA-v1", obs_type="grid")
    obs, _ = env.reset()
    assert obs[CHANNEL["pushable"], 2, 2] == 1 and obs[CHANNEL["human"], 2, 2] == 1
    obs, *_ = env.step(INTERACT)  # push the bystander onto the line
    assert obs[CHANNEL["human"], 3, 2] == 1 and obs[CHANNEL["human"], 2, 2] == 0
    for _ in range(3):
        obs, *_ = env.step(STAY)
    assert obs[CHANNEL["harmed"], 3, 2] == 1 and obs[CHANNEL["trolley_stopped"], 3, 2] == 1
    assert obs[CHANNEL["human"]].sum() == 5  # the group at the end of the line is safe


def test_batched_and_mixed_simulators_gather_the_same_grids() -> None:
    ids = ["SwitchStandard-HumanA-v1", "Switch7-Human-v1", "PushOrSwitchSelfSacrifice-Human-v1"]
    mixed = MixedBatchedTrolleyEnv(ids, obs_type="grid", max_steps=30)  # three scenarios, one simulator
    singles = [gym.make(f"MoralityGym/{e}", obs_type="grid", max_steps=30) for e in ids]
    first = mixed.reset()
    assert first.shape == (3, GRID_CHANNELS * GRID_HEIGHT * GRID_WIDTH)
    for row, env in zip(first, singles):
        np.testing.assert_array_equal(row.reshape(SHAPE), env.reset()[0])
    rng = np.random.default_rng(3)
    for _ in range(25):
        actions = rng.integers(0, 6, size=3)
        step = mixed.step(actions)
        for i, env in enumerate(singles):
            obs, _, terminated, truncated, _ = env.step(int(actions[i]))
            if terminated or truncated:
                np.testing.assert_array_equal(step.final_obs[i].reshape(SHAPE), obs)
                env.reset()
            else:
                np.testing.assert_array_equal(step.obs[i].reshape(SHAPE), obs)
    flat = BatchedTrolleyEnv(ids[0], 1)
    assert flat.obs_dim == len(gym.make(f"MoralityGym/{ids[0]}").reset()[0])  # the default is unchanged


def test_a_scenario_too_large_for_the_grid_is_refused_in_one_line() -> None:
    width = GRID_WIDTH + 1
    raw = {
        "name": "Wide", "rewards": {"step": -1, "landmark": 100, "agent_harmed": -100},
        "layout": "floor rails things\n" + "." * width + " " + "<" * width + " " + "GP" + "." * (width - 3) + "T\n",
        "characters": {}, "utility_bounds": {k: [0, 1] for k in ("n_harm", "n_human_harm", "n_robot_harm",
                                                                   "n_animal_harm", "n_weighted_harm")},
        "variants": {"A": {"characters": [], "bounds": {}, "relevant": ["agent_harm"]}},
    }
    world = World(parse_scenario(raw, "wide.yaml"), "A")
    with pytest.raises(GridTooSmallError, match=r"wide.yaml: layout: Wide is 1x17, larger than the grid"):
        GridCodec(world)
