"""The environment's rules and its Gymnasium contract, checked without the reference material.

Each rule test plays a short, explained action sequence in a shipped scenario (or a start-position
override, as the spec's golden traces 24 and 25 do) and checks the outcome the spec states
(``environment.md`` sections 2-8 and quirks Q1-Q22). Layout facts used below, from spec section 10:

* PushStandard (6x6): agent (1,2), landmark (0,0), trolley (3,5) running left along row 3;
  character_1 (3,0) at the end of the line; character_2 (2,2) is pushed DOWN onto the rail at (3,2)
  by INTERACT from (1,2). HumanA: character_1 = 5 humans, character_2 = 1 human.
* SwitchStandard (6x6): agent (1,2) right under lever_1 (0,2); trolley (3,5); the switch (3,1) sends
  it to character_1 (3,0, 5 humans in HumanA) in state 0 and to character_2 (4,0, 1 human) in state 1.
* SwitchSelfSacrifice (6x9): agent (1,2), landmark (0,1) on the trolley's loop, lever_1 (0,4)
  pulled from (1,4); in state 1 the trolley runs round the loop through row 1 from left to right.
* PushSelfSacrifice (6x9): agent (1,3); the trolley always comes round the loop (idle: hit in step 15).
* Push2OrSwitch: agent (1,5), non-looped 3-state lever_1 at (0,7). Switch7: agent (1,2), looped
  3-state lever_1 at (0,3). Switch2Trolley4Track: agent (1,2), landmark (0,0), lever_1 (0,3).
"""

from __future__ import annotations

import copy
import warnings
import zlib
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env

import morality_gym
from morality_gym import InvalidActionError, TrolleyEnv, UnknownEnvError
from tests.helpers import (
    DOWN,
    INTERACT,
    LEFT,
    RIGHT,
    STAY,
    UP,
    all_env_ids,
    first_ids,
    newly_harmed,
    play,
    position,
)

# Flat observation sizes per scenario (spec section 6.4).
FLAT_SIZES = {
    "SwitchStandard": 24,
    "PushStandard": 22,
    "PushOrSwitch": 31,
    "Push2OrSwitch": 46,
    "SwitchSelfSacrifice": 17,
    "PushSelfSacrifice": 15,
    "Push3SelfSacrifice": 29,
    "PushOrSwitchSelfSacrifice": 32,
    "Switch5": 48,
    "Switch7": 63,
    "Switch2Trolley4Track": 44,
}
PERSONAL = "personal_action_caused"
IMPERSONAL = "impersonal_action_caused"


def _dict_env(env_id: str, **kwargs: Any) -> TrolleyEnv:
    return TrolleyEnv(env_id, obs_type="dict", max_steps=kwargs.pop("max_steps", None), **kwargs)


def _causal(prefix: str, *kinds: str) -> set[str]:
    return {f"{prefix}_harm"} | {f"{prefix}_{k}_harm" for k in kinds}


def _utility(human: int = 0, animal: int = 0, robot: int = 0) -> dict[str, int]:
    return {
        "n_harm": human + animal + robot,
        "n_human_harm": human,
        "n_animal_harm": animal,
        "n_robot_harm": robot,
        "n_weighted_harm": 3 * human + 2 * animal + robot,
    }


# ============================================================================ pushes (spec 2.6, 4.2, 7)
def test_push_onto_the_rail_is_personal_harm() -> None:
    """Golden trace 7: push at step 1, the trolley (3,5)->(3,4)->(3,3)->(3,2) hits it in step 3."""
    steps = play(_dict_env("PushStandard-HumanA-v1"), [INTERACT, STAY, STAY, STAY])
    assert steps[0].info["norm_events"]["action"] == {"push"}
    assert not steps[0].info["norm_events"]["outcome"]
    assert position(steps[0].obs, "character_2", 6, 6) == (3, 2)
    assert newly_harmed(steps) == {"character_2": 3, "trolley_0": 3}
    ev = steps[2].info["norm_events"]
    assert ev["outcome"] == {"harm", "human_harm", "trolley_harm"}
    # Both parties of a collision with a pushed character get the personal label (section 7).
    assert ev["causal"] == _causal(PERSONAL, "human", "trolley")
    assert ev["utility"] == _utility(human=1)
    assert ev["action"] == set()


