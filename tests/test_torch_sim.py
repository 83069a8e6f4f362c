"""The simulator and the step-wise cost on a torch device take the host's transitions, bit for bit.

Run with torch on the CPU (CI has no GPU): the tensors, gathers and float64 cost arithmetic are the
device code's; only the device differs on a GPU. All 98 registered envs step in *one* simulator
(observations padded to the widest), with random actions, truncation and auto-reset, and each copy is
compared with the host simulator of its own env id. The cost of every built-in chain on every env it
binds to is compared with the host's :class:`StackedCost` under both reset policies and all modes.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

import morality_gym
from morality_gym.envs.batched import BatchedTrolleyEnv
from morality_gym.envs.mixed import MixedBatchedTrolleyEnv
from morality_gym.envs.torch_sim import TorchStep, TorchTrolleySim
from morality_gym.norms.cost import StackedCost, VectorCost
from morality_gym.norms.reward_cost import RewardCostSpec
from tests.helpers import bound_pairs

COPIES = 3
STEPS = 120
#: The device code on the CPU everywhere; on a GPU too wherever torch sees one (benchmarks/gpu_check.sh).
DEVICES = ["cpu", *(["cuda"] if th.cuda.is_available() else [])]


def _actions(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.integers(0, 6, size=n).astype(np.int64)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("max_steps", [7, 50])
def test_all_98_envs_in_one_device_simulator_step_as_the_host_simulator(max_steps: int, device: str) -> None:
    ids = morality_gym.env_ids()
    assert len(ids) == 98
    copies = [e for e in ids for _ in range(COPIES)]
    sim = TorchTrolleySim(copies, device, max_steps=max_steps)
    hosts = [BatchedTrolleyEnv(e, COPIES, max_steps=max_steps) for e in ids]
    rng = np.random.default_rng(0)
    obs = sim.reset().cpu().numpy()
    for h, e in enumerate(hosts):
        np.testing.assert_array_equal(obs[h * COPIES : (h + 1) * COPIES, : e.obs_dim], e.reset())
    for _ in range(STEPS):
        act = _actions(rng, len(copies))
        got = TorchStep(*(t.cpu() for t in sim.step(th.from_numpy(act).to(device))))
        utility = sim.utility(got.transition.to(device)).cpu().numpy()
        goal = sim.goal_reached(got.transition.to(device)).cpu().numpy()
        for h, env in enumerate(hosts):
            rows = slice(h * COPIES, (h + 1) * COPIES)
            want = env.step(act[rows])
            d = env.obs_dim
            np.testing.assert_array_equal(got.obs[rows, :d].numpy(), want.obs, err_msg=env.env_id)
            assert not got.obs[rows, d:].any(), "padding stays zero"
            np.testing.assert_array_equal(got.reward[rows].numpy(), want.reward)
            np.testing.assert_array_equal(got.terminated[rows].numpy(), want.terminated)
            np.testing.assert_array_equal(got.truncated[rows].numpy(), want.truncated)
            np.testing.assert_array_equal(got.events[rows].numpy(), want.events.astype(np.int64))
            np.testing.assert_array_equal(utility[rows], env.utility(want.transition).astype(np.float64))
            np.testing.assert_array_equal(goal[rows], env.goal_reached(want.transition))
            final = np.zeros_like(want.obs) if want.final_obs is None else want.final_obs
            np.testing.assert_array_equal(got.final_obs[rows, :d].numpy(), final)


@pytest.mark.parametrize("obs_type", ["compact", "grid"])
def test_the_device_simulator_steps_the_host_tables_of_every_observation_type(obs_type: str, tmp_path) -> None:
    """The device simulator's tables are the host's (one layout, :func:`~morality_gym.envs.batched.lay_out`),
    so it offers the host's observation types and table cache too: a mixture of scenarios with
    compact or grid rows, its tables read back from the cache, steps as the host mixture does."""
    ids = ["SwitchStandard-HumanA-v1", "PushOrSwitch-Human-v1", "Switch7-Human-v1"]
    copies = [e for e in ids for _ in range(COPIES)]
    host = MixedBatchedTrolleyEnv(copies, obs_type=obs_type)
    for cache in (tmp_path, tmp_path):  # the second build reads the entries the first wrote (compact only)
        sim = TorchTrolleySim(copies, "cpu", obs_type=obs_type, table_cache=cache)
        assert sim.obs_dim == host.obs_dim
    np.testing.assert_array_equal(sim.reset().numpy(), host.reset())
    rng = np.random.default_rng(1)
    for _ in range(60):
        act = _actions(rng, len(copies))
        got, want = sim.step(th.from_numpy(act)), host.step(act)
        np.testing.assert_array_equal(got.obs.numpy(), want.obs)
        np.testing.assert_array_equal(got.reward.numpy(), want.reward)
        np.testing.assert_array_equal((got.terminated | got.truncated).numpy(), want.terminated | want.truncated)


def test_reset_of_some_copies_and_state_round_trip() -> None:
    sim = TorchTrolleySim(["SwitchStandard-HumanA-v1", "PushOrSwitch-Human-v1"], "cpu")
    sim.reset()
    for _ in range(3):
        sim.step(th.tensor([3, 1]))
    saved = sim.state_dict()
    after = sim.step(th.tensor([5, 0])).obs.clone()
    sim.load_state_dict(saved)
    assert th.equal(sim.step(th.tensor([5, 0])).obs, after)
    start = TorchTrolleySim(["SwitchStandard-HumanA-v1", "PushOrSwitch-Human-v1"], "cpu").reset()
    obs = sim.reset(th.tensor([False, True]))
    assert th.equal(obs[1], start[1]) and int(sim.elapsed[0]) > 0 and int(sim.elapsed[1]) == 0
    with pytest.raises(ValueError, match="expected shape"):
        sim.load_state_dict({"state": th.zeros(3, dtype=th.int64), "elapsed": th.zeros(3, dtype=th.int64)})


def test_bad_arguments_are_refused_with_one_line() -> None:
    with pytest.raises(ValueError, match="non-empty list"):
        TorchTrolleySim("SwitchStandard-HumanA-v1")
    with pytest.raises(ValueError, match="narrower than the widest"):
        TorchTrolleySim(["SwitchStandard-HumanA-v1"], obs_dim=1)
    with pytest.raises(morality_gym.UnknownEnvError, match="SwitchStandard"):
        TorchTrolleySim(["SwitchStandrd-HumanA-v1"])


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize(("mode", "reset"), [("minimal", "never"), ("full", "per_episode"), ("partial", "per_episode")])
def test_the_device_cost_of_every_builtin_chain_matches_the_host_cost(mode: str, reset: str, device: str) -> None:
    bounds = bound_pairs()
    assert len({b.chain.name for b in bounds}) >= 4 and len(bounds) >= 98
    spec = RewardCostSpec(cost_mode=mode, cost_reset=reset, cost_scale=2.0)  # type: ignore[arg-type]
    sim = TorchTrolleySim([b.env_id for b in bounds], device, max_steps=30)
    device_cost = StackedCost.for_copies(bounds, spec, device)
    groups = [
        (np.array([i]), VectorCost(b, 1, mode=spec.cost_mode, scale=spec.cost_scale, reset=spec.cost_reset))
        for i, b in enumerate(bounds)
    ]
    host_cost = StackedCost.of_groups(groups, len(bounds))
    assert host_cost is not None
    rng = np.random.default_rng(1)
    sim.reset()
    nonzero = 0
    for _ in range(80):
        step = sim.step(th.from_numpy(_actions(rng, len(bounds))).to(device))
        ended = step.terminated | step.truncated
        utility = sim.utility(step.transition)
        got = device_cost(step.events, utility, ended)
        want = host_cost(step.events.cpu().numpy().astype(np.uint32), utility.cpu().numpy(), ended.cpu().numpy())
        np.testing.assert_array_equal(got.cpu().numpy(), want)
        nonzero += int((want != 0).sum())
    assert nonzero > 50  # the comparison saw real costs
    np.testing.assert_array_equal(device_cost.state_dict()["charged"].numpy(), host_cost.charged.astype(np.int64))
