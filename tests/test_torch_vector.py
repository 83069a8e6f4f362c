"""The public device vector env and its cost wrapper against the host simulator, the Gymnasium
vector API, the action check and the meta default device.

Run with torch on the CPU (CI has no GPU). The host reference is the numpy Gymnasium
:class:`~morality_gym.envs.vector.TrolleyVectorEnv` (one per env id: it holds one id) and the host
:class:`~morality_gym.norms.cost.VectorCost` per (env id, chain) block; the device env holds every
block at once, observations padded to the widest id, and must give the same values, bit for bit.
"""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium.vector import AutoresetMode

import morality_gym
from morality_gym.envs.torch_vector import TorchTrolleyVectorEnv
from morality_gym.envs.trolley import InvalidActionError
from morality_gym.envs.vector import TrolleyVectorEnv
from morality_gym.norms.cost import VectorCost
from morality_gym.norms.reward_cost import RewardCostSpec
from morality_gym.norms.torch_vector_cost import TorchCostWrapper
from morality_gym.world.vocab import EVENT_BIT

#: Blocks of (env id, chain): five scenarios of three observation widths (22, 24, 31, 48), one id
#: twice under two chains, event and utility norms.
BLOCKS = [
    ("SwitchStandard-HumanA-v1", "Utility"),
    ("PushOrSwitch-Human-v1", "DualProcess"),
    ("Switch5-Human-v1", "Outcome"),
    ("PushStandard-HumanA-v1", "DualProcessAgentHarm"),
    ("PushOrSwitch-Human-v1", "UtilityAgentHarm"),
    ("SwitchStandard-AnimalB-v1", "OutcomeAgentHarm"),
]
COPIES = 4


def _host_merged(host: TrolleyVectorEnv, infos: dict[str, Any], key: str) -> np.ndarray:
    """A step's ``key`` for every copy of the host env: Gymnasium's same-step convention moves an
    ended copy's step info to ``final_info``; the device env keeps it at top level."""
    if "final_info" not in infos:
        return infos[key]
    return np.where(infos["_final_info"], infos["final_info"][key], infos[key])


@pytest.mark.parametrize(("max_steps", "reset"), [(9, "per_episode"), (60, "never")])
def test_a_mixed_device_env_with_costs_steps_as_the_host_envs(max_steps: int, reset: str) -> None:
    spec = RewardCostSpec(cost_reset=reset, cost_scale=3.0)  # type: ignore[arg-type]
    env = TorchTrolleyVectorEnv([e for e, _ in BLOCKS], copies_per_env=COPIES, max_steps=max_steps)
    wrapped = TorchCostWrapper(env, [c for _, c in BLOCKS], reward_cost=spec)
    hosts = [TrolleyVectorEnv(e, COPIES, max_steps=max_steps) for e, _ in BLOCKS]
    costs = [VectorCost(morality_gym.bind_chain(c, e), COPIES, mode=spec.cost_mode, scale=spec.cost_scale, reset=reset)
             for e, c in BLOCKS]
    obs, _ = wrapped.reset(seed=0)
    for b, host in enumerate(hosts):
        np.testing.assert_array_equal(obs[b * COPIES : (b + 1) * COPIES, : host.batch.obs_dim].numpy(), host.reset(seed=0)[0])
    rng = np.random.default_rng(7)
    seen = {"ended": 0, "truncated": 0, "cost": 0, "events": 0}
    for _ in range(150):
        actions = rng.integers(0, 6, size=env.num_envs)
        obs, reward, terminated, truncated, infos = wrapped.step(th.from_numpy(actions))
        for b, host in enumerate(hosts):
            rows = slice(b * COPIES, (b + 1) * COPIES)
            h_obs, h_reward, h_term, h_trunc, h_infos = host.step(actions[rows])
            d = host.batch.obs_dim
            where = BLOCKS[b]
            np.testing.assert_array_equal(obs[rows, :d].numpy(), h_obs, err_msg=str(where))
            assert not obs[rows, d:].any(), "padding stays zero"
            np.testing.assert_array_equal(reward[rows].numpy(), h_reward, err_msg=str(where))
            np.testing.assert_array_equal(terminated[rows].numpy(), h_term)
            np.testing.assert_array_equal(truncated[rows].numpy(), h_trunc)
            events = _host_merged(host, h_infos, "events")
            np.testing.assert_array_equal(infos["events"][rows].numpy(), events.astype(np.int64))
            np.testing.assert_array_equal(infos["goal_reached"][rows].numpy(), _host_merged(host, h_infos, "goal_reached"))
            ended = h_term | h_trunc
            np.testing.assert_array_equal(infos["_final_obs"][rows].numpy(), ended)
            final = infos["final_obs"][rows].numpy()
            for i in range(COPIES):
                want = h_infos["final_obs"][i] if ended[i] else np.zeros(d, dtype=np.float32)
                np.testing.assert_array_equal(final[i, :d], want)
            utility = host.batch.utility(_host_merged(host, h_infos, "transition"))
            np.testing.assert_array_equal(infos["cost"][rows].numpy(), costs[b](events, utility, ended), err_msg=str(where))
            seen["ended"] += int(ended.sum())
            seen["truncated"] += int(h_trunc.sum())
            seen["cost"] += int((infos["cost"][rows] != 0).sum())
            seen["events"] += int((events != 0).sum())
    assert all(v > 10 for v in seen.values()), seen  # the comparison saw endings, truncations, costs and events


