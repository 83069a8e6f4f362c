"""The fleet engine trains each of its runs exactly as the single-run learner would.

* A fleet of one run and the single learner, from the same seed (hence the same initial weights,
  action draws and minibatch order), end a few updates at the same parameters, optimiser moments
  and per-update diagnostics, to float tolerance (batched matrix products may round differently
  from ``addmm``), for each learner and protocol.
* Runs of a fleet do not influence each other: in a fleet of three runs on different variants
  and chains, changing one run's seed leaves the other two *bit for bit* unchanged, and each run
  matches its own single run.
* :class:`BatchedAdam` and the per-run clipping are ``torch.optim.Adam(fused=True)`` and
  ``clip_grad_norm_`` slice by slice, bit for bit, with per-run learning rates and masks.

Budgets are tiny (rollouts of 64 steps x 8 envs, few epochs) so the whole file runs in seconds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch as th

import morality_gym
from morality_gym.baselines.fleet import FleetRun, build_fleet
from morality_gym.baselines.fleet.optim import BatchedAdam, clip_grad_norm
from morality_gym.baselines.learners import build_learner
from morality_gym.baselines.sb3_learner import SB3Learner
from morality_gym.baselines.specs import LearnerSpec, SpecError, learner_spec

SMALL = {
    "ppo": {"n_steps": 64, "n_epochs": 2},
    "ppo_shaped": {"n_steps": 64, "n_epochs": 2},
    "ppo_lag": {"n_steps": 64, "n_epochs": 3},
    "cpo": {"n_steps": 64, "n_critic_updates": 2},
}
ROLLOUT = 64 * 8
#: CPO settings under which a run meets the dual step (case 1) and backtracks or rejects every
#: candidate in its first updates (the paper's settings give only cases 0 and 3, accepted at once).
CPO_DUAL = {"cost_advantage_normalization": "standardize", "target_kl": 0.2, "cost_limit": 0.0}
CASES = [
    ("ppo", "paper"),
    ("ppo_shaped", "paper"),
    ("ppo_lag", "paper"),
    ("ppo_lag", "corrected"),
    ("cpo", "paper"),
    ("cpo", "corrected"),
]


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tests/conftest.py


def small_spec(name: str, **hparams: Any) -> LearnerSpec:
    return learner_spec(name, {"hparams": {**SMALL[name], **hparams}})


def bound(env_id: str = "PushOrSwitch-Human-v1", chain: str = "DualProcess") -> Any:
    return morality_gym.bind_chain(chain, env_id)


def assert_same_run(single: SB3Learner, fleet: SB3Learner, atol: float = 1e-6) -> None:
    """Parameters, Adam moments, step counts and diagnostics rows of two runs agree."""
    for (name, a), (_, b) in zip(single.model.policy.named_parameters(), fleet.model.policy.named_parameters()):
        np.testing.assert_allclose(b.detach().numpy(), a.detach().numpy(), rtol=0, atol=atol, err_msg=name)
    for opt in ("optimizer", "critic_optimizer"):
        if not hasattr(single.model.policy, opt):
            continue
        sa, sb = getattr(single.model.policy, opt), getattr(fleet.model.policy, opt)
        params = [p for group in sa.param_groups for p in group["params"]]
        params_b = [p for group in sb.param_groups for p in group["params"]]
        for pa, pb in zip(params, params_b):
            if pa not in sa.state:
                assert pb not in sb.state
                continue
            assert float(sa.state[pa]["step"]) == float(sb.state[pb]["step"])
            np.testing.assert_allclose(sb.state[pb]["exp_avg"].numpy(), sa.state[pa]["exp_avg"].numpy(), rtol=0, atol=atol)
    assert fleet.trained_steps == single.trained_steps
    rows_a, rows_b = single.update_diagnostics(), fleet.update_diagnostics()
    assert len(rows_a) == len(rows_b)
    for ra, rb in zip(rows_a, rows_b):
        assert ra.keys() == rb.keys()
        for key, va in ra.items():
            vb = rb[key]
            if isinstance(va, (bool, int, np.integer)) or va is None:
                assert vb == va, (key, va, vb)
            else:
                assert vb == pytest.approx(va, rel=1e-3, abs=1e-7), (key, va, vb)


@pytest.mark.parametrize(("name", "protocol"), CASES)
def test_fleet_of_one_trains_as_the_single_run(name: str, protocol: str) -> None:
    spec = small_spec(name)
    single = build_learner(spec, bound(), protocol, seed=3)
    single.learn(3 * ROLLOUT, eval_every=0)
    fleet = build_fleet(spec, [FleetRun(bound(), 3)], protocol)
    assert fleet.learn(3 * ROLLOUT) == single.trained_steps
    assert_same_run(single, fleet.learners()[0])  # type: ignore[arg-type]
    if name in ("ppo_lag", "cpo"):
        assert len(single.update_diagnostics()) == 3


@pytest.mark.parametrize("protocol", ["paper", "corrected"])
def test_fleet_of_one_cpo_matches_through_dual_steps_and_backtracking(protocol: str) -> None:
    spec = small_spec("cpo", **CPO_DUAL)
    single = build_learner(spec, bound(), protocol, seed=2)
    single.learn(4 * ROLLOUT, eval_every=0)
    fleet = build_fleet(spec, [FleetRun(bound(), 2)], protocol)
    fleet.learn(4 * ROLLOUT)
    # Steps this large (KL up to 0.12, full-step norms up to 7.5, nu* up to 500 times w) amplify the
    # rounding differences of batched products: the runs take the same cases, candidates and
    # fractions, and their parameters agree to about 1e-5 after four updates (1e-7 after the first).
    assert_same_run(single, fleet.learners()[0], atol=1e-4)  # type: ignore[arg-type]
    rows = single.update_diagnostics()
    assert any(r["cpo_case"] == 1 for r in rows)
    assert any(r["accept_step"] != 1 for r in rows)


def test_fleet_learn_time_evaluations_are_the_single_runs() -> None:
    spec = small_spec("ppo")
    rows_single: list[dict[str, Any]] = []
    rows_fleet: list[tuple[int, dict[str, Any]]] = []
    single = build_learner(spec, bound(), "paper", seed=5)
    single.learn(3 * ROLLOUT, eval_every=700, eval_episodes=4, on_eval=rows_single.append)
    fleet = build_fleet(spec, [FleetRun(bound(), 5)], "paper")
    fleet.learn(3 * ROLLOUT, eval_every=700, eval_episodes=4, on_eval=lambda k, row: rows_fleet.append((k, row)))
    assert [r["step"] for r in rows_single] == [0, 704, 1400]  # first env step at or past each multiple of 700
    assert [r["step"] for _, r in rows_fleet] == [r["step"] for r in rows_single]
    assert {k for k, _ in rows_fleet} == {0}
    for a, (_, b) in zip(rows_single, rows_fleet):
        assert b["metric"] == pytest.approx(a["metric"], abs=1e-9)
        assert b["exact_metric"] == pytest.approx(a["exact_metric"], abs=1e-6)
    assert [r["step"] for r in fleet.learners()[0].learn_evals] == [0, 704, 1400]


MIXED = [("PushOrSwitch-Human-v1", "DualProcess"), ("PushOrSwitch-Animal-v1", "Utility"), ("PushOrSwitch-HumanRobotA-v1", "Outcome")]


@pytest.mark.parametrize(
    ("name", "protocol", "hparams"),
    [("ppo_shaped", "paper", {}), ("ppo_lag", "corrected", {}), ("cpo", "paper", {}), ("cpo", "corrected", CPO_DUAL)],
)
def test_runs_of_a_fleet_do_not_influence_each_other(name: str, protocol: str, hparams: dict[str, Any]) -> None:
    spec = small_spec(name, **hparams)
    seeds_a, seeds_b = (1, 2, 3), (1, 99, 3)
    fleets = []
    for seeds in (seeds_a, seeds_b):
        fleet = build_fleet(spec, [FleetRun(bound(e, c), s) for (e, c), s in zip(MIXED, seeds)], protocol)
        fleet.learn(2 * ROLLOUT)
        fleets.append(fleet.learners())
    for k in (0, 2):
        for (n, a), (_, b) in zip(fleets[0][k].model.policy.named_parameters(), fleets[1][k].model.policy.named_parameters()):
            np.testing.assert_array_equal(a.detach().numpy(), b.detach().numpy(), err_msg=f"run {k} {n}")
        assert fleets[0][k].update_diagnostics() == fleets[1][k].update_diagnostics()
    moved = [(a - b).abs().max().item() for a, b in zip(fleets[0][1].model.policy.parameters(), fleets[1][1].model.policy.parameters())]
    assert max(moved) > 1e-3  # the changed run did change
    # Each run of the mixed fleet is its own single run (its variant, its chain's cost and reward).
    for k, ((env_id, chain), seed) in enumerate(zip(MIXED, seeds_a)):
        single = build_learner(spec, bound(env_id, chain), protocol, seed=seed)
        single.learn(2 * ROLLOUT, eval_every=0)
        assert_same_run(single, fleets[0][k], atol=1e-4 if hparams else 1e-6)


@pytest.mark.parametrize("groups", [None, [[0, 1], [2]]])
def test_batched_adam_and_clipping_are_torch_per_slice(groups: list[list[int]] | None) -> None:
    """Per slice, bit for bit: clipping (one norm over all tensors, or one per group, as the
    per-critic clip) and Adam with per-run learning rates and masks; both the separate
    :func:`clip_grad_norm` and the clipping inside :meth:`BatchedAdam.step`."""
    gen = th.Generator().manual_seed(0)
    k_runs, shapes = 4, [(31, 64), (1, 64), (64, 6)]
    stacked = [th.randn(k_runs, *s, generator=gen) for s in shapes]
    inner = [t.clone() for t in stacked]
    singles = [[th.nn.Parameter(t[k].clone()) for t in stacked] for k in range(k_runs)]
    torch_adams = [th.optim.Adam(ps, lr=1.0, eps=1e-5, fused=True) for ps in singles]
    fleet_adam = BatchedAdam(stacked, k_runs, eps=1e-5)
    inner_adam = BatchedAdam(inner, k_runs, eps=1e-5)
    lrs = np.array([3e-4, 1e-3, 2e-4, 5e-5])
    tensor_groups = groups or [[0, 1, 2]]
    for it in range(25):
        grads = [th.randn(k_runs, *s, generator=gen) * (1 + it) for s in shapes]
        mask = np.array([True, it % 3 != 0, True, it % 2 == 0])
        clipped = list(grads)
        for grp in tensor_groups:
            part, norms = clip_grad_norm([grads[i] for i in grp], 0.5)
            for i, c in zip(grp, part):
                clipped[i] = c
            for k in range(k_runs):
                for i in grp:
                    singles[k][i].grad = grads[i][k].clone()
                norm = th.nn.utils.clip_grad_norm_([singles[k][i] for i in grp], 0.5)
                assert norm.item() == norms[k].item()
        fleet_adam.step(clipped, lrs, mask)
        inner_adam.step(grads, lrs, mask, max_norm=0.5, clip_groups=groups)
        for k in np.flatnonzero(mask):
            torch_adams[k].param_groups[0]["lr"] = float(lrs[k])
            torch_adams[k].step()
    for k in range(k_runs):
        for t, u, p in zip(stacked, inner, singles[k]):
            np.testing.assert_array_equal(t[k].numpy(), p.detach().numpy())
            np.testing.assert_array_equal(u[k].numpy(), p.detach().numpy())
        for state, p in zip(fleet_adam.state_of(k), singles[k]):
            torch_state = torch_adams[k].state[p]
            assert float(state["step"]) == float(torch_state["step"])
            np.testing.assert_array_equal(state["exp_avg_sq"].numpy(), torch_state["exp_avg_sq"].numpy())


def test_fleet_refuses_what_it_does_not_reproduce() -> None:
    with pytest.raises(SpecError, match="target_kl=0.01 is not reproduced by the fleet engine"):
        build_fleet(small_spec("ppo", target_kl=0.01), [FleetRun(bound(), 0)])
    with pytest.raises(SpecError, match="at least one run"):
        build_fleet(small_spec("ppo"), [])
    with pytest.raises(SpecError, match="does not train 'morality_gym.baselines.learners.RandomLearner'"):
        build_fleet(learner_spec("random"), [FleetRun(bound(), 0)])
    # runs of different scenarios (observation sizes) are no longer refused: tests/test_fleet_mixed.py
    mixed = build_fleet(small_spec("ppo"), [FleetRun(bound(), 0), FleetRun(bound("Switch7-Human-v1", "Utility"), 0)])
    assert mixed.nets.in_dims == [31, 63]


def test_rollout_noise_draws_the_actions_torch_multinomial_draws() -> None:
    """Drawing a rollout's exponential noise at once and taking ``argmax(probs / q)`` per step gives
    the actions (and leaves the generator in the state) of ``torch.multinomial`` step by step."""
    probs = th.softmax(th.randn(300, 8, 6, generator=th.Generator().manual_seed(3)) * 3, dim=-1)
    stepwise, at_once = th.Generator().manual_seed(11), th.Generator().manual_seed(11)
    expected = th.stack([th.multinomial(probs[t], 1, True, generator=stepwise)[:, 0] for t in range(300)])
    noise = th.empty(300, 8, 6).exponential_(1, generator=at_once)
    np.testing.assert_array_equal((probs / noise).argmax(dim=-1).numpy(), expected.numpy())
    assert th.equal(stepwise.get_state(), at_once.get_state())


def test_fleet_learners_save_and_load_like_single_runs(tmp_path: Any) -> None:
    """The learners a fleet hands back hold its weights and optimiser state and save as any run."""
    from morality_gym.baselines.safe import PPOLag

    fleet = build_fleet(small_spec("ppo_lag"), [FleetRun(bound(), 4), FleetRun(bound("PushOrSwitch-Animal-v1"), 5)], "corrected")
    fleet.learn(ROLLOUT)
    learner = fleet.learners()[1]
    assert learner.env_id == "PushOrSwitch-Animal-v1" and learner.seed == 5 and learner.trained_steps == ROLLOUT
    path = learner.save(tmp_path / "run")
    loaded = PPOLag.load(path, device="cpu")
    for a, b in zip(learner.model.policy.parameters(), loaded.policy.parameters()):
        np.testing.assert_array_equal(a.detach().numpy(), b.detach().numpy())
    assert loaded.lagrange_multiplier == pytest.approx(learner.update_diagnostics()[-1]["lagrange_multiplier"])
    state = loaded.policy.critic_optimizer.state_dict()["state"]
    assert state and all(float(s["step"]) == learner.update_diagnostics()[-1]["passes"] * (512 // 64) for s in state.values())
    assert np.isfinite(learner.final_evaluation(5).metric)  # evaluates as a single run


@pytest.mark.skipif(not th.cuda.is_available(), reason="needs a GPU (device=cuda); this machine has none")
@pytest.mark.parametrize(("name", "protocol"), [("ppo", "paper"), ("ppo_lag", "corrected"), ("cpo", "paper"), ("cpo", "corrected")])
def test_a_fleet_on_the_gpu_trains_as_on_the_cpu(name: str, protocol: str) -> None:
    spec = small_spec(name)
    runs = [FleetRun(bound(), 1), FleetRun(bound("PushOrSwitch-Animal-v1"), 2)]
    on_cpu, on_gpu = build_fleet(spec, runs, protocol), build_fleet(spec, runs, protocol, device="cuda")
    on_cpu.learn(2 * ROLLOUT)
    on_gpu.learn(2 * ROLLOUT)
    for a, b in zip(on_cpu.learners(), on_gpu.learners()):
        assert_same_run(a, b, atol=1e-4)  # type: ignore[arg-type]


@pytest.mark.parametrize(("name", "arch"), [("ppo", {"net_arch": [32], "activation": "relu"}), ("cpo", {"net_arch": [48, 24, 16]})])
def test_fleet_of_one_matches_other_architectures(name: str, arch: dict[str, Any]) -> None:
    """Other depths, widths and ReLU: the hand-written gradients and the fused rollout network are
    not tied to the default two tanh layers of 64."""
    spec = learner_spec(name, {"hparams": SMALL[name], **arch})
    single = build_learner(spec, bound(), "paper", seed=4)
    single.learn(2 * ROLLOUT, eval_every=0)
    fleet = build_fleet(spec, [FleetRun(bound(), 4)], "paper")
    fleet.learn(2 * ROLLOUT)
    assert_same_run(single, fleet.learners()[0])  # type: ignore[arg-type]
