"""Every tensor the fleet makes names its device, checked on a machine without a GPU.

CI has no GPU, so nothing there runs ``device=cuda``; the first GPU run of the fleet crashed on a
scalar made without a device (``th.ones(())`` in the tanh backward pass, a CPU tensor that CUDA's
``addcmul`` refuses). Here the fleet trains with torch's *default* device set to ``"meta"``: a tensor
created without naming its device then lands on the meta device, and the first operation that mixes
it with the fleet's CPU tensors fails, exactly where the same line would put a CPU tensor into a CUDA
computation. The runs' sampling streams are drawn on the CPU on purpose (their generators live there,
so the draws are the single runs' bits); that code says ``device="cpu"`` and passes.

Each learner and protocol runs with learn-time evaluations and a checkpoint written and restored,
and truncated episodes (bootstrapped with the critics), so the rarer paths are exercised too.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th

import morality_gym
from morality_gym.baselines.fleet import FleetCheckpoint, FleetRun, build_fleet
from morality_gym.baselines.fleet.env import DeviceFleetEnv, FleetEnv
from morality_gym.baselines.specs import learner_spec

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tests/conftest.py

SMALL = {
    "ppo": {"n_steps": 32, "n_epochs": 2},
    "ppo_shaped": {"n_steps": 32, "n_epochs": 2},
    "ppo_lag": {"n_steps": 32, "n_epochs": 2},
    "cpo": {"n_steps": 32, "n_critic_updates": 2},
}
CASES = [
    ("ppo", "paper"),
    ("ppo_shaped", "paper"),
    ("ppo_lag", "paper"),
    ("ppo_lag", "corrected"),
    ("cpo", "paper"),
    ("cpo", "corrected"),
]
ROLLOUT = 32 * 8


def _runs() -> list[FleetRun]:
    return [
        FleetRun(morality_gym.bind_chain("DualProcess", "PushOrSwitch-Human-v1"), 1),
        FleetRun(morality_gym.bind_chain("Utility", "PushOrSwitch-Animal-v1"), 2),
    ]


def test_the_meta_default_device_catches_a_tensor_made_without_a_device() -> None:
    """The check itself can fail: the line that crashed the first GPU run fails here on the CPU."""
    h = th.rand(2, 3)
    with th.device("meta"), pytest.raises((RuntimeError, NotImplementedError, AssertionError)):
        th.addcmul(th.ones((), dtype=h.dtype), h, h, value=-1.0).numpy()
    with th.device("meta"):  # the fixed line names its device (h's)
        assert th.addcmul(h.new_ones(()), h, h, value=-1.0).device.type == "cpu"


@pytest.mark.parametrize(("name", "protocol"), CASES)
def test_a_fleet_learns_with_the_default_device_set_to_meta(name: str, protocol: str, tmp_path: Path) -> None:
    spec = learner_spec(name, {"hparams": SMALL[name]})
    # built outside: SB3 builds its single-run learners (which the fleet starts from) on the default device
    fleet, resumed = build_fleet(spec, _runs(), protocol), build_fleet(spec, _runs(), protocol)
    with th.device("meta"):
        steps = fleet.learn(2 * ROLLOUT, eval_every=ROLLOUT, eval_episodes=2, checkpoint=FleetCheckpoint(tmp_path / "f.pt", every_s=0))
        assert steps == 2 * ROLLOUT
        resumed.learn(2 * ROLLOUT, eval_every=ROLLOUT, eval_episodes=2, checkpoint=FleetCheckpoint(tmp_path / "f.pt", every_s=0))
    for a, b in zip(fleet.learners(), resumed.learners()):
        for pa, pb in zip(a.model.policy.parameters(), b.model.policy.parameters()):
            assert pa.device.type == "cpu"
            np.testing.assert_array_equal(pa.detach().numpy(), pb.detach().numpy())


@pytest.mark.parametrize("simulator", ["host", "device"])
@pytest.mark.parametrize(("name", "protocol"), [("ppo", "paper"), ("ppo_lag", "corrected"), ("cpo", "corrected")])
def test_truncated_episodes_bootstrap_with_the_default_device_set_to_meta(name: str, protocol: str, simulator: str) -> None:
    """max_steps=6 truncates episodes, so the critics' bootstrap of rewards and costs runs too; the
    device simulator and the every-step bootstrap are what a GPU fleet runs."""
    fleet = build_fleet(learner_spec(name, {"hparams": SMALL[name]}), _runs(), protocol, max_steps=6, simulator=simulator)  # type: ignore[arg-type]
    fleet.collector.dense_bootstrap = simulator == "device"
    with th.device("meta"):
        assert fleet.learn(2 * ROLLOUT) == 2 * ROLLOUT


@pytest.mark.parametrize(("name", "protocol"), CASES)
def test_the_device_simulator_and_dense_bootstrap_train_the_host_simulators_bits(name: str, protocol: str) -> None:
    """What a GPU fleet runs, run on the CPU: the simulator, cost and reward on the device
    (:class:`DeviceFleetEnv`) and the truncation bootstrap computed in every step (no host sync).
    Truncated episodes (max_steps=9) and three rollouts; the runs end at the host engine's bits."""
    spec = learner_spec(name, {"hparams": SMALL[name]})
    host = build_fleet(spec, _runs(), protocol, max_steps=9, simulator="host")
    device = build_fleet(spec, _runs(), protocol, max_steps=9, simulator="device")
    device.collector.dense_bootstrap = True
    assert type(device.collector.env) is DeviceFleetEnv and type(host.collector.env) is FleetEnv
    host.learn(3 * ROLLOUT)
    device.learn(3 * ROLLOUT)
    for a, b in zip(host.learners(), device.learners()):
        for pa, pb in zip(a.model.policy.parameters(), b.model.policy.parameters()):
            np.testing.assert_array_equal(pa.detach().numpy(), pb.detach().numpy())
        assert str(a.update_diagnostics()) == str(b.update_diagnostics())
    np.testing.assert_array_equal(host.mean_episode_costs(), device.mean_episode_costs())


def test_auto_picks_the_host_simulator_on_the_cpu_and_refuses_unknown_ones() -> None:
    fleet = build_fleet(learner_spec("ppo", {"hparams": SMALL["ppo"]}), _runs(), "paper")
    assert fleet.collector.env.name == "host" and fleet.checkpoint_key()["simulator"] == "host"
    with pytest.raises(ValueError, match="simulator='gpu'"):
        build_fleet(learner_spec("ppo", {"hparams": SMALL["ppo"]}), _runs(), "paper", simulator="gpu")  # type: ignore[arg-type]