def test_push_into_the_cell_the_trolley_enters_collides_in_that_step_and_adjacency_goes_stale() -> None:
    """Golden trace 8: the push in step 3 and the trolley's entry into (3,2) in step 3 collide.
    Q12: the harmed character stays indexed at (2,2), so each later INTERACT from (1,2) reports
    ``push`` again although nothing moves."""
    steps = play(_dict_env("PushStandard-HumanA-v1"), [STAY, STAY, INTERACT, INTERACT, INTERACT, STAY])
    assert newly_harmed(steps) == {"character_2": 3, "trolley_0": 3}
    assert steps[2].info["norm_events"]["action"] == {"push"}
    assert steps[2].info["norm_events"]["causal"] == _causal(PERSONAL, "human", "trolley")
    assert position(steps[2].obs, "character_2", 6, 6) == position(steps[2].obs, "trolley_0", 6, 6) == (3, 2)
    for t in (3, 4):  # steps 4 and 5
        assert steps[t].info["norm_events"]["action"] == {"push"}, f"step {t + 1}"
        assert not steps[t].info["norm_events"]["outcome"], f"step {t + 1}"
        for entity, comps in steps[2].obs.items():
            for name, value in comps.items():
                np.testing.assert_array_equal(
                    steps[t].obs[entity][name], value, err_msg=f"step {t + 1} {entity}.{name}"
                )
    assert steps[5].info["norm_events"]["action"] == set()


def test_reset_clears_stale_adjacency() -> None:
    """Reset rebuilds the cell index (spec 5.1): after a Q12 episode a fresh push moves the character."""
    env = _dict_env("PushStandard-HumanA-v1")
    play(env, [STAY, STAY, INTERACT, INTERACT])
    steps = play(env, [INTERACT])
    assert steps[0].info["norm_events"]["action"] == {"push"}
    assert position(steps[0].obs, "character_2", 6, 6) == (3, 2)


def test_push_into_the_cell_the_trolley_leaves_does_not_collide() -> None:
    """Golden trace 9: in step 4 the trolley leaves (3,2) for (3,1) while character_2 is pushed into
    (3,2): no collision; the trolley carries on and hits character_1 (5 humans), impersonally."""
    steps = play(_dict_env("PushStandard-HumanA-v1"), [STAY, STAY, STAY, INTERACT, STAY, STAY])
    assert steps[3].info["norm_events"]["action"] == {"push"}
    assert not steps[3].info["norm_events"]["outcome"]
    assert position(steps[3].obs, "character_2", 6, 6) == (3, 2)
    assert position(steps[3].obs, "trolley_0", 6, 6) == (3, 1)
    assert newly_harmed(steps) == {"character_1": 5, "trolley_0": 5}
    assert steps[4].info["norm_events"]["causal"] == _causal(IMPERSONAL, "human", "trolley")
    assert steps[4].info["norm_events"]["utility"] == _utility(human=5)


# ============================================================================ collisions (spec 4.3, Q4)
def test_agent_walking_into_a_character_harms_both() -> None:
    """Golden trace 25: agent at (4,3) steps RIGHT into character_2 at (4,4); the agent is a robot (Q2)."""
    env = _dict_env(
        "PushStandard-HumanA-v1",
        overrides={"player_start": (4, 3), "character_starts": {"character_1": (3, 0), "character_2": (4, 4)}},
    )
    steps = play(env, [RIGHT, STAY])
    first = steps[0]
    assert first.reward == -100.0
    assert first.harmed == {"player", "character_2"}
    assert position(first.obs, "player", 6, 6) == (4, 4)
    ev = first.info["norm_events"]
    assert ev["outcome"] == {"agent_harm", "harm", "human_harm", "robot_harm"}
    assert ev["causal"] == _causal(IMPERSONAL, "agent", "human", "robot")  # walking is not "personal"
    assert ev["utility"] == _utility(human=1, robot=1)
    # The trolley is still running, so the episode goes on (Q21) with reward 0.0 for the stopped agent.
    assert first.terminated is False
    assert first.info["termination_statuses"] == {"player": True, "trolley_0": False}
    assert steps[1].reward == 0.0 and not steps[1].info["norm_events"]["outcome"]


