"""A fleet may mix scenarios, and no run's numbers depend on which runs share its fleet, bit for bit.

Runs of different scenarios observe vectors of different widths (22 to 63 here). The fleet pads
every observation with zeros to the widest and gives each run's first layers zero weights beyond
its own width; its zero inputs there keep those weights' gradients, moments and values at exactly 0.
What makes it bit for bit: the batched products give the same bits with a zero-padded inner
dimension (checked here, on every learner's whole training), and every sum over a run's parameters
(gradient norms for clipping, CPO's dot products and norms) runs over the run's own columns, laid
out as in a fleet of its scenario alone.
"""

from __future__ import annotations

import numpy as np
import pytest

import morality_gym
from morality_gym.baselines.fleet import FleetRun, build_fleet
from morality_gym.baselines.specs import learner_spec

SMALL = {
    "ppo": {"n_steps": 32, "n_epochs": 2},
    "ppo_shaped": {"n_steps": 32, "n_epochs": 2},
    "ppo_lag": {"n_steps": 32, "n_epochs": 3},
    "cpo": {"n_steps": 32, "n_critic_updates": 2},
}
CASES = [("ppo", "paper"), ("ppo_shaped", "paper"), ("ppo_lag", "paper"), ("ppo_lag", "corrected"), ("cpo", "paper"), ("cpo", "corrected")]
ROLLOUT = 32 * 8
#: (chain, env id, seed): three scenarios of observation widths 31, 63 and 22, one of them twice.
RUNS = [
    ("DualProcess", "PushOrSwitch-Human-v1", 1),
    ("Utility", "Switch7-Human-v1", 2),
    ("DualProcess", "PushStandard-AnimalA-v1", 3),
    ("Utility", "PushOrSwitch-Animal-v1", 4),
]


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tests/conftest.py


def _fleet(name: str, protocol: str, runs: list[tuple[str, str, int]], simulator: str = "host"):
    spec = learner_spec(name, {"hparams": SMALL[name]})
    fleet = build_fleet(spec, [FleetRun(morality_gym.bind_chain(c, e), s) for c, e, s in runs], protocol, simulator=simulator)  # type: ignore[arg-type]
    fleet.learn(3 * ROLLOUT)
    return fleet


def _assert_same_runs(a, ka: int, b, kb: int) -> None:
    la, lb = a.learners()[ka], b.learners()[kb]
    for (name, pa), (_, pb) in zip(la.model.policy.named_parameters(), lb.model.policy.named_parameters()):
        np.testing.assert_array_equal(pa.detach().numpy(), pb.detach().numpy(), err_msg=name)
    assert str(la.update_diagnostics()) == str(lb.update_diagnostics())
    for opt in ("optimizer", "critic_optimizer"):
        if hasattr(la.model.policy, opt):
            sa, sb = getattr(la.model.policy, opt).state_dict()["state"], getattr(lb.model.policy, opt).state_dict()["state"]
            for key in sa:
                np.testing.assert_array_equal(sa[key]["exp_avg_sq"].numpy(), sb[key]["exp_avg_sq"].numpy())


@pytest.mark.parametrize(("name", "protocol"), CASES)
def test_a_mixed_fleet_trains_each_run_as_a_fleet_of_its_scenario_alone(name: str, protocol: str) -> None:
    mixed = _fleet(name, protocol, RUNS)
    assert mixed.nets.in_dims == [31, 63, 22, 31] and mixed.collector.env.obs_dim == 63
    alone = {scenario: _fleet(name, protocol, [r for r in RUNS if r[1].startswith(scenario + "-")])
             for scenario in ("PushOrSwitch", "Switch7", "PushStandard")}
    position = {"PushOrSwitch": 0, "Switch7": 0, "PushStandard": 0}
    for k, (_, env_id, _) in enumerate(RUNS):
        scenario = env_id.split("-")[0]
        _assert_same_runs(mixed, k, alone[scenario], position[scenario])
        position[scenario] += 1
    # the padded first-layer columns never moved from 0
    w0 = mixed.nets.heads["pi"][0][0]
    assert float(w0[2, :, 22:].abs().max()) == 0.0 and float(w0[0, :, 31:].abs().max()) == 0.0


@pytest.mark.parametrize(("name", "protocol"), [("ppo", "paper"), ("cpo", "corrected")])
def test_the_device_simulator_mixes_scenarios_as_the_host_one(name: str, protocol: str) -> None:
    host, device = _fleet(name, protocol, RUNS), _fleet(name, protocol, RUNS, simulator="device")
    for k in range(len(RUNS)):
        _assert_same_runs(host, k, device, k)
