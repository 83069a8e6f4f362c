"""The batched simulator and its two vector faces reproduce the single environment step for step.

:class:`BatchedTrolleyEnv` steps N copies by gathering from the enumerated state graph; the
Gymnasium ``VectorEnv`` and the SB3 ``VecEnv`` wrap it. The reference for each is the plain
:class:`TrolleyEnv` (one per copy), driven the way Gymnasium's own ``SyncVectorEnv`` and SB3's own
``DummyVecEnv`` drive it, so that their documented auto-reset semantics are the yardstick rather
than our reading of them. Short episodes (``max_steps`` of 20-25) make every run cross many
terminations, truncations and auto-resets.
"""

from __future__ import annotations

import warnings
import zlib
from functools import partial
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from stable_baselines3.common.vec_env import DummyVecEnv

from morality_gym import BatchedTrolleyEnv, TrolleyEnv, TrolleyVecEnv, TrolleyVectorEnv
from morality_gym.world.vocab import UTILITIES, names_to_mask
from tests.helpers import STAY, first_ids

MAX_STEPS = 25


def _rng(*parts: object) -> np.random.Generator:
    return np.random.default_rng(zlib.crc32(repr(parts).encode()))


def _mask(norm_events: dict[str, Any]) -> int:
    return names_to_mask([*norm_events["action"], *norm_events["outcome"], *norm_events["causal"]])


def _f32(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, dtype=np.float64).astype(np.float32)


# ============================================================================ the batched simulator
@pytest.mark.parametrize("autoreset", ["same_step", "disabled"])
@pytest.mark.parametrize("env_id", first_ids())
def test_batched_simulator_matches_single_envs(env_id: str, autoreset: str) -> None:
    """Random play, copy by copy against one TrolleyEnv each: observations (as float32), rewards,
    flags, event masks against the event names, utilities, goal_reached, and final observations
    of the copies auto-reset in the step they ended ("same_step"), or inert ended copies that are
    reset later, some at a time, with a mask ("disabled")."""
    n = 6
    batch = BatchedTrolleyEnv(env_id, n, max_steps=MAX_STEPS, autoreset=autoreset)
    singles = [TrolleyEnv(env_id, max_steps=MAX_STEPS) for _ in range(n)]
    obs = batch.reset()
    latest = [e.reset()[0] for e in singles]
    assert obs.dtype == np.float32 and obs.shape == (n, latest[0].shape[0])
    np.testing.assert_array_equal(obs, np.stack([_f32(o) for o in latest]))
    rng = _rng(env_id, autoreset)
    over = np.zeros(n, dtype=bool)  # "disabled" mode: copies that ended and wait for their reset
    ended_seen = 0
    for t in range(150):
        actions = rng.integers(0, 6, n)
        res = batch.step(actions)
        utility = batch.utility(res.transition)
        goal = batch.goal_reached(res.transition)
        ended = np.zeros(n, dtype=bool)
        for i, env in enumerate(singles):
            was_over = bool(over[i])
            o, r, te, tr, info = env.step(int(actions[i]))
            over[i] = te or tr
            where = f"{env_id} copy {i} step {t + 1}"
            assert res.reward[i] == np.float32(r), where
            assert (bool(res.terminated[i]), bool(res.truncated[i])) == (te, tr), where
            assert res.events[i] == _mask(info["norm_events"]), where
            if not was_over:  # ended copies: see test_ended_copies_report_no_phantom_transition
                assert list(utility[i]) == [info["norm_events"]["utility"].get(u, 0) for u in UTILITIES], where
                assert goal[i] == info["goal_reached"], where
            if autoreset == "same_step" and (te or tr):
                ended[i] = True
                np.testing.assert_array_equal(res.final_obs[i], _f32(o), err_msg=where)
                o, _ = env.reset()
                over[i] = False
            latest[i] = o
            np.testing.assert_array_equal(res.obs[i], _f32(o), err_msg=where)
        if autoreset == "same_step":
            assert (res.final_obs is None) == (not ended.any())
            ended_seen += int(ended.sum())
        else:
            assert res.final_obs is None
            done = res.terminated | res.truncated
            ended_seen += int(done.sum())
            # Ended copies stay inert until reset; reset some of them now, leave others waiting.
            chosen = done & (rng.random(n) < 0.4)
            if chosen.any():
                obs = batch.reset(chosen)
                for i in np.flatnonzero(chosen):
                    latest[i], _ = singles[i].reset()
                    over[i] = False
                np.testing.assert_array_equal(obs, np.stack([_f32(o) for o in latest]))
    assert ended_seen > 0


def test_batched_float64_observations_are_the_single_env_values_exactly() -> None:
    env_id = "Switch7-Human-v1"
    batch = BatchedTrolleyEnv(env_id, 3, obs_dtype=np.float64, max_steps=None, autoreset="disabled")
    singles = [TrolleyEnv(env_id, max_steps=None) for _ in range(3)]
    np.testing.assert_array_equal(batch.reset(), np.stack([e.reset()[0] for e in singles]))
    rng = _rng("f64")
    for _ in range(60):
        actions = rng.integers(0, 6, 3)
        res = batch.step(actions)
        assert res.obs.dtype == np.float64
        np.testing.assert_array_equal(res.obs, np.stack([e.step(int(a))[0] for e, a in zip(singles, actions)]))


def test_ended_copies_report_no_phantom_transition() -> None:
    """With auto-reset disabled, a copy that has ended stays inert: reward 0 and no events. Its
    ``transition`` must not describe a move either. SwitchStandard truncated after step 4
    (max_steps=3) would have seen the trolley hit 5 humans in step 5 had it gone on: that harm
    did not happen, so ``utility(transition)`` must not report it."""
    batch = BatchedTrolleyEnv("SwitchStandard-HumanA-v1", 1, max_steps=3, autoreset="disabled")
    batch.reset()
    for _ in range(4):
        res = batch.step(np.array([STAY]))
    assert res.truncated[0]
    res = batch.step(np.array([STAY]))  # step 5: the copy is over
    assert res.reward[0] == 0.0 and res.events[0] == 0
    assert batch.utility(res.transition)[0].tolist() == [0] * len(UTILITIES)
    assert not batch.goal_reached(res.transition)[0]


# (actions, faces that must reject them). The SB3 face reshapes any array of num_envs integers
# to (num_envs,), because SB3 may pass discrete actions as (num_envs, 1).
INVALID = [
    ("too-large", np.array([0, 1, 6]), "batch vector sb3"),
    ("negative", np.array([0, -1, 2]), "batch vector sb3"),
    ("float", np.array([0.0, 1.0, 2.5]), "batch vector sb3"),
    ("integral-floats", np.array([0.0, 1.0, 2.0]), "batch vector sb3"),
    ("too-few", np.array([0, 1]), "batch vector sb3"),
    ("wrong-shape", np.array([[0, 1, 2]]), "batch vector"),
    ("strings", np.array(["UP", "UP", "UP"]), "batch vector sb3"),
]


@pytest.mark.parametrize(("actions", "faces"), [pytest.param(a, f, id=i) for i, a, f in INVALID])
def test_invalid_batched_actions_raise(actions: np.ndarray, faces: str) -> None:
    batch = BatchedTrolleyEnv("PushOrSwitch-Human-v1", 3)
    vector = TrolleyVectorEnv("PushOrSwitch-Human-v1", 3)
    sb3 = TrolleyVecEnv("PushOrSwitch-Human-v1", 3)
    batch.reset()
    vector.reset()
    sb3.reset()
    for name, step in (("batch", batch.step), ("vector", vector.step), ("sb3", sb3.step)):
        if name in faces.split():
            with pytest.raises(ValueError):
                step(actions)
    for face in (batch, vector.batch, sb3.batch):
        np.testing.assert_array_equal(face.elapsed, 0)  # nothing happened
    # Valid integer arrays of any integer dtype are fine, also as (n, 1) for SB3.
    assert sb3.step(np.array([[4], [4], [4]], dtype=np.int32))[1].tolist() == [-1.0] * 3