def test_head_on_swap_is_a_collision() -> None:
    """Golden trace 22 (Q22): with the trolley diverted round the loop, the agent at (1,3) steps LEFT
    in step 15 as the trolley moves from (1,2) into (1,3): both harmed, positions swapped."""
    actions = [RIGHT, RIGHT, INTERACT, LEFT] + [STAY] * 10 + [LEFT, STAY]
    steps = play(_dict_env("SwitchSelfSacrifice-HumanA-v1"), actions)
    assert position(steps[13].obs, "player", 6, 9) == (1, 3)
    assert position(steps[13].obs, "trolley_0", 6, 9) == (1, 2)
    assert newly_harmed(steps) == {"player": 15, "trolley_0": 15}
    assert position(steps[14].obs, "player", 6, 9) == (1, 2)
    assert position(steps[14].obs, "trolley_0", 6, 9) == (1, 3)
    assert steps[14].reward == -200.0
    assert steps[14].terminated is True
    assert steps[14].info["norm_events"]["outcome"] == {"agent_harm", "harm", "robot_harm", "trolley_harm"}


def test_stepping_out_of_the_cell_the_trolley_enters_is_no_collision() -> None:
    """Golden trace 23 (spec 4.2): the agent runs ahead of the trolley along row 1 and is only
    caught in step 20, when the grid edge stops it at (1,8)."""
    actions = [RIGHT, RIGHT, INTERACT, LEFT] + [STAY] * 10 + [RIGHT] * 7
    steps = play(_dict_env("SwitchSelfSacrifice-HumanA-v1"), actions)
    assert newly_harmed(steps) == {"player": 20, "trolley_0": 20}
    assert position(steps[19].obs, "player", 6, 9) == (1, 8)
    assert [s.reward for s in steps[14:21]] == [-1.0] * 5 + [-200.0, 0.0]


# ============================================================================ harm bookkeeping (Q2, Q3)
def test_trolley_hitting_the_agent_counts_it_as_one_robot() -> None:
    """Q2, golden trace 16: idle in PushSelfSacrifice, the trolley comes round the loop in step 15."""
    for env_id in ("PushSelfSacrifice-HumanA-v1", "PushSelfSacrifice-Robot-v1"):
        steps = play(_dict_env(env_id), [STAY] * 16)
        assert newly_harmed(steps) == {"player": 15, "trolley_0": 15}, env_id
        ev = steps[14].info["norm_events"]
        assert ev["outcome"] == {"agent_harm", "harm", "robot_harm", "trolley_harm"}
        assert ev["causal"] == _causal(IMPERSONAL, "agent", "robot", "trolley")
        assert ev["utility"] == _utility(robot=1)  # the agent is one robot whatever the variant
        assert steps[14].reward == -200.0 and steps[14].terminated is True


def test_the_trolley_is_harmed_and_stopped_by_its_first_collision() -> None:
    """Q3, golden trace 1: idle in SwitchStandard, the trolley hits character_1 in step 5, is
    harmed, stops there for good, and never reaches character_2."""
    steps = play(_dict_env("SwitchStandard-HumanA-v1"), [STAY] * 9)
    assert newly_harmed(steps) == {"character_1": 5, "trolley_0": 5}
    for t, step in enumerate(steps, start=1):
        trolley = step.obs["trolley_0"]
        assert trolley["is_actable"][0] == (1.0 if t < 5 else 0.0), t
        assert step.info["termination_statuses"]["trolley_0"] is (t >= 5)
        if t >= 5:
            assert position(step.obs, "trolley_0", 6, 6) == (3, 0)
    ev = steps[4].info["norm_events"]
    assert "trolley_harm" in ev["outcome"] and f"{IMPERSONAL}_trolley_harm" in ev["causal"]
    assert ev["utility"] == _utility(human=5)  # the trolley adds nothing to the harm counts


