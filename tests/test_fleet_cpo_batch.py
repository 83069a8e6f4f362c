"""CPO's actor step for all runs at once (:mod:`morality_gym.baselines.fleet.cpo_batch`, the GPU
path) takes each run's step as the per-run path does, on the CPU.

The two paths differ only in the order of float additions (padded states, batched rows), so the
runs take the same CPO cases, try and accept the same line-search candidates, and end at the same
parameters to float tolerance; under settings that reach the dual step and backtracking too.
Also: the batched path makes every tensor on the fleet's device (torch's default device is set to
``meta`` while it learns, as tests/test_fleet_device.py does for the per-run path).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch as th

import morality_gym
from morality_gym.baselines.fleet import FleetRun, build_fleet
from morality_gym.baselines.fleet.cpo import FleetCPO
from morality_gym.baselines.specs import learner_spec

ROLLOUT = 64 * 8
#: reaches the dual step (case 1) and rejected candidates in the first updates (as in tests/test_fleet.py)
CPO_DUAL = {"cost_advantage_normalization": "standardize", "target_kl": 0.2, "cost_limit": 0.0}
INTEGER_FIELDS = ("cpo_case", "accept_step", "line_search_tried", "update", "timesteps")


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tests/conftest.py


def _runs() -> list[FleetRun]:
    """Three runs whose rollouts visit different numbers of distinct observations (so padding bites)."""
    return [
        FleetRun(morality_gym.bind_chain("DualProcess", "PushOrSwitch-Human-v1"), 1),
        FleetRun(morality_gym.bind_chain("Utility", "PushOrSwitch-Animal-v1"), 2),
        FleetRun(morality_gym.bind_chain("UtilityAgentHarm", "PushOrSwitch-Robot-v1"), 3),
    ]


def _trained(protocol: str, batched: bool, updates: int, **hparams: Any) -> FleetCPO:
    spec = learner_spec("cpo", {"hparams": {"n_steps": 64, "n_critic_updates": 2, **hparams}})
    fleet = build_fleet(spec, _runs(), protocol)
    assert isinstance(fleet, FleetCPO)
    fleet.batched_actor_step = batched
    fleet.learn(updates * ROLLOUT)
    return fleet


def _assert_same_steps(per_run: FleetCPO, batched: FleetCPO, atol: float, row_atol: float = 1e-5) -> None:
    """The same actors (to ``atol``) and diagnostics: integers equal, floats to ``rel=1e-3`` or ``row_atol``."""
    np.testing.assert_allclose(batched.actor_optimizer.flat.numpy(), per_run.actor_optimizer.flat.numpy(), rtol=0, atol=atol)
    for rows_a, rows_b in zip(per_run.update_logs, batched.update_logs):
        assert len(rows_a) == len(rows_b)
        for ra, rb in zip(rows_a, rows_b):
            for key, va in ra.items():
                if key in INTEGER_FIELDS:
                    assert rb[key] == va, (key, va, rb[key])
                elif isinstance(va, float) and not np.isnan(va):
                    assert rb[key] == pytest.approx(va, rel=1e-3, abs=row_atol), (key, va, rb[key])


@pytest.mark.parametrize("protocol", ["paper", "corrected"])
def test_the_batched_actor_step_takes_the_per_run_steps(protocol: str) -> None:
    per_run, batched = _trained(protocol, False, 3), _trained(protocol, True, 3)
    _assert_same_steps(per_run, batched, atol=1e-5)


@pytest.mark.parametrize("protocol", ["paper", "corrected"])
def test_the_batched_actor_step_matches_through_dual_steps_and_backtracking(protocol: str) -> None:
    per_run, batched = _trained(protocol, False, 4, **CPO_DUAL), _trained(protocol, True, 4, **CPO_DUAL)
    # Large dual steps amplify rounding (tests/test_fleet.py), and B = 2 delta - c^2 / s cancels to
    # about 0.02 out of 0.4 here: its rounding differences are those of its 0.4-sized terms. How far
    # they carry depends on the CPU's kernels: 2 of 19,794 weights 1.2e-4 apart on a 2-core EPYC
    # (2026-11-28, the same at 90dc6b4; a diagnostic, kl, 0.17683 against 0.17664), under 1e-4 on the
    # machine this test was written on.
    _assert_same_steps(per_run, batched, atol=2e-4, row_atol=5e-4)
    rows = [r for log in per_run.update_logs for r in log]
    assert any(r["cpo_case"] == 1 for r in rows), "the settings must reach the dual step"
    assert any(r["accept_step"] != 1 for r in rows), "the settings must reach a rejected candidate"


def test_the_batched_actor_step_rescales_to_the_trust_region_as_the_per_run_one() -> None:
    settings = {**CPO_DUAL, "trust_region_rescale": True}
    # The third run's second solve is ill-conditioned: 15 conjugate-gradient steps leave q = v^T H v
    # 1e-3 (relative) apart from rounding alone. The single learner and the per-run fleet differ as
    # much there (q 0.018882 vs 0.018860; batched 0.018885), so the tolerance is that spread.
    per_run, batched = _trained("corrected", False, 2, **settings), _trained("corrected", True, 2, **settings)
    _assert_same_steps(per_run, batched, atol=2e-4, row_atol=2e-3)
    unscaled = _trained("corrected", True, 2, **CPO_DUAL)
    norms = [[r["full_step_norm"] for r in log] for log in (*batched.update_logs, *unscaled.update_logs)]
    assert norms[:3] != norms[3:], "the settings must make the rescale act"


def test_the_batched_actor_step_names_its_device() -> None:
    spec = learner_spec("cpo", {"hparams": {"n_steps": 32, "n_critic_updates": 1, **CPO_DUAL}})
    fleet = build_fleet(spec, _runs(), "corrected")
    assert isinstance(fleet, FleetCPO)
    fleet.batched_actor_step = True
    with th.device("meta"):
        assert fleet.learn(2 * 32 * 8) == 2 * 32 * 8
    assert all(len(log) == 2 for log in fleet.update_logs)


def test_accelerators_take_the_batched_path_and_the_cpu_the_per_run_one() -> None:
    fleet = build_fleet(learner_spec("cpo"), _runs()[:1], "paper")
    assert isinstance(fleet, FleetCPO) and not fleet._batched()
    fleet.device = th.device("meta")  # what the choice reads: any device but the CPU
    assert fleet._batched()
    fleet.batched_actor_step = False
    assert not fleet._batched()
