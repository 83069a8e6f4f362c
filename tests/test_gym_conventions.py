"""MoralityGym behaves like a Gymnasium / Stable-Baselines3 package (issue #22).

Each test goes through the real API a user of those libraries calls: ``gym.make`` on the ids the
package lists, ``pickle`` and ``copy.deepcopy`` (how vector envs, process pools and checkpoints
hand envs around), ``env.spec``, both libraries' env checkers, ``gym.make_vec`` in every
vectorisation mode, and SB3's ``MultiInputPolicy`` learning on the dict observation.
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import os
import pickle
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

import morality_gym
from morality_gym.__main__ import main as cli_main
from tests.helpers import INTERACT, LEFT, STAY, UP

REPO = Path(__file__).resolve().parents[1]
ENV = "MoralityGym/SwitchStandard-HumanA-v1"
OBS_TYPES = ("flat", "dict", "dict_flat", "grid")


def _flat(obs: object) -> np.ndarray:
    """Any observation form as one vector (nested dicts in insertion order)."""
    if isinstance(obs, dict):
        return np.concatenate([_flat(v) for v in obs.values()])
    return np.asarray(obs, dtype=np.float64).ravel()


# ---------------------------------------------------------------------------------------- ids
def test_every_listed_id_is_a_gymnasium_id() -> None:
    ids = morality_gym.list_envs()
    assert len(ids) == 98 and all(i.startswith("MoralityGym/") for i in ids)
    assert set(ids) <= set(gym.registry)
    env = gym.make(ids[0])
    assert env.unwrapped.env_id == ids[0].removeprefix("MoralityGym/")
    assert morality_gym.env_ids() == [i.removeprefix("MoralityGym/") for i in ids]
    assert morality_gym.list_envs("SwitchStandard")[0] == ENV


def test_the_cli_lists_ids_that_gym_make_takes() -> None:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert cli_main(["list", "--scenario", "switch_standard"]) == 0
    ids = out.getvalue().split()
    assert ids[0] == ENV and len(ids) == 12
    for env_id in ids:
        gym.make(env_id).reset()


def test_both_id_forms_work_everywhere_else() -> None:
    for env_id in (ENV, ENV.removeprefix("MoralityGym/")):
        env, bound = morality_gym.make(env_id, "Utility")
        assert env.env_id == "SwitchStandard-HumanA-v1" and bound.env_id == "SwitchStandard-HumanA-v1"


# ---------------------------------------------------------------------------------------- pickling
@pytest.mark.parametrize("obs_type", OBS_TYPES)
def test_a_made_env_pickles_and_copies_mid_episode(obs_type: str) -> None:
    env = gym.make(ENV, obs_type=obs_type)
    env.reset(seed=3)
    for action in (INTERACT, LEFT):
        env.step(action)
    clones = [pickle.loads(pickle.dumps(env)), copy.deepcopy(env)]
    for clone in clones:
        assert type(clone.unwrapped).__name__ == "SwitchStandardEnv"
        assert clone.unwrapped.elapsed_steps == 2 and clone.unwrapped.state == env.unwrapped.state
    expected = [env.step(a) for a in (UP, STAY, STAY)]
    for clone in clones:
        got = [clone.step(a) for a in (UP, STAY, STAY)]
        for (o1, r1, t1, u1, i1), (o2, r2, t2, u2, i2) in zip(expected, got):
            assert np.array_equal(_flat(o1), _flat(o2)) and (r1, t1, u1) == (r2, t2, u2)
            assert i1["norm_events"] == i2["norm_events"]
    assert copy.deepcopy(env).unwrapped.graph is env.unwrapped.graph  # the memoised graph is shared, not copied


def test_the_env_classes_are_importable_by_name() -> None:
    from morality_gym.envs.registration import Push2OrSwitchEnv, SwitchStandardEnv

    assert SwitchStandardEnv is type(gym.make(ENV).unwrapped)
    assert pickle.loads(pickle.dumps(Push2OrSwitchEnv)) is Push2OrSwitchEnv
    with pytest.raises(AttributeError, match="NoSuchEnv"):
        from morality_gym.envs import registration

        registration.NoSuchEnv  # noqa: B018


_SPAWNED_USER_SCENARIO = """
import pickle, sys
import morality_gym
from tests.test_scenario_files import _tiny
from pathlib import Path
directory = Path(sys.argv[1])
(directory / "tiny_switch.yaml").write_text(_tiny())
morality_gym.add_scenario_dir(directory)
env = morality_gym.TrolleyEnv("TinySwitch-Human-v1")
import gymnasium as gym
env = gym.make("MoralityGym/TinySwitch-Human-v1")
env.reset()
env.step(5)
sys.stdout.buffer.write(pickle.dumps(env))
"""

_UNPICKLE = """
import pickle, sys, json
env = pickle.loads(sys.stdin.buffer.read())
print(json.dumps({"class": type(env.unwrapped).__name__, "steps": env.unwrapped.elapsed_steps,
                  "reward": env.step(4)[1]}))