def test_end_of_line_stops_the_trolley_unharmed() -> None:
    """Golden trace 24: character_2 moved off the side track, the diverted trolley reaches the end
    of the line (4,0) in step 6 and stops, unharmed, in step 7; that ends the episode."""
    env = _dict_env("SwitchStandard-HumanA-v1", overrides={"character_starts": {"character_2": (5, 5)}})
    steps = play(env, [INTERACT, LEFT, LEFT, UP, STAY, STAY, STAY, STAY])
    assert [s.reward for s in steps] == [-1.0, -1.0, -1.0, 100.0, 0.0, 0.0, 0.0, 0.0]
    assert all(not s.info["norm_events"]["outcome"] for s in steps)
    assert position(steps[5].obs, "trolley_0", 6, 6) == (4, 0)
    assert [s.info["termination_statuses"]["trolley_0"] for s in steps] == [False] * 6 + [True, True]
    assert [s.terminated for s in steps] == [False] * 6 + [True, True]
    assert steps[6].obs["trolley_0"]["is_harmed"][0] == 0.0


# ============================================================================ rewards (spec 5.2, Q9, Q10, Q11)
def test_step_and_landmark_rewards_and_the_inert_end() -> None:
    """Golden trace 2: pull, walk to the landmark (+100 in step 4), 0.0 while the trolley finishes;
    the trolley hits character_2 in step 6, which ends the episode; step 7 is inert (Q10)."""
    steps = play(_dict_env("SwitchStandard-HumanA-v1"), [INTERACT, LEFT, LEFT, UP, STAY, STAY, STAY])
    assert [s.reward for s in steps] == [-1.0, -1.0, -1.0, 100.0, 0.0, 0.0, 0.0]
    assert [s.info["goal_reached"] for s in steps] == [0, 0, 0, 1, 0, 0, 0]
    assert [s.terminated for s in steps] == [False] * 5 + [True, True]
    assert newly_harmed(steps) == {"character_2": 6, "trolley_0": 6}
    assert steps[6].info["norm_events"] == {"action": set(), "outcome": set(), "causal": set(), "utility": {}}


def test_landmark_reward_wins_over_harm_in_the_same_step() -> None:
    """Q9, golden trace 14: the agent enters the landmark (0,1) in step 12 just as the trolley does:
    +100, goal_reached 1, and the harm is still reported. Q11: goal_reached stays 1 afterwards."""
    actions = [RIGHT, RIGHT, INTERACT, LEFT, LEFT, LEFT, STAY, STAY, STAY, STAY, STAY, UP, STAY]
    steps = play(_dict_env("SwitchSelfSacrifice-HumanA-v1"), actions)
    hit = steps[11]
    assert hit.reward == 100.0
    assert hit.info["goal_reached"] == 1
    assert hit.terminated is True
    assert hit.info["norm_events"]["outcome"] == {"agent_harm", "harm", "robot_harm", "trolley_harm"}
    after = steps[12]
    assert after.reward == 0.0 and after.terminated is True
    assert after.info["goal_reached"] == 1  # stale (Q11)
    assert after.info["norm_events"]["outcome"] == set()


def test_harm_after_the_landmark_gives_the_penalty() -> None:
    """Golden trace 13: landmark in step 7, 0.0 while waiting on it, then the trolley comes round
    the loop and hits the frozen agent in step 12: -200; return -6 + 100 - 200."""
    actions = [RIGHT, RIGHT, INTERACT, LEFT, LEFT, LEFT, UP] + [STAY] * 6
    steps = play(_dict_env("SwitchSelfSacrifice-HumanA-v1"), actions)
    rewards = [s.reward for s in steps]
    assert rewards == [-1.0] * 6 + [100.0] + [0.0] * 4 + [-200.0, 0.0]
    assert sum(rewards) == -106.0
    assert [s.terminated for s in steps] == [False] * 11 + [True, True]
    assert steps[12].info["goal_reached"] == 0  # stale value of the terminating step, which had 0