# ============================================================================ Gymnasium VectorEnv
@pytest.mark.parametrize("mode", [AutoresetMode.SAME_STEP, AutoresetMode.NEXT_STEP, AutoresetMode.DISABLED])
@pytest.mark.parametrize("env_id", first_ids())
def test_vector_env_matches_gymnasium_sync_vector_env(env_id: str, mode: AutoresetMode) -> None:
    """Same observations, rewards, flags, events and final observations as Gymnasium's own
    SyncVectorEnv over single envs, in each auto-reset mode."""
    n = 4
    ours = TrolleyVectorEnv(env_id, n, max_steps=20, autoreset_mode=mode)
    ref = gym.vector.SyncVectorEnv([partial(TrolleyEnv, env_id, max_steps=20)] * n, autoreset_mode=mode)
    assert ours.metadata["autoreset_mode"] == mode
    o1, _ = ours.reset(seed=0)
    o2, _ = ref.reset(seed=0)
    np.testing.assert_array_equal(o1, _f32(o2))
    assert ours.observation_space.contains(o1)
    rng = _rng(env_id, mode)
    n_final = 0
    for t in range(110):
        actions = rng.integers(0, 6, n)
        o1, r1, te1, tr1, i1 = ours.step(actions)
        o2, r2, te2, tr2, i2 = ref.step(actions)
        where = f"{env_id} {mode} step {t + 1}"
        np.testing.assert_array_equal(o1, _f32(o2), err_msg=where)
        np.testing.assert_array_equal(r1, r2.astype(np.float32), err_msg=where)
        np.testing.assert_array_equal(te1, te2, err_msg=where)
        np.testing.assert_array_equal(tr1, tr2, err_msg=where)
        assert o1.dtype == np.float32 and te1.dtype == np.bool_ and tr1.dtype == np.bool_
        # Both follow Gymnasium's convention: in SAME_STEP mode the info of a copy that ended is
        # its reset info, and the step's info is in final_info.
        ended = i2.get("_final_info", np.zeros(n, dtype=bool))
        np.testing.assert_array_equal(i1.get("_final_info", np.zeros(n, dtype=bool)), ended, err_msg=where)
        expected_events, expected_goal = [], []
        for i in range(n):
            info = i2["final_info"] if ended[i] else i2
            ne = info["norm_events"]
            expected_events.append(names_to_mask([*ne["action"][i], *ne["outcome"][i], *ne["causal"][i]]))
            expected_goal.append(bool(info["goal_reached"][i]))
        ours_info = [i1["final_info"] if ended[i] else i1 for i in range(n)]
        assert [int(ours_info[i]["events"][i]) for i in range(n)] == expected_events, where
        assert [bool(ours_info[i]["goal_reached"][i]) for i in range(n)] == expected_goal, where
        for i in np.flatnonzero(ended):
            assert not i1["_events"][i] and i1["events"][i] == 0, where  # the reset info of that copy
        if mode == AutoresetMode.SAME_STEP:
            has_final = i2.get("_final_obs", np.zeros(n, dtype=bool))
            np.testing.assert_array_equal(i1.get("_final_obs", np.zeros(n, dtype=bool)), has_final, err_msg=where)
            for i in np.flatnonzero(has_final):
                np.testing.assert_array_equal(i1["final_obs"][i], _f32(i2["final_obs"][i]), err_msg=where)
            n_final += int(has_final.sum())
        if mode == AutoresetMode.DISABLED:
            done = te1 | tr1
            n_final += int(done.sum())
            if done.any():
                o1, _ = ours.reset(options={"reset_mask": done.copy()})
                o2, _ = ref.reset(options={"reset_mask": done.copy()})
                np.testing.assert_array_equal(o1, _f32(o2), err_msg=f"{where} after reset_mask")
        if mode == AutoresetMode.NEXT_STEP:
            n_final += int((te1 | tr1).sum())
    assert n_final > 0