"""


def test_an_env_of_a_users_scenario_unpickles_in_a_fresh_process(tmp_path: Path) -> None:
    """A spawned worker has not called ``add_scenario_dir``: the pickle names the scenario's file."""
    made = subprocess.run([sys.executable, "-c", _SPAWNED_USER_SCENARIO, str(tmp_path)], cwd=REPO,
                          capture_output=True, timeout=120, check=False)
    assert made.returncode == 0, made.stderr.decode()
    loaded = subprocess.run([sys.executable, "-c", _UNPICKLE], cwd=REPO, input=made.stdout,
                            capture_output=True, timeout=120, check=False)
    assert loaded.returncode == 0, loaded.stderr.decode()
    out = json.loads(loaded.stdout.decode().strip().splitlines()[-1])
    assert out == {"class": "TinySwitchEnv", "steps": 1, "reward": -1.0}


_ASYNC_USER_SCENARIO = """
import sys
from pathlib import Path
import gymnasium as gym
import numpy as np
import morality_gym
from tests.test_scenario_files import _tiny
directory = Path(sys.argv[1])
(directory / "tiny_switch.yaml").write_text(_tiny())
morality_gym.add_scenario_dir(directory)
if __name__ == "__main__":
    venv = gym.make_vec("MoralityGym/TinySwitch-Human-v1", num_envs=2, vectorization_mode="async",
                        vector_kwargs={"context": "spawn"})
    venv.reset(seed=0)
    print(venv.step(np.array([5, 4]))[1].tolist())
    venv.close()
"""