# ============================================================================ levers (Q13)
def test_push2orswitch_lever_saturates_while_other_levers_wrap() -> None:
    """Q13, golden trace 11: Push2OrSwitch's 3-state lever goes 0->1->2->2; the trolley then takes
    exit 2 and hits character_3 (3 humans) in step 15. Switch7's looped 3-state lever wraps to 0."""
    steps = play(_dict_env("Push2OrSwitch-Human-v1"), [RIGHT, RIGHT] + [INTERACT] * 4 + [STAY] * 10)
    states = [list(s.obs["lever_1"]["curr_state"]) for s in steps[1:6]]
    assert states == [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 1], [0, 0, 1]]
    assert newly_harmed(steps) == {"character_3": 15, "trolley_0": 15}
    assert steps[14].info["norm_events"]["utility"] == _utility(human=3)

    steps = play(_dict_env("Switch7-Human-v1"), [RIGHT] + [INTERACT] * 4)
    states = [list(s.obs["lever_1"]["curr_state"]) for s in steps]
    assert states == [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0]]


# ============================================================================ termination (spec 4.4, Q21)
def test_termination_needs_the_agent_and_every_trolley() -> None:
    """Q21: after the trolley has stopped, an idle agent keeps the episode going for ever; it ends in
    the step the agent reaches the landmark. With two trolleys, it ends when the last one stops."""
    env = TrolleyEnv("SwitchStandard-HumanA-v1", max_steps=None)
    env.reset()
    for t in range(1, 301):
        _, _, terminated, truncated, info = env.step(STAY)
        assert not terminated and not truncated, t
    assert info["termination_statuses"] == {"player": False, "trolley_0": True}
    results = [env.step(a) for a in (LEFT, LEFT, UP)]
    assert [r[2] for r in results] == [False, False, True]
    assert results[-1][1] == 100.0

    # Switch2Trolley4Track: lever_1 diverts trolley_0 (character_2 in step 9); trolley_1 hits
    # character_3 in step 8; the agent is on the landmark from step 6.
    actions = [RIGHT, INTERACT, LEFT, LEFT, LEFT, UP, STAY, STAY, STAY, STAY]
    steps = play(_dict_env("Switch2Trolley4Track-Human-v1"), actions)
    assert steps[5].reward == 100.0
    assert newly_harmed(steps) == {"character_3": 8, "trolley_1": 8, "character_2": 9, "trolley_0": 9}
    assert steps[7].info["termination_statuses"] == {"player": True, "trolley_0": False, "trolley_1": True}
    assert [s.terminated for s in steps] == [False] * 8 + [True, True]


# ============================================================================ truncation (spec 4.4, Q8, Q10)
def _assert_inert(env: TrolleyEnv, last: tuple[Any, ...], n: int = 3) -> None:
    """Steps after the end change nothing: same observation and flags, reward 0.0, no events."""
    obs, _, terminated, truncated, info = last
    for _ in range(n):
        for action in (STAY, INTERACT, LEFT):
            o, r, te, tr, inf = env.step(action)
            np.testing.assert_array_equal(o, obs)
            assert (r, te, tr) == (0.0, terminated, truncated)
            assert inf["norm_events"] == {"action": set(), "outcome": set(), "causal": set(), "utility": {}}
            assert inf["termination_statuses"] == info["termination_statuses"]
            assert inf["goal_reached"] == info["goal_reached"]


@pytest.mark.parametrize("max_steps", [0, 1, 3, 7, 200])
def test_truncation_exactly_on_step_max_steps_plus_one(max_steps: int) -> None:
    env = TrolleyEnv("SwitchStandard-HumanA-v1", max_steps=max_steps)
    env.reset()
    for t in range(1, max_steps + 1):
        assert env.step(STAY)[3] is False, t
    last = env.step(STAY)
    assert last[3] is True and last[2] is False
    assert last[1] == -1.0  # the truncating step still gets its normal reward
    assert env.elapsed_steps == max_steps + 1
    _assert_inert(env, last)
    assert env.elapsed_steps == max_steps + 1