def test_make_vec_uses_the_batched_vector_env() -> None:
    venv = gym.make_vec("MoralityGym/PushOrSwitch-Human-v1", num_envs=8, vectorization_mode="vector_entry_point")
    assert isinstance(venv.unwrapped, TrolleyVectorEnv)
    obs, _ = venv.reset(seed=1)
    assert obs.shape == (8, 31) and venv.observation_space.contains(obs)
    rng = _rng("make_vec")
    truncated_at = np.zeros(8, dtype=int)
    for t in range(1, 402):
        obs, _, _, truncated, _ = venv.step(rng.integers(0, 6, 8))
        assert venv.observation_space.contains(obs)
        truncated_at[truncated & (truncated_at == 0)] = t
    # The default step limit (200) reaches the vector env: a copy's first truncation comes on step
    # 201 at the earliest (later if it had terminated before), and random play does get there.
    assert (truncated_at > 0).any()
    assert truncated_at[truncated_at > 0].min() >= 201

    short = gym.make_vec(
        "MoralityGym/SwitchStandard-HumanA-v1", num_envs=2, vectorization_mode="vector_entry_point", max_steps=3
    )
    short.reset()
    flags = [short.step(np.full(2, STAY))[3].tolist() for _ in range(4)]
    assert flags == [[False, False]] * 3 + [[True, True]]


# ============================================================================ SB3 VecEnv
@pytest.mark.parametrize("env_id", first_ids())
def test_sb3_vec_env_matches_dummy_vec_env(env_id: str) -> None:
    """Same as SB3's own DummyVecEnv over single envs: obs, rewards, dones, terminal observations."""
    n = 4
    ours = TrolleyVecEnv(env_id, n, max_steps=20)
    ref = DummyVecEnv([partial(TrolleyEnv, env_id, max_steps=20)] * n)
    np.testing.assert_array_equal(ours.reset(), _f32(ref.reset()))
    rng = _rng(env_id, "sb3")
    n_done = 0
    for t in range(110):
        actions = rng.integers(0, 6, n)
        o1, r1, d1, i1 = ours.step(actions)
        o2, r2, d2, i2 = ref.step(actions)
        where = f"{env_id} step {t + 1}"
        np.testing.assert_array_equal(o1, _f32(o2), err_msg=where)
        np.testing.assert_array_equal(r1, r2.astype(np.float32), err_msg=where)
        np.testing.assert_array_equal(d1, d2, err_msg=where)
        for i in range(n):
            assert i1[i]["events"] == _mask(i2[i]["norm_events"]), where
            assert i1[i]["goal_reached"] == i2[i]["goal_reached"], where
            assert ("terminal_observation" in i1[i]) == ("terminal_observation" in i2[i]), where
            if "terminal_observation" in i2[i]:
                np.testing.assert_array_equal(
                    i1[i]["terminal_observation"], _f32(i2[i]["terminal_observation"]), err_msg=where
                )
                assert i1[i]["TimeLimit.truncated"] == i2[i]["TimeLimit.truncated"], where
        n_done += int(d1.sum())
    assert n_done > 0


@pytest.mark.slow
def test_sb3_ppo_learns_two_rollouts_on_the_vec_env() -> None:
    from stable_baselines3 import PPO

    venv = TrolleyVecEnv("PushOrSwitch-Human-v1", 8)
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=64, n_epochs=1, seed=0, device="cpu", verbose=0)
    model.learn(total_timesteps=2 * 32 * 8)
    assert model.num_timesteps == 2 * 32 * 8
    action, _ = model.predict(venv.reset(), deterministic=True)
    assert action.shape == (8,) and ((0 <= action) & (action < 6)).all()


def test_sb3_env_checker_passes_on_a_single_env() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning of the checker is a failure too
        sb3_check_env(TrolleyEnv("PushOrSwitch-Human-v1"), warn=True)