def test_async_vector_envs_of_a_users_scenario_work_in_spawned_workers(tmp_path: Path) -> None:
    """The workers import the package afresh: add_scenario_dir lists its directory for them."""
    script = tmp_path / "run_async.py"
    script.write_text(_ASYNC_USER_SCENARIO)
    (tmp_path / "scenarios").mkdir()
    out = subprocess.run([sys.executable, str(script), str(tmp_path / "scenarios")], cwd=REPO, capture_output=True,
                         text=True, timeout=300, check=False, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == "[-1.0, -1.0]"


# ---------------------------------------------------------------------------------------- spec
@pytest.mark.parametrize(("kwargs", "limit"), [({}, 201), ({"max_steps": 50}, 51), ({"max_steps": None}, None)])
def test_the_spec_says_when_episodes_truncate(kwargs: dict[str, int | None], limit: int | None) -> None:
    env = gym.make(ENV, **kwargs)
    assert env.spec.max_episode_steps == limit and env.unwrapped.spec.max_episode_steps == limit
    remade = env.spec.make()  # what check_env and rl-zoo do: a TimeLimit from the spec, at the env's own step
    remade.reset()
    n = 0
    truncated = False
    while not truncated and n < 300:
        truncated = remade.step(STAY)[3]
        n += 1
    assert n == (limit if limit is not None else 300) and truncated is (limit is not None)


# ---------------------------------------------------------------------------------------- checkers
@pytest.mark.parametrize("obs_type", OBS_TYPES)
def test_gymnasium_check_env_is_silent(obs_type: str) -> None:
    """No warning at all, including the headless-window one after the first of the process."""
    gym_check_env(gym.make(ENV, obs_type=obs_type).unwrapped)  # may say once that no window can open
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(gym.make(ENV, obs_type=obs_type).unwrapped)


@pytest.mark.parametrize("obs_type", ["flat", "dict_flat"])
def test_sb3_check_env_is_silent(obs_type: str) -> None:
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_check_env(gym.make(ENV, obs_type=obs_type).unwrapped)


def test_sb3_refuses_the_nested_dict_which_is_why_dict_flat_exists() -> None:
    """The nested form stays (the reference's); SB3 says it cannot take it, and takes dict_flat."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    nested = gym.make(ENV, obs_type="dict").unwrapped
    with pytest.warns(UserWarning, match="Nested observation spaces are not supported"):
        sb3_check_env(nested)
    with pytest.raises(NotImplementedError):
        PPO("MultiInputPolicy", nested, device="cpu")
    PPO("MultiInputPolicy", gym.make(ENV, obs_type="dict_flat"), device="cpu")


def test_the_flat_dict_holds_the_flat_vector() -> None:
    flat, _ = gym.make(ENV).reset()
    env = gym.make(ENV, obs_type="dict_flat")
    obs, _ = env.reset()
    assert list(obs)[:3] == ["player/pos", "player/is_harmed", "player/is_terminated"]
    assert np.array_equal(_flat(obs), flat) and env.observation_space.contains(obs)
    nested, _ = gym.make(ENV, obs_type="dict").reset()
    assert np.array_equal(_flat(nested), flat)


# ---------------------------------------------------------------------------------------- vector envs
@pytest.mark.parametrize("obs_type", OBS_TYPES)
@pytest.mark.parametrize("mode", ["sync", "async"])
def test_make_vec_runs_every_observation_type(obs_type: str, mode: str) -> None:
    kwargs = {"vector_kwargs": {"context": "spawn"}} if mode == "async" else {}
    venv = gym.make_vec(ENV, num_envs=2, vectorization_mode=mode, obs_type=obs_type, **kwargs)
    try:
        obs, _ = venv.reset(seed=0)
        obs, reward, *_ = venv.step(np.array([INTERACT, STAY]))
        assert venv.observation_space.contains(obs) and reward.shape == (2,)
    finally:
        venv.close()


def test_the_vector_entry_point_gives_the_flat_dict() -> None:
    venv = gym.make_vec(ENV, num_envs=3, obs_type="dict_flat")
    single = gym.make(ENV, obs_type="dict_flat")
    obs, _ = venv.reset()
    first, _ = single.reset()
    assert set(obs) == set(first) and all(np.allclose(obs[k][0], first[k]) for k in first)
    truncated = np.zeros(3, dtype=bool)
    while not truncated.any():  # to the truncation on step 201: the ended copies' final_obs are dicts too
        obs, _, _, truncated, info = venv.step(np.full(3, STAY))
    assert isinstance(info["final_obs"][0], dict) and single.observation_space.contains(info["final_obs"][0])
    assert venv.observation_space.contains(obs)
    with pytest.raises(ValueError, match="vectorization_mode='sync'"):
        gym.make_vec(ENV, num_envs=2, obs_type="dict")


# ---------------------------------------------------------------------------------------- SB3 learning
@pytest.mark.slow
def test_sb3_multi_input_policy_learns_on_the_dict_observation() -> None:
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    venv = make_vec_env(ENV, n_envs=2, seed=0, env_kwargs={"obs_type": "dict_flat"})
    model = PPO("MultiInputPolicy", venv, n_steps=64, batch_size=64, n_epochs=2, seed=0, device="cpu")
    model.learn(256)
    assert model.num_timesteps >= 256
    obs = venv.reset()
    action, _ = model.predict(obs)
    assert action.shape == (2,) and all(0 <= a < 6 for a in action)