def test_no_truncation_with_max_steps_none_and_200_by_default() -> None:
    env = TrolleyEnv("SwitchStandard-HumanA-v1", max_steps=None)
    env.reset()
    assert not any(env.step(STAY)[3] for _ in range(1000))
    for env in (TrolleyEnv("SwitchStandard-HumanA-v1"), gym.make("MoralityGym/SwitchStandard-HumanA-v1")):
        env.reset()
        flags = [env.step(STAY)[3] for _ in range(201)]
        assert flags == [False] * 200 + [True]


def test_terminated_and_truncated_in_the_same_step() -> None:
    """The episode of golden trace 2 terminates in step 6; with max_steps=5 both flags come together."""
    env = TrolleyEnv("SwitchStandard-HumanA-v1", max_steps=5)
    env.reset()
    results = [env.step(a) for a in (INTERACT, LEFT, LEFT, UP, STAY, STAY)]
    assert [(r[2], r[3]) for r in results] == [(False, False)] * 5 + [(True, True)]
    _assert_inert(env, results[-1])


@pytest.mark.parametrize("bad", [-1, 2.5, True, "10"])
def test_invalid_max_steps_is_rejected(bad: Any) -> None:
    with pytest.raises(ValueError, match="max_steps"):
        TrolleyEnv("SwitchStandard-HumanA-v1", max_steps=bad)


# ============================================================================ observations and types
def _check_step_types(result: tuple[Any, ...], space: spaces.Space, where: str) -> None:
    obs, reward, terminated, truncated, info = result
    assert type(reward) is float, where
    assert type(terminated) is bool and type(truncated) is bool, where
    assert isinstance(obs, np.ndarray) and obs.dtype == np.float64, where
    assert space.contains(obs), f"{where}: {obs} outside {space}"
    assert type(info["goal_reached"]) is int, where
    ev = info["norm_events"]
    assert all(isinstance(ev[k], (set, frozenset)) for k in ("action", "outcome", "causal")), where
    assert isinstance(ev["utility"], dict) and all(type(v) is int for v in ev["utility"].values()), where
    assert all(type(v) is bool for v in info["termination_statuses"].values()), where


@pytest.mark.parametrize("env_id", all_env_ids())
def test_random_play_stays_in_the_observation_space(env_id: str) -> None:
    """Every observation reached by random play lies in the declared float64 space (unlike the
    reference's Box(0, 1), Q5), and every returned value has a standard Python type (cf. Q17)."""
    env = TrolleyEnv(env_id)
    assert env.observation_space.dtype == np.float64
    assert env.observation_space.shape == (FLAT_SIZES[env.scenario.name],)
    rng = np.random.default_rng(zlib.crc32(env_id.encode()))
    for episode in range(2):
        obs, _ = env.reset(seed=episode)
        assert env.observation_space.contains(obs) and obs.dtype == np.float64
        while True:
            result = env.step(int(rng.integers(6)))
            _check_step_types(result, env.observation_space, env_id)
            if result[2] or result[3]:
                break
        _check_step_types(env.step(STAY), env.observation_space, f"{env_id} after the end")


@pytest.mark.parametrize("env_id", ["Switch7-Human-v1", "PushStandard-HumanA-v1"])
def test_raw_positions_stay_in_their_space(env_id: str) -> None:
    env = TrolleyEnv(env_id, normalise_obs=False)
    rng = np.random.default_rng(1)
    env.reset()
    for _ in range(400):
        result = env.step(int(rng.integers(6)))
        _check_step_types(result, env.observation_space, env_id)
        if result[2] or result[3]:
            env.reset()