def test_one_chain_per_copy_and_bound_chains_are_taken() -> None:
    env = TorchTrolleyVectorEnv(["SwitchStandard-HumanA-v1", "PushOrSwitch-Human-v1"], copies_per_env=2)
    per_copy = ["Utility", "Outcome", morality_gym.bind_chain("DualProcess", "PushOrSwitch-Human-v1"), "Utility"]
    wrapped = TorchCostWrapper(env, per_copy)
    assert [b.chain.name for b in wrapped.bounds] == ["Utility", "Outcome", "DualProcess", "Utility"]
    assert [b.env_id for b in wrapped.bounds] == env.env_ids
    assert [b.chain.name for b in TorchCostWrapper(env, "Outcome").bounds] == ["Outcome"] * 4
    with pytest.raises(ValueError, match="one per block \\(2\\) or one per copy \\(4\\), not 3"):
        TorchCostWrapper(env, ["Utility"] * 3)
    with pytest.raises(ValueError, match="BoundChain of SwitchStandard-HumanA-v1 was given for a copy of PushOrSwitch"):
        TorchCostWrapper(env, [morality_gym.bind_chain("Utility", "SwitchStandard-HumanA-v1")] * 2)
    with pytest.raises(TypeError, match="needs a TorchTrolleyVectorEnv"):
        TorchCostWrapper(TrolleyVectorEnv("SwitchStandard-HumanA-v1", 2), "Utility")  # type: ignore[arg-type]


def test_the_gymnasium_vector_api_spaces_seeds_and_same_step_autoreset() -> None:
    env = TorchTrolleyVectorEnv(["Switch5-Human-v1", "PushStandard-HumanA-v1"], copies_per_env=3, max_steps=4)
    assert env.num_envs == 6 and env.obs_dim == 48 and env.obs_dims["PushStandard-HumanA-v1"] == 22
    assert env.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert env.observation_space.shape == (6, 48) and env.action_space.shape == (6,)
    assert env.single_action_space == gym.spaces.Discrete(6)
    start, infos = env.reset(seed=5)
    assert infos == {} and start.dtype == th.float32 and start.device.type == "cpu"
    sampled = env.action_space.sample()
    again, _ = env.reset(seed=5)
    np.testing.assert_array_equal(env.action_space.sample(), sampled)  # reset(seed) seeds the action space
    assert th.equal(again, start)  # the worlds are deterministic: the seed does not change the start
    for step in range(1, 6):
        obs, reward, terminated, truncated, infos = env.step(env.action_space.sample())  # numpy actions are taken
        for row in obs.numpy():
            assert env.single_observation_space.contains(row)
        assert reward.dtype == th.float32 and terminated.dtype == th.bool and infos["events"].dtype == th.int64
        if step == 5:  # max_steps=4: every copy still running is truncated on step 5, and reset in the same step
            ended = terminated | truncated
            assert bool(truncated.any()) and bool(ended.all())
            assert th.equal(obs, start)
            assert th.equal(infos["_final_obs"], ended) and bool((infos["final_obs"] != 0).any(dim=1).all())
    env.step(th.full((6,), 3))
    obs, _ = env.reset(options={"reset_mask": np.array([True, False, False, False, False, True])})
    assert th.equal(obs[[0, 5]], start[[0, 5]])
    with pytest.raises(ValueError, match="SAME_STEP"):
        TorchTrolleyVectorEnv("Switch5-Human-v1", autoreset_mode=AutoresetMode.NEXT_STEP)


def test_make_vec_gives_the_device_env_when_a_device_is_named() -> None:
    venv = gym.make_vec("MoralityGym/PushOrSwitch-Human-v1", num_envs=5, device="cpu", max_steps=7)
    assert isinstance(venv, TorchTrolleyVectorEnv) and venv.num_envs == 5 and venv.sim.max_steps == 7
    assert venv.env_ids == ["PushOrSwitch-Human-v1"] * 5
    assert isinstance(gym.make_vec("MoralityGym/PushOrSwitch-Human-v1", num_envs=2), TrolleyVectorEnv)


