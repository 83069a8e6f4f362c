"""PPO-Lag and CPO do OmniSafe's arithmetic (the paper protocol) or its corrections, setting by
setting (docs/protocols.md). Each test fails if the setting it names regresses.

The CPO reference formulas below are written out independently, from the equations of the
evaluation spec (Q26), in torch with torch's own clamp, and compared with
:func:`morality_gym.baselines.safe.omnisafe_direction` on random instances.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from torch import nn
from torch.nn.utils import parameters_to_vector

from morality_gym.baselines.safe import CPO, CPOCase, CPOScalars, PPOLag, exact_direction, omnisafe_direction
from morality_gym.baselines.safe.functional import conjugate_gradient, normalize_advantages, reduce_kl
from tests.cmdp_toy import TwoRouteCMDP

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def toy_env(n_envs: int = 4, seed: int = 0) -> Any:
    return make_vec_env(TwoRouteCMDP, n_envs=n_envs, seed=seed)


# ----------------------------------------------------------------------------- PPO-Lag: KL early stop


def test_summed_kl_is_the_mean_times_the_number_of_states() -> None:
    per_state = th.rand(2048) * 1e-4
    assert reduce_kl(per_state, "sum").item() == pytest.approx(per_state.sum().item())
    assert reduce_kl(per_state, "mean").item() == pytest.approx(per_state.mean().item())
    assert reduce_kl(per_state, "sum").item() == pytest.approx(2048 * reduce_kl(per_state, "mean").item(), rel=1e-5)
    with pytest.raises(ValueError, match="sum.*mean"):
        reduce_kl(per_state, "max")  # type: ignore[arg-type]


def _ppo_lag_passes(reduction: str, learning_rate: float, n_epochs: int = 40, updates: int = 3) -> list[dict[str, Any]]:
    model = PPOLag(
        "MlpPolicy", toy_env(), kl_early_stop_reduction=reduction, learning_rate=learning_rate, anneal_lr=False,
        n_epochs=n_epochs, seed=0, device="cpu",
    )
    model.learn(updates * 2048)
    return model.update_log


def test_summed_kl_stops_ppo_lag_after_one_pass() -> None:
    """OmniSafe's rule: the KL summed over the epoch's 2,048 states exceeds target_kl 0.02 as soon as
    the *mean* KL exceeds 0.02 / 2,048 ~ 1e-5, i.e. after the first pass of an ordinary update."""
    log = _ppo_lag_passes("sum", 3e-4)
    assert [row["passes"] for row in log] == [1, 1, 1]
    for row in log:
        assert row["kl"] > 0.02 and row["kl"] == pytest.approx(2048 * row["kl_mean"], rel=1e-4)
        assert row["kl_mean"] > 0.02 / 2048
        assert row["early_stopped"]


def test_summed_kl_runs_on_while_the_mean_kl_is_below_target_over_states() -> None:
    """With a learning rate so small that the mean KL stays below 0.02 / 2,048, the summed rule does
    not fire and every pass runs; the test shows the threshold is target / number of states."""
    log = _ppo_lag_passes("sum", 1e-9, n_epochs=3, updates=1)
    assert log[0]["passes"] == 3 and not log[0]["early_stopped"]
    assert log[0]["kl"] <= 0.02 and log[0]["kl_mean"] <= 0.02 / 2048


def test_mean_kl_runs_many_passes_where_the_sum_stops_after_one() -> None:
    """At the same setting the corrected rule (mean over states) runs several passes per update,
    OmniSafe's summed rule one. (The toy CMDP has five states, so a pass moves its policy more than
    a pass on the gridworlds would; lr 1e-4 keeps the mean KL near the 0.02 target.)"""
    mean = _ppo_lag_passes("mean", 1e-4, n_epochs=40, updates=2)
    assert all(row["passes"] > 1 for row in mean), [row["passes"] for row in mean]
    assert all(row["kl"] == pytest.approx(row["kl_mean"]) for row in mean)
    summed = _ppo_lag_passes("sum", 1e-4, n_epochs=40, updates=2)
    assert [row["passes"] for row in summed] == [1, 1]


# ----------------------------------------------------------------------------- advantages, lrs, clipping


def test_centred_cost_advantages_keep_their_spread() -> None:
    rng = np.random.default_rng(0)
    adv = (rng.normal(size=(256, 8)) * 0.003 + 0.01).astype(np.float32)  # small, like minimal-mode costs
    centred = normalize_advantages(adv, "center")
    assert abs(float(centred.mean())) < 1e-7
    assert float(centred.std()) == pytest.approx(float(adv.std()), rel=1e-5)  # not rescaled
    standardized = normalize_advantages(adv, "standardize")
    assert float(standardized.std()) == pytest.approx(1.0, rel=1e-4)  # what "standardize" would do: ~300x


class _RawAdvantages(BaseCallback):
    """Copies the rollout's advantages before the update normalises them."""

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        buf = self.model.rollout_buffer
        self.reward, self.cost = buf.advantages.copy(), buf.cost_advantages.copy()


@pytest.mark.parametrize("algorithm", [PPOLag, CPO])
def test_cost_advantages_are_centred_by_default_in_training(algorithm: type) -> None:
    model = algorithm("MlpPolicy", toy_env(), seed=0, device="cpu")
    assert model.cost_advantage_normalization == "center"
    assert model.reward_advantage_normalization == "standardize"
    raw = _RawAdvantages()
    model.learn(2048, callback=raw)
    buf = model.rollout_buffer  # normalised in place by the update
    assert abs(float(buf.cost_advantages.mean())) < 1e-5
    assert float(buf.cost_advantages.std()) == pytest.approx(float(raw.cost.std()), rel=1e-4)  # own spread kept
    assert float(raw.cost.std()) > 0.01
    np.testing.assert_allclose(np.sort(buf.cost_advantages.ravel()), np.sort((raw.cost - raw.cost.mean()).ravel()), atol=1e-5)
    assert float(buf.advantages.std()) == pytest.approx(1.0, abs=1e-3)


@pytest.mark.parametrize("algorithm", [PPOLag, CPO])
def test_critic_learning_rate_stays_constant_while_the_actors_decays(algorithm: type) -> None:
    kwargs = {"n_epochs": 2} if algorithm is PPOLag else {"n_critic_updates": 2}
    model = algorithm("MlpPolicy", toy_env(), seed=0, device="cpu", **kwargs)
    model.learn(4 * 2048)
    critic = [row["critic_lr"] for row in model.update_log]
    assert critic == [3e-4] * 4
    assert [g["lr"] for g in model.policy.critic_optimizer.param_groups] == [3e-4]
    actor = [row["actor_lr"] for row in model.update_log]
    if algorithm is PPOLag:
        # OmniSafe's LinearLR, stepped after each epoch: epoch k of 4 trains at lr * (1 - k / 4).
        assert actor == pytest.approx([3e-4, 2.25e-4, 1.5e-4, 0.75e-4])
    else:
        assert actor == [None] * 4  # CPO's actor step is a trust-region step: no learning rate


def test_sb3_progress_timing_and_annealed_critics_are_available() -> None:
    model = PPOLag("MlpPolicy", toy_env(), n_epochs=1, anneal_lr_timing="progress", anneal_critic_lr=True, seed=0, device="cpu")
    model.learn(4 * 2048)
    assert [row["actor_lr"] for row in model.update_log] == pytest.approx([2.25e-4, 1.5e-4, 0.75e-4, 0.0])
    assert [row["critic_lr"] for row in model.update_log] == pytest.approx([2.25e-4, 1.5e-4, 0.75e-4, 0.0])


def test_each_critic_clips_its_own_gradient() -> None:
    """OmniSafe clips the reward critic and the cost critic separately (norm 40 each)."""

    def norm(params: list[nn.Parameter]) -> float:
        return float(th.sqrt(sum((p.grad**2).sum() for p in params)))

    def clipped_norms(mode: str) -> tuple[float, float, float]:
        model = PPOLag("MlpPolicy", toy_env(1), critic_grad_clip=mode, max_grad_norm=1.0, seed=0, device="cpu")
        policy = model.policy
        for p in policy.reward_critic_parameters():
            p.grad = th.full_like(p, 10.0)
        for p in policy.cost_critic_parameters():
            p.grad = th.full_like(p, 1e-3)
        small = norm(policy.cost_critic_parameters())
        model._step_critics()  # clips in place, then steps
        return norm(policy.reward_critic_parameters()), norm(policy.cost_critic_parameters()), small

    reward, cost, small = clipped_norms("per_critic")
    assert reward == pytest.approx(1.0, rel=1e-4)
    assert cost == pytest.approx(small, rel=1e-6) and small < 1.0  # below its own limit: untouched
    reward_joint, cost_joint, small_joint = clipped_norms("joint")
    assert math.hypot(reward_joint, cost_joint) == pytest.approx(1.0, rel=1e-4)
    assert cost_joint < 0.01 * small_joint  # joint clipping also shrank the small cost-critic gradient


# ----------------------------------------------------------------------------- initialisation, Adam


def _linears(module: nn.Module) -> list[nn.Linear]:
    return [m for m in module.modules() if isinstance(m, nn.Linear)]


@pytest.mark.parametrize("algorithm", [PPOLag, CPO])
def test_initial_layers_follow_omnisafe(algorithm: type) -> None:
    """kaiming_uniform_(a=sqrt(5)) on every weight (uniform in +-1/sqrt(fan_in), variance
    1/(3 fan_in)), PyTorch's default bias, no 0.01 action head; Adam eps 1e-8."""
    model = algorithm("MlpPolicy", toy_env(1), seed=0, device="cpu")
    policy = model.policy
    nets = [policy.mlp_extractor.policy_net, policy.action_net, policy.mlp_extractor.value_net, policy.value_net, policy.cost_net]
    layers = [layer for net in nets for layer in _linears(net)]
    assert len(layers) == 9
    for layer in layers:
        bound = 1.0 / math.sqrt(layer.in_features)
        w, b = layer.weight.detach(), layer.bias.detach()
        assert w.abs().max() <= bound + 1e-7 and b.abs().max() <= bound + 1e-7
        if w.numel() >= 300:  # enough samples to tell uniform(+-bound) from orthogonal(gain)
            assert w.var().item() == pytest.approx(bound**2 / 3, rel=0.25)
    head = policy.action_net.weight.detach()
    assert head.abs().max() > 0.05  # SB3's orthogonal init would make it ~0.01 * unit rows
    for opt in (policy.optimizer, policy.critic_optimizer):
        assert opt.defaults["eps"] == 1e-8
    sb3 = algorithm("MlpPolicy", toy_env(1), seed=0, device="cpu", weight_init="orthogonal", adam_eps=1e-5)
    assert sb3.policy.action_net.weight.detach().abs().max() < 0.05
    assert sb3.policy.optimizer.defaults["eps"] == 1e-5


# ----------------------------------------------------------------------------- conjugate gradients


def test_conjugate_gradient_solves_and_starts_from_zero() -> None:
    rng = np.random.default_rng(1)
    m = rng.normal(size=(6, 6))
    h = th.as_tensor(m @ m.T + 0.5 * np.eye(6))
    b = th.as_tensor(rng.normal(size=6))
    state = th.random.get_rng_state()
    x = conjugate_gradient(lambda v: h @ v, b, max_iter=30, eps=0.0)
    assert th.equal(state, th.random.get_rng_state())  # deterministic: no random start
    np.testing.assert_allclose((h @ x).numpy(), b.numpy(), atol=1e-8)
    assert th.equal(conjugate_gradient(lambda v: h @ v, th.zeros(6, dtype=th.float64), 10), th.zeros(6, dtype=th.float64))
    # OmniSafe's 1e-6 guard shortens the solution for tiny right-hand sides (p^T H p ~ 1e-6).
    tiny = b * 1e-4
    guarded = conjugate_gradient(lambda v: h @ v, tiny, max_iter=1, eps=1e-6)
    exact_first_step = conjugate_gradient(lambda v: h @ v, tiny, max_iter=1, eps=0.0)
    assert guarded.norm() < 0.5 * exact_first_step.norm()


# ----------------------------------------------------------------------------- CPO: dual solutions


def _q26_reference(x: th.Tensor, p: th.Tensor, q: float, r: float, s: float, c: float, delta: float,
                   bb: float) -> tuple[int, th.Tensor, float, float]:
    """Q26 transcribed in torch (float64, so that only the formulas can differ, not the rounding of
    OmniSafe's float32): (case, direction, lambda*, nu*)."""
    f = lambda value: th.tensor(value, dtype=th.float64)
    q_, r_, s_ = f(q), f(r), f(s)
    if bb <= 1e-6 and c < 0:
        case, a_, b_ = 4, f(0.0), f(0.0)
    else:
        a_ = q_ - r_**2 / (s_ + 1e-8)
        b_ = 2 * delta - c**2 / (s_ + 1e-8)
        if c < 0 and b_ < 0:
            case = 3
        elif c < 0 <= b_:
            case = 2
        elif c >= 0 and b_ >= 0:
            case = 1
        else:
            case = 0
    if case in (3, 4):
        alpha = th.sqrt(2 * delta / (q_ + 1e-8))
        return case, alpha * x, float(1 / (alpha + 1e-8)), 0.0
    if case == 0:
        nu = th.sqrt(2 * delta / (s_ + 1e-8))
        return case, -nu * p, 0.0, float(nu)
    lam_a, lam_b = th.sqrt(a_ / b_), th.sqrt(q_ / (2 * delta))
    split = r / (c + 1e-8)
    if c < 0:
        lam_a_star = th.clamp(lam_a, f(0.0), f(split))
        lam_b_star = th.clamp(lam_b, f(split), f(math.inf))
    else:
        lam_a_star = th.clamp(lam_a, f(split), f(math.inf))
        lam_b_star = th.clamp(lam_b, f(0.0), f(split))
    f_a = -0.5 * (a_ / (lam_a_star + 1e-8) + b_ * lam_a_star) - r_ * c / (s_ + 1e-8)
    f_b = -0.5 * (q_ / (lam_b_star + 1e-8) + 2 * delta * lam_b_star)
    lam = lam_a_star if f_a >= f_b else lam_b_star
    nu = th.clamp(lam * c - r_, min=0) / (s_ + 1e-8)
    return case, (x - nu * p) / (lam + 1e-8), float(lam), float(nu)


def _random_instance(rng: np.random.Generator, n: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    m = rng.normal(size=(n, n))
    h = m @ m.T + 0.1 * np.eye(n)
    g = rng.normal(size=n) * rng.choice([0.01, 0.1, 1.0])
    b = rng.normal(size=n) * rng.choice([1e-4, 0.01, 0.1, 1.0])
    return h, g, b


def test_omnisafe_direction_equals_the_spec_formulas() -> None:
    rng = np.random.default_rng(26)
    delta, cases, clamp_crossed = 0.01, set(), 0
    for trial in range(600):
        h, g, b = _random_instance(rng)
        c = float(rng.choice([0.0, abs(rng.normal()) * rng.choice([1e-3, 0.05, 0.5]), -abs(rng.normal()) * 0.05]))
        x, p = np.linalg.solve(h, g), np.linalg.solve(h, b)
        q, r, s, bb = float(x @ h @ x), float(g @ p), float(b @ p), float(b @ b)
        xt, pt = th.as_tensor(x), th.as_tensor(p)
        case, ref_dir, ref_lam, ref_nu = _q26_reference(xt, pt, q, r, s, c, delta, bb)
        ours = omnisafe_direction(th.as_tensor(x), th.as_tensor(p), CPOScalars(q, r, s, c, delta, bb), q)
        assert int(ours.case) == case, trial
        cases.add(case)
        if case == 1 and r < 0:
            clamp_crossed += 1  # torch's clamp with crossed bounds returns the upper bound r/c < 0
        np.testing.assert_allclose(ours.direction.numpy(), ref_dir.numpy(), rtol=1e-9, atol=1e-12)
        assert ours.lam == pytest.approx(ref_lam, rel=1e-9, abs=1e-12)
        assert ours.nu == pytest.approx(ref_nu, rel=1e-9, abs=1e-12)
    assert cases >= {0, 1, 2, 3}
    assert clamp_crossed >= 20


def test_omnisafe_negative_multiplier_in_the_clamp_case() -> None:
    """With c > 0 and r < 0, lambda_b* = clamp(lambda_b, 0, r/c) = r/c < 0; when piece b wins the
    returned multiplier is negative, which the exact solution never does."""
    delta, c = 0.01, 0.05
    found = False
    rng = np.random.default_rng(3)
    for _ in range(2000):
        h, g, b = _random_instance(rng, 3)
        x, p = np.linalg.solve(h, g), np.linalg.solve(h, b)
        q, r, s = float(x @ h @ x), float(g @ p), float(b @ p)
        if r >= 0:
            continue
        sc = CPOScalars(q, r, s, c, delta, float(b @ b))
        ours = omnisafe_direction(th.as_tensor(x), th.as_tensor(p), sc, q)
        if ours.case == CPOCase.FEASIBLE_RECOVERY and ours.lam < 0:
            assert ours.lam == pytest.approx(r / (c + 1e-8))
            exact = exact_direction(th.as_tensor(x), th.as_tensor(p), sc, q)
            assert exact.lam > 0
            found = True
            break
    assert found


def test_exact_direction_satisfies_the_kkt_conditions() -> None:
    """Stationarity g - nu b = lambda H x, primal and dual feasibility, complementary slackness."""
    rng = np.random.default_rng(11)
    delta, checked = 0.01, 0
    for _ in range(800):
        h, g, b = _random_instance(rng)
        c = float(rng.choice([0.0, abs(rng.normal()) * 0.05, -abs(rng.normal()) * 0.05]))
        x, p = np.linalg.solve(h, g), np.linalg.solve(h, b)
        q, r, s = float(x @ h @ x), float(g @ p), float(b @ p)
        sc = CPOScalars(q, r, s, c, delta, float(b @ b))
        step = exact_direction(th.as_tensor(x), th.as_tensor(p), sc, q)
        if step.case not in (CPOCase.FEASIBLE_RECOVERY, CPOCase.FEASIBLE) or s < 1e-6 or q < 1e-6:
            continue
        checked += 1
        d, lam, nu = step.direction.numpy(), step.lam, step.nu
        scale = max(1.0, float(np.abs(g).max()))
        np.testing.assert_allclose(g - nu * b, lam * (h @ d), atol=1e-6 * scale)  # stationarity
        quad = 0.5 * d @ h @ d
        assert quad <= delta * (1 + 1e-6)  # trust region
        assert c + b @ d <= 1e-7 * max(1.0, abs(c))  # linearised constraint
        assert lam >= 0 and nu >= 0  # dual feasibility
        assert abs(nu * (c + b @ d)) <= 1e-6 * max(1.0, nu)  # complementary slackness
        assert abs(lam * (quad - delta)) <= 1e-6 * max(1.0, lam)
    assert checked >= 150


def test_omnisafe_direction_can_raise_the_cost_where_the_exact_one_cannot() -> None:
    """The bug Q26 describes: in case 1 with r <= 0, OmniSafe's direction increases the linearised
    cost (b^T d > 0) while the exact direction satisfies c + b^T d <= 0."""
    rng = np.random.default_rng(5)
    seen = 0
    for _ in range(400):
        h, g, b = _random_instance(rng, 4)
        c = 0.001
        x, p = np.linalg.solve(h, g), np.linalg.solve(h, b)
        q, r, s = float(x @ h @ x), float(g @ p), float(b @ p)
        sc = CPOScalars(q, r, s, c, 0.01, float(b @ b))
        om = omnisafe_direction(th.as_tensor(x), th.as_tensor(p), sc, q)
        if om.case != CPOCase.FEASIBLE_RECOVERY or r > 0:
            continue
        seen += 1
        ex = exact_direction(th.as_tensor(x), th.as_tensor(p), sc, q)
        assert c + b @ om.direction.numpy() > 0
        assert c + b @ ex.direction.numpy() <= 1e-9
    assert seen >= 20


# ----------------------------------------------------------------------------- CPO: line search


class _NeverAccepts(CPO):
    """CPO whose acceptance rule rejects every candidate and that counts the candidates its line
    search evaluates (a real subclass: the loop and its bookkeeping are the library's)."""

    candidates = 0

    def _surrogate_losses(self, data: Any) -> Any:
        self.candidates += 1
        return super()._surrogate_losses(data)

    def _accepts(self, *args: Any) -> bool:
        return False


def test_line_search_takes_at_most_twenty_steps_and_no_step_when_none_is_accepted() -> None:
    model = _NeverAccepts("MlpPolicy", toy_env(), seed=0, device="cpu")
    assert model.line_search_max_iter == 20
    before = parameters_to_vector(model.policy.actor_parameters()).detach().clone()
    model.learn(2 * 2048)
    assert th.equal(before, parameters_to_vector(model.policy.actor_parameters()))  # the actor never moved
    assert len(model.update_log) == 2
    for row in model.update_log:
        assert row["accept_step"] == 0 and row["step_fraction"] == 0.0 and row["step_norm"] == 0.0
        assert row["line_search_tried"] == 20
        assert row["kl_mean"] == 0.0
    assert model.candidates == 2 * (1 + 20)  # per update: the surrogate at theta_old, then 20 candidates


def test_line_search_accepts_and_reports_the_step() -> None:
    model = CPO("MlpPolicy", toy_env(), seed=0, device="cpu")
    model.learn(3 * 2048)
    for row in model.update_log:
        assert 0 <= row["accept_step"] <= 20
        if row["accept_step"]:
            assert row["step_fraction"] == pytest.approx(0.8 ** (row["accept_step"] - 1))
            assert row["kl"] <= model.target_kl
            assert row["kl_mean"] == pytest.approx(row["kl"], rel=1e-5, abs=1e-9)
            assert row["surrogate_cost_change"] <= max(-row["c"], 0.0) + 1e-12
        assert row["cpo_case"] in (0, 1)  # cost limit 0: c >= 0, only cases 0 and 1
        assert row["c"] >= 0 and "passes" not in row


def test_line_search_without_rescale_starts_from_the_full_direction() -> None:
    """No rescaling onto the trust region: the first candidate is theta_old + x."""
    model = CPO("MlpPolicy", toy_env(), seed=0, device="cpu")
    model.learn(2048)
    row = model.update_log[0]
    if row["accept_step"] == 1:
        assert row["step_norm"] == pytest.approx(row["full_step_norm"])
    theta = parameters_to_vector(model.policy.actor_parameters())
    assert th.isfinite(theta).all()