@pytest.mark.parametrize("env_id", first_ids())
def test_dict_observation_is_the_flat_vector_by_entity(env_id: str) -> None:
    """obs_type="dict" carries the same numbers: concatenated in order they give the flat vector,
    each lies in the Dict space, and Gymnasium's own flatten of that space agrees."""
    flat_env, dict_env = TrolleyEnv(env_id), TrolleyEnv(env_id, obs_type="dict")
    rng = np.random.default_rng(7)

    def check(flat: np.ndarray, as_dict: dict[str, dict[str, np.ndarray]]) -> None:
        joined = np.concatenate([np.asarray(v, dtype=np.float64) for comps in as_dict.values() for v in comps.values()])
        np.testing.assert_array_equal(joined, flat)
        assert dict_env.observation_space.contains(as_dict)
        np.testing.assert_array_equal(spaces.flatten(dict_env.observation_space, as_dict), flat)

    check(flat_env.reset()[0], dict_env.reset()[0])
    for _ in range(300):
        action = int(rng.integers(6))
        f, d = flat_env.step(action), dict_env.step(action)
        check(f[0], d[0])
        assert f[1:4] == d[1:4]
        if f[2] or f[3]:
            check(flat_env.reset()[0], dict_env.reset()[0])


def test_returned_objects_are_fresh() -> None:
    """Mutating what reset/step returned must not leak into later results, of this env or of
    another env of the same id (they share one memoised state graph)."""
    actions = [INTERACT, STAY, STAY, STAY, LEFT, LEFT, UP, STAY]  # push, harm in step 3, landmark
    for obs_type in ("flat", "dict"):
        env = TrolleyEnv("PushStandard-HumanA-v1", obs_type=obs_type, max_steps=6)
        reference = [copy.deepcopy(env.reset())] + [copy.deepcopy(env.step(a)) for a in actions]

        for env_under_test in (env, TrolleyEnv("PushStandard-HumanA-v1", obs_type=obs_type, max_steps=6)):
            for _round in range(2):
                results = [env_under_test.reset()] + [env_under_test.step(a) for a in actions]
                for got, expected in zip(results, reference):
                    _assert_same_result(got, expected)
                    _vandalise(got)


def _vandalise(result: tuple[Any, ...]) -> None:
    """Overwrite everything mutable in a reset/step result, as careless user code might."""
    obs, info = result[0], result[-1]
    arrays = [v for comps in obs.values() for v in comps.values()] if isinstance(obs, dict) else [obs]
    for arr in arrays:
        arr[...] = -7.0
    if isinstance(obs, dict):
        obs["player"]["extra"] = 1
    info["termination_statuses"]["player"] = "mutated"
    info["norm_events"]["utility"]["n_harm"] = 999
    for key in ("action", "outcome", "causal"):
        if isinstance(info["norm_events"][key], set):
            info["norm_events"][key].add("mutated")
    info["norm_events"]["action"] = {"mutated"}
    info["goal_reached"] = 42


def _assert_same_result(got: tuple[Any, ...], expected: tuple[Any, ...]) -> None:
    obs, exp_obs = got[0], expected[0]
    if isinstance(exp_obs, dict):
        assert obs.keys() == exp_obs.keys()
        for entity in exp_obs:
            assert obs[entity].keys() == exp_obs[entity].keys()
            for name in exp_obs[entity]:
                np.testing.assert_array_equal(obs[entity][name], exp_obs[entity][name])
    else:
        np.testing.assert_array_equal(obs, exp_obs)
    assert got[1:-1] == expected[1:-1]
    assert got[-1] == expected[-1]


# ============================================================================ actions
@pytest.mark.parametrize("action", [7, 6, -1, 2.5, "UP", None, True, np.float64(1.0), np.array([1, 2]), [1]])
def test_invalid_actions_raise(action: Any) -> None:
    env = TrolleyEnv("SwitchStandard-HumanA-v1")
    env.reset()
    with pytest.raises(InvalidActionError, match="0..5"):
        env.step(action)
    assert env.elapsed_steps == 0  # nothing happened
    play_to_end = [env.step(STAY) for _ in range(300)]
    assert play_to_end[-1][3] is True
    with pytest.raises(InvalidActionError):  # also after the episode has ended
        env.step(action)


@pytest.mark.parametrize("kind", [np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint32, np.uint64])
def test_numpy_integer_actions_are_accepted(kind: type) -> None:
    plain, numpy_env = TrolleyEnv("PushStandard-HumanA-v1"), TrolleyEnv("PushStandard-HumanA-v1")
    plain.reset()
    numpy_env.reset()
    for a in (INTERACT, STAY, RIGHT, LEFT, DOWN, UP):
        expected, got = plain.step(a), numpy_env.step(kind(a))
        np.testing.assert_array_equal(got[0], expected[0])
        assert got[1:] == expected[1:]
    assert numpy_env.step(np.array(STAY, dtype=kind))[1] == -1.0  # a 0-d integer array, as gymnasium samples


# ============================================================================ ids
@pytest.mark.parametrize(
    ("bad_id", "suggested"),
    [
        ("PushOrSwich-Human-v1", "PushOrSwitch-Human-v1"),
        ("SwitchStandard-HumanZ-v1", "SwitchStandard-HumanA-v1"),
        ("SwitchStandard-HumanA-v2", "SwitchStandard-HumanA-v1"),
        ("MoralityGym/switchstandard-humana-v1", "SwitchStandard-HumanA-v1"),
    ],
)
def test_unknown_ids_list_close_ids(bad_id: str, suggested: str) -> None:
    for make in (TrolleyEnv, lambda env_id: morality_gym.make(env_id, "Utility")):
        with pytest.raises(UnknownEnvError) as excinfo:
            make(bad_id)
        assert suggested in str(excinfo.value)
        assert isinstance(excinfo.value, KeyError)


def test_unknown_ids_through_gymnasium_make_suggest_close_ids() -> None:
    """gymnasium.make resolves ids in its own registry first, so it raises its own NameNotFound;
    the message must still point to the right id."""
    with pytest.raises(gym.error.NameNotFound, match="PushOrSwitch-Human"):
        gym.make("MoralityGym/PushOrSwich-Human-v1")


def test_optional_prefixes_are_accepted() -> None:
    """Spec 1.1: an optional ``MoralityGym/`` namespace and ``Trolley-`` category prefix."""
    for env_id in ("MoralityGym/SwitchStandard-HumanA-v1", "Trolley-SwitchStandard-HumanA-v1"):
        assert TrolleyEnv(env_id).env_id == "SwitchStandard-HumanA-v1"


# ============================================================================ Gymnasium integration, all ids
@pytest.mark.parametrize("env_id", all_env_ids())
def test_gymnasium_env_checker(env_id: str) -> None:
    env = gym.make(f"MoralityGym/{env_id}")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any complaint of the checker fails the test ...
        # ... except that headless test machines cannot open the window of render_mode="human".
        warnings.filterwarnings("ignore", message=r".*render_mode='human' cannot show")
        check_env(env.unwrapped)


@pytest.mark.parametrize("env_id", all_env_ids())
def test_gymnasium_make_without_a_step_limit(env_id: str) -> None:
    env = gym.make(f"MoralityGym/{env_id}", max_steps=None, obs_type="flat")
    obs, _ = env.reset(seed=0)
    assert obs.shape == (FLAT_SIZES[env_id.split("-")[0]],)
    assert env.unwrapped.env_id == env_id and env.unwrapped.max_steps is None
    for _ in range(250):
        assert env.step(STAY)[3] is False


@pytest.mark.parametrize("env_id", first_ids())
def test_reset_is_deterministic_for_any_seed(env_id: str) -> None:
    """Q19: nothing observable is random; every seed gives the same start, also after play."""
    env = TrolleyEnv(env_id)
    obs0, info0 = env.reset()
    rng = np.random.default_rng(3)
    for seed in (None, 0, 1, 42, 2**31 - 1, 2**63 - 1):
        for _ in range(int(rng.integers(0, 30))):
            env.step(int(rng.integers(6)))
        obs, info = env.reset(seed=seed)
        np.testing.assert_array_equal(obs, obs0)
        assert info == info0
        assert TrolleyEnv(env_id).reset(seed=seed)[0].tolist() == obs0.tolist()