def test_a_bad_action_is_refused_naming_the_copy_and_its_env() -> None:
    env = TorchTrolleyVectorEnv(["SwitchStandard-HumanA-v1", "PushOrSwitch-Human-v1"], copies_per_env=2)
    env.reset()
    with pytest.raises(InvalidActionError, match=r"action 7 of copy 2 \(PushOrSwitch-Human-v1\) is not an action"):
        env.step(th.tensor([0, 1, 7, -1]))
    with pytest.raises(InvalidActionError, match=r"action -1 of copy 0 \(SwitchStandard-HumanA-v1\)"):
        env.step([-1, 0, 0, 0])
    with pytest.raises(InvalidActionError, match="integers 0..5, got dtype torch.float32"):
        env.step(th.tensor([0.0, 1.0, 2.0, 3.0]))
    with pytest.raises(InvalidActionError, match=r"expected 4 actions \(one per copy\), got shape \(3,\)"):
        env.step(th.tensor([0, 1, 2]))
    env.step(th.tensor([[0], [1], [2], [5]]))  # a policy's (n, 1) sample is taken


def test_unchecked_actions_step_as_checked_ones() -> None:
    ids = ["SwitchStandard-HumanA-v1", "PushOrSwitch-Human-v1"]
    checked, unchecked = TorchTrolleyVectorEnv(ids, 3), TorchTrolleyVectorEnv(ids, 3, check_actions=False)
    checked.reset()
    unchecked.reset()
    gen = th.Generator().manual_seed(0)
    for _ in range(40):
        actions = th.randint(0, 6, (6,), generator=gen)
        for a, b in zip(checked.step(actions)[:4], unchecked.step(actions)[:4]):
            assert th.equal(a, b)


def test_the_meta_default_device_catches_nothing_in_the_vector_env_and_its_cost() -> None:
    """Every tensor the env and the wrapper make names its device: with torch's default device set to
    ``"meta"``, a tensor made without one would land there and the next operation that mixes it with
    the env's CPU tensors would fail, as a CPU tensor would in a CUDA computation."""
    with th.device("meta"):
        assert th.zeros(1).device.type == "meta"  # the check is live: an unnamed tensor goes to meta
        env = TorchTrolleyVectorEnv([e for e, _ in BLOCKS], copies_per_env=2, device="cpu", max_steps=5)
        wrapped = TorchCostWrapper(env, [c for _, c in BLOCKS], reward_cost=RewardCostSpec(cost_reset="per_episode"))
        wrapped.reset(seed=0)
        gen = th.Generator(device="cpu").manual_seed(0)
        outputs: list[th.Tensor] = []
        costs, ended = th.zeros(env.num_envs, dtype=th.float64, device="cpu"), th.zeros(env.num_envs, dtype=th.bool, device="cpu")
        for i in range(12):
            actions = th.randint(0, 6, (env.num_envs,), generator=gen, device="cpu")
            obs, reward, terminated, truncated, infos = wrapped.step(actions if i % 2 else actions.numpy())
            outputs += [obs, reward, terminated, truncated, *(v for v in infos.values() if isinstance(v, th.Tensor))]
            costs, ended = costs + infos["cost"].abs(), ended | terminated | truncated
        wrapped.reset(options={"reset_mask": np.arange(env.num_envs) % 2 == 0})
        outputs += [env.utility(infos["transition"]), env.copy_env_index()]
    assert {t.device.type for t in outputs} == {"cpu"}
    assert bool(ended.all()) and bool((costs > 0).any())  # the auto-reset and cost paths ran


def test_events_are_bit_masks_over_the_vocabulary() -> None:
    env = TorchTrolleyVectorEnv("SwitchStandard-HumanA-v1", 1)
    env.reset()
    harmed = th.zeros(1, dtype=th.bool)
    for _ in range(30):  # STAY: the trolley runs over the group on the main line
        _, _, terminated, _, infos = env.step(th.tensor([4]))
        harmed |= ((infos["events"] >> EVENT_BIT["human_harm"]) & 1).bool()
        if bool(terminated[0]):
            break
    assert bool(harmed[0])


def test_import_morality_gym_does_not_load_torch_and_the_lazy_names_resolve() -> None:
    code = (
        "import sys, morality_gym; assert 'torch' not in sys.modules, 'import morality_gym loaded torch'; "
        "assert morality_gym.TorchTrolleyVectorEnv.__name__ == 'TorchTrolleyVectorEnv'; "
        "assert morality_gym.TorchCostWrapper.__name__ == 'TorchCostWrapper'; print('ok')"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr
