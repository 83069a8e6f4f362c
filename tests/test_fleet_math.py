"""The fleet's hand-written arithmetic against autograd and PyTorch's own functions.

The fleet trainers take no gradient by autograd: the learners' losses are differentiated in closed
form (:mod:`morality_gym.baselines.fleet.losses`) and back-propagated by hand through the stacked
networks (:mod:`morality_gym.baselines.fleet.nets`). Each piece is checked here against what
autograd computes for the same expression, including the ties where ``torch.min`` splits the
gradient and ``clamp`` passes it at its bounds; CPO's Fisher-vector product on distinct
observations is checked against the double backward of the mean KL over the whole batch, which is
what the single learner takes.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

from morality_gym.baselines.fleet.dedup import DistinctStates
from morality_gym.baselines.fleet.losses import Policy, clipped_surrogate, mse
from morality_gym.baselines.fleet.nets import FleetNetworks, tanh_


def networks(activation: str = "tanh", runs: int = 3, obs_dim: int = 7, seed: int = 0) -> FleetNetworks:
    gen = th.Generator().manual_seed(seed)
    nets = FleetNetworks(runs, obs_dim, [16, 16], {"pi": 6, "vf": 1, "cf": 1}, activation)
    for t in nets.params("pi", "vf", "cf"):
        t.copy_(th.randn(t.shape, generator=gen) * 0.5)
    return nets


def autograd_head(nets: FleetNetworks, head: str, x: th.Tensor, runs: slice | None = None) -> tuple[th.Tensor, list[th.Tensor]]:
    """The head's output ``[R, out, B]`` computed by torch modules' arithmetic, with leaf copies of its parameters."""
    params = [t[runs if runs is not None else slice(None)].clone().requires_grad_() for t in nets.params(head)]
    act = th.tanh if nets.activation_name == "tanh" else th.relu
    h = x.transpose(1, 2)
    for i in range(0, len(params), 2):
        h = th.baddbmm(params[i + 1], params[i], h)
        if i + 2 < len(params):
            h = act(h)
    return h, params


def test_fast_tanh_is_tanh_to_float_rounding() -> None:
    x = th.linspace(-12, 12, 200_001)
    np.testing.assert_allclose(tanh_(x.clone()).numpy(), th.tanh(x).numpy(), rtol=0, atol=3e-7)
    assert tanh_(th.tensor([0.0])).item() == 0.0


@pytest.mark.parametrize("activation", ["tanh", "relu"])
@pytest.mark.parametrize("head", ["pi", "vf"])
def test_backward_is_autograd(activation: str, head: str) -> None:
    nets = networks(activation)
    x = th.randn(3, 11, 7, generator=th.Generator().manual_seed(1))
    tr = nets.trace(head, x)
    out, params = autograd_head(nets, head, x)
    np.testing.assert_allclose(tr.out.numpy(), out.detach().numpy(), rtol=0, atol=2e-6)
    cotangent = th.randn(out.shape, generator=th.Generator().manual_seed(2))
    expected = th.autograd.grad((out * cotangent).sum(), params)
    for mine, ref in zip(nets.backward(tr, cotangent), expected):
        assert mine.shape == ref.shape
        np.testing.assert_allclose(mine.numpy(), ref.numpy(), rtol=1e-5, atol=2e-6)


def test_backward_and_jvp_of_one_run_take_several_vectors() -> None:
    """CPO's per-run products: one run's trace, ``R'`` cotangents or tangents at once."""
    nets = networks()
    x = th.randn(1, 9, 7, generator=th.Generator().manual_seed(3))
    tr = nets.trace("pi", x, slice(1, 2))
    out, params = autograd_head(nets, "pi", x, slice(1, 2))
    gen = th.Generator().manual_seed(4)
    cotangents = th.randn(2, *out.shape[1:], generator=gen)
    grads = nets.backward(tr, cotangents)
    for r in range(2):
        expected = th.autograd.grad((out * cotangents[r : r + 1]).sum(), params, retain_graph=True)
        for mine, ref in zip(grads, expected):
            np.testing.assert_allclose(mine[r : r + 1].numpy(), ref.numpy(), rtol=1e-5, atol=2e-6)
    # jvp: <J v, u> = <v, J^T u> for every pair of tangent and cotangent
    tangents = [th.randn(2, *p.shape[1:], generator=gen) for p in params]
    jv = nets.jvp(tr, tangents)
    for r in range(2):
        lhs = (jv[r] * cotangents[r]).sum()
        rhs = sum((t[r] * g[r]).sum() for t, g in zip(tangents, grads))
        assert lhs.item() == pytest.approx(rhs.item(), rel=1e-4, abs=1e-5)


@pytest.mark.parametrize("hidden", [[16, 16], [16], []])
def test_fused_heads_are_the_heads(hidden: list[int]) -> None:
    nets = FleetNetworks(3, 7, hidden, {"pi": 6, "vf": 1, "cf": 1}, "tanh")
    gen = th.Generator().manual_seed(5)
    for t in nets.params("pi", "vf", "cf"):
        t.copy_(th.randn(t.shape, generator=gen) * 0.5)
    x = th.randn(3, 8, 7, generator=gen)
    fused = nets.fused(["pi", "vf", "cf"])(x)
    for head, out in zip(["pi", "vf", "cf"], fused):
        np.testing.assert_allclose(out.numpy(), nets(head, x).numpy(), rtol=0, atol=2e-6)


def test_policy_gradients_are_autograd_through_torch_categorical() -> None:
    gen = th.Generator().manual_seed(6)
    logits = th.randn(2, 6, 10, generator=gen, requires_grad=True)
    actions = th.randint(0, 6, (2, 10), generator=gen)
    dlogp, dent = th.randn(2, 10, generator=gen), th.randn(2, 10, generator=gen)
    dist = th.distributions.Categorical(logits=logits.transpose(1, 2))
    loss = (dist.log_prob(actions) * dlogp).sum() + (dist.entropy() * dent).sum()
    (expected,) = th.autograd.grad(loss, logits)
    policy = Policy.of(logits.detach())
    np.testing.assert_allclose(policy.log_prob(actions).numpy(), dist.log_prob(actions).detach().numpy(), atol=1e-6)
    np.testing.assert_allclose(policy.entropy().numpy(), dist.entropy().detach().numpy(), atol=1e-6)
    np.testing.assert_allclose(policy.dlogits(actions, dlogp, dent).numpy(), expected.numpy(), rtol=1e-5, atol=1e-6)
    other = Policy.of(th.randn(2, 6, 10, generator=gen))
    reference = (policy.p * (policy.logp - other.logp)).sum(dim=1)
    np.testing.assert_allclose(other.kl_from(policy).numpy(), reference.numpy(), atol=1e-7)


def test_clipped_surrogate_gradient_splits_ties_as_autograd() -> None:
    """Inside the clip range the two terms are equal (autograd gives each half); at a bound the
    clamp still passes the gradient; outside it the clipped term has none."""
    ratio = th.tensor([[1.0, 1.2, 0.8, 1.5, 0.5, 1.1, 0.7, 1.3]], requires_grad=True)
    adv = th.tensor([[1.0, -1.0, 2.0, 1.0, -1.0, -2.0, 1.0, -1.0]])
    expected_loss = -th.min(ratio * adv, th.clamp(ratio, 0.8, 1.2) * adv).mean(dim=1)
    (expected,) = th.autograd.grad(expected_loss.sum(), ratio)
    loss, grad = clipped_surrogate(ratio.detach(), adv, 0.2)
    assert loss.item() == expected_loss.item()
    assert th.equal(grad, expected)


def test_mse_gradient_is_autograd() -> None:
    pred = th.randn(3, 9, requires_grad=True)
    target = th.randn(3, 9)
    expected_loss = ((pred - target) ** 2).mean(dim=1)
    (expected,) = th.autograd.grad(expected_loss.sum(), pred)
    loss, grad = mse(pred.detach(), target)
    np.testing.assert_allclose(loss.numpy(), expected_loss.detach().numpy(), atol=1e-7)
    assert grad.shape == (3, 1, 9)
    np.testing.assert_allclose(grad[:, 0].numpy(), expected.numpy(), atol=1e-7)


def test_distinct_states_rebuild_the_rollout() -> None:
    gen = th.Generator().manual_seed(7)
    rows = th.randn(13, 5, generator=gen)
    obs = rows[th.randint(0, 13, (200,), generator=gen)]
    states = DistinctStates.of(obs)
    assert states.n == len(th.unique(obs, dim=0))
    assert th.equal(states.obs[states.inverse], obs)
    assert states.counts.sum().item() == 200
    assert states.weights.sum().item() == pytest.approx(1.0)
    assert th.equal(states.counts, th.bincount(states.inverse).float())


def test_fisher_product_on_distinct_states_is_the_double_backward_of_the_mean_kl() -> None:
    """What the single CPO learner computes (Hessian of the mean KL over every transition, by
    double backward) equals the fleet's product on the distinct observations."""
    from morality_gym.baselines.fleet.cpo import FleetCPO, RunBatch
    from morality_gym.baselines.safe.functional import categorical_kl

    nets = networks(runs=2)
    gen = th.Generator().manual_seed(8)
    rows = th.randn(6, 7, generator=gen)
    obs = rows[th.randint(0, 6, (64,), generator=gen)]
    k = 1
    # single-learner arithmetic: autograd through the whole batch
    logits, params = autograd_head(nets, "pi", obs.unsqueeze(0), slice(k, k + 1))
    old = logits.detach()
    mean_kl = categorical_kl(old[0].T, logits[0].T).mean()
    grad_kl = th.autograd.grad(mean_kl, params, create_graph=True)
    vector = [th.randn(p.shape, generator=gen) for p in params]
    hv = th.autograd.grad(sum((g * v).sum() for g, v in zip(grad_kl, vector)), params)
    expected = th.cat([h.reshape(-1) for h in hv])
    # fleet arithmetic: distinct observations, forward-mode product, one backward pass
    fleet = FleetCPO.__new__(FleetCPO)
    fleet.nets = nets
    fleet.actor_params = nets.params("pi")
    fleet._build_flats()
    states = DistinctStates.of(obs)
    data = RunBatch(k, states, th.zeros(64, dtype=th.long), th.zeros(64), th.zeros(64), th.zeros(64))
    tr = nets.trace("pi", states.obs.unsqueeze(0), slice(k, k + 1))
    product = fleet._fisher_product(data, tr, Policy.of(tr.out), damping=0.0)
    mine = product(fleet.flat_actor.flat([v for v in vector]))[0]
    np.testing.assert_allclose(mine.numpy(), expected.numpy(), rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("batch", [64, 8])
def test_a_run_computes_the_same_bits_alone_or_with_the_others(batch: int) -> None:
    """Whether the other runs of a fleet are computed too (all K) or left out (a gathered subset,
    as PPO-Lag does once most runs have stopped) does not change a run's numbers: runs stay
    independent bit for bit, whatever the others do."""
    nets = networks(runs=5)
    gen = th.Generator().manual_seed(9)
    x = th.randn(5, batch, 7, generator=gen)
    picked = th.tensor([1, 3])
    for head in ("pi", "vf"):
        full, sub = nets.trace(head, x), nets.trace(head, x[picked], picked)
        assert th.equal(full.out[picked], sub.out)
        dout = th.randn(full.out.shape, generator=gen)
        for a, b in zip(nets.backward(full, dout), nets.backward(sub, dout[picked])):
            assert th.equal(a[picked], b)
