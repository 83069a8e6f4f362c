"""CPO for a fleet: :class:`~morality_gym.baselines.safe.cpo.CPO`'s update, K runs at once.

Per run, as the single learner: the reward and cost surrogate gradients ``g`` and ``b``, conjugate
gradients on Fisher-vector products for ``v = H^-1 g`` and ``w = H^-1 b``, the case and full step
of :mod:`~morality_gym.baselines.safe.cpo_dual` (``dual_solution``), the backtracking line search
with its acceptance rule, then the critics' regression (batched over the runs).

The actor step works on each run's rollout as its distinct observations (:mod:`.dedup`): every
whole-rollout quantity of CPO is a mean over transitions of something that depends on the state
only through the actor's logits there, so it is computed at the distinct observations and weighted
by their counts:

* ``g`` and ``b``: the surrogates' gradients with respect to the logits are summed per distinct
  observation (``(A_t rho_t / N) (onehot(a_t) - p)`` over its transitions), then back-propagated
  through the actor once, both at once;
* ``H v``: at the current actor (where the single learner's double backward through the mean KL
  is taken) the Hessian of the mean KL is the Fisher matrix ``sum_s w_s J_s^T (diag p_s - p_s
  p_s^T) J_s``, ``J_s`` the Jacobian of the logits at observation ``s`` and ``w_s`` its share of the
  rollout; it is applied as a forward-mode product ``J v`` (:meth:`~.nets.FleetNetworks.jvp`), the
  per-state matrix, and one backward pass, for ``g`` and ``b``'s solves together;
* the line search's surrogates and KL, and the diagnostics' ``kl_mean``.

The same matrices and vectors as the single learner's, up to the order of float additions, on a
tenth to a hundredth of the rows: the conjugate gradients, which dominated a CPO update, no longer
do. Each run is computed on its own (its number of distinct observations is its own), so no run's
arithmetic depends on another's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch as th

from morality_gym.baselines.fleet.cost_base import FleetCostTrainer
from morality_gym.baselines.fleet.cpo_batch import BatchedActorStep
from morality_gym.baselines.fleet.cpo_math import (
    ActorStep,
    FlatActor,
    Operator,
    conjugate_gradient,
    fisher_product,
    judge_candidate,
    new_search,
)
from morality_gym.baselines.fleet.dedup import DistinctStates
from morality_gym.baselines.fleet.losses import Policy
from morality_gym.baselines.fleet.nets import Trace
from morality_gym.baselines.safe.cpo_dual import (
    CPOScalars,
    CPOStep,
    exact_direction,
    omnisafe_direction,
)
from morality_gym.baselines.specs import CPO


@dataclass
class RunBatch:
    """One run's rollout for its actor step: its distinct observations and, per transition, the
    action, the rollout's log-probability and the (normalised) reward and cost advantages."""

    k: int
    states: DistinctStates
    actions: th.Tensor
    old_log_prob: th.Tensor
    advantages: th.Tensor
    cost_advantages: th.Tensor

    @property
    def size(self) -> int:
        return int(self.actions.shape[0])

    def log_prob(self, policy: Policy) -> th.Tensor:
        """``[N]``: each transition's action log-probability under ``policy`` (at the distinct states)."""
        return policy.logp[0][self.actions, self.states.inverse]


@dataclass
class Evaluation:
    """The actor of one run at its distinct states: its policy, the surrogates ``L_r`` and ``L_c``,
    and whether its distribution can be built (no NaN log-probabilities; the single learner's
    ``Categorical`` raises ``ValueError`` there)."""

    policy: Policy
    reward: float
    cost: float
    valid: bool


class FleetCPO(FleetCostTrainer):
    algorithm = CPO

    #: Whether the actor steps run all at once (:mod:`.cpo_batch`): ``None`` does so on accelerators,
    #: where the per-run path is launch-bound; the per-run path keeps the CPU's (and the release's) bits.
    batched_actor_step: bool | None = None

    def _setup_optimisers(self) -> None:
        super()._setup_optimisers()
        self._build_flats()

    def _build_flats(self) -> None:
        """The actor's flat-vector layout (:class:`~.cpo_math.FlatActor`), from :attr:`actor_params`."""
        self.flat_actor = FlatActor(self.actor_params)
        #: Per observation width, the flat vectors of a run of that width (its own first-layer columns).
        self._flats = {d: FlatActor(self.actor_params, d) for d in set(self.nets.in_dims)}

    def _flat_of(self, k: int) -> FlatActor:
        return self._flats[self.nets.in_dims[k]]

    def _actor(self, k: int) -> th.Tensor:
        """Run ``k``'s actor parameters as one vector (a view: writing it moves the actor)."""
        return self.actor_optimizer.flat[k]

    # ------------------------------------------------------------------ per run
    def _batch(self, k: int) -> RunBatch:
        ro = self.rollout
        assert ro is not None and ro.cost_advantages is not None
        return RunBatch(k, self.distinct_states()[k], ro.actions[k], ro.log_probs[k], ro.advantages[k], ro.cost_advantages[k])

    def _evaluate(self, data: RunBatch) -> Evaluation:
        """``CPO._surrogate_losses`` of run ``data.k``'s current actor."""
        policy = Policy.of(self.nets("pi", data.states.obs.unsqueeze(0), slice(data.k, data.k + 1)))
        ratio = th.exp(data.log_prob(policy) - data.old_log_prob)
        valid = not bool(th.isnan(policy.logp).any())
        return Evaluation(policy, (ratio * data.advantages).mean().item(), (ratio * data.cost_advantages).mean().item(), valid)

    def _mean_kl(self, data: RunBatch, old: Policy, new: Policy) -> float:
        """The mean over the rollout's transitions of ``KL(old || new)`` at their states."""
        return (new.kl_from(old)[0] * data.states.weights).sum().item()

    def _gradients(self, data: RunBatch, actor: Trace, policy: Policy) -> th.Tensor:
        """``[2, D]``: ``g`` and ``b``, the gradients of ``mean(rho A_r)`` and ``mean(rho A_c)`` at
        the current actor (``rho = exp(log pi - log pi_rollout)``, about 1 there), as one
        back-propagation of both logit gradients summed per distinct observation."""
        n_actions, n_states = policy.p.shape[1], data.states.n
        ratio = th.exp(data.log_prob(policy) - data.old_log_prob)
        coef = th.stack([ratio * data.advantages, ratio * data.cost_advantages]) / data.size  # d L / d log pi(a_t|s_t)
        cell = data.actions * n_states + data.states.inverse
        onehot = th.zeros(2, n_actions * n_states, device=coef.device).index_add_(1, cell, coef).view(2, n_actions, n_states)
        per_state = th.zeros(2, n_states, device=coef.device).index_add_(1, data.states.inverse, coef)
        dlogits = onehot.sub_(policy.p * per_state.unsqueeze(1))
        return self._flat_of(data.k).flat(self.nets.backward(actor, dlogits))

    def _fisher_product(self, data: RunBatch, actor: Trace, policy: Policy, damping: float) -> Operator:
        """``V -> H V + damping V`` for vectors ``V`` (``[R, D]``), ``H`` the Fisher matrix of the
        mean KL at the current actor (the module docstring)."""
        return fisher_product(self.nets, self._flat_of(data.k), actor, policy, data.states.weights.unsqueeze(0), damping)

    def _conjugate_gradient(self, fvp: Operator, b: th.Tensor) -> th.Tensor:
        m = self.model
        return conjugate_gradient(fvp, b, int(m.cg_max_steps), float(m.cg_eps), float(m.cg_residual_tol))

    def _step_direction(self, data: RunBatch, c: float) -> tuple[CPOStep, th.Tensor, CPOScalars, Policy]:
        """``CPO._step_direction`` for one run: ``(step, g, scalars, the policy at theta_old)``."""
        m = self.model
        actor = self.nets.trace("pi", data.states.obs.unsqueeze(0), slice(data.k, data.k + 1))
        policy = Policy.of(actor.out)
        gb = self._gradients(data, actor, policy)
        fvp = self._fisher_product(data, actor, policy, float(m.cg_damping))
        vw = self._conjugate_gradient(fvp, gb)  # v = H^-1 g and w = H^-1 b, solved together
        g, b, v, w = gb[0], gb[1], vw[0], vw[1]
        vhv = (v @ fvp(v.unsqueeze(0))[0]).item()
        sc = CPOScalars(q=vhv, r=(g @ w).item(), s=(b @ w).item(), c=c, delta=float(m.target_kl), bb=(b @ b).item())
        direction_of = omnisafe_direction if m.dual_solution == "omnisafe" else exact_direction
        step = direction_of(v, w, sc, vhv)
        if m.trust_region_rescale and step.direction.abs().sum() > 0:
            quad = (step.direction @ fvp(step.direction.unsqueeze(0))[0]).item()
            if quad > 2 * m.target_kl:
                scaled = step.direction * math.sqrt(2 * m.target_kl / quad)
                step = CPOStep(scaled, step.case, step.lam, step.nu, step.A, step.B)
        return step, g, sc, policy

    def _line_search(self, data: RunBatch, old: Policy, step: CPOStep, g: th.Tensor, c: float) -> dict[str, float]:
        """``CPO._line_search`` for one run; leaves its actor at the accepted point (or unchanged)."""
        m = self.model
        theta = self._actor(data.k)
        theta_old = theta.clone()
        direction = self._flat_of(data.k).expand(step.direction)  # the buffer's layout
        start = self._evaluate(data)
        expected = (g @ step.direction).item()
        result = new_search()
        fraction = 1.0
        for j in range(int(m.line_search_max_iter)):
            theta.copy_(theta_old + fraction * direction)
            new = self._evaluate(data)
            kl = self._mean_kl(data, old, new.policy) if new.valid else math.nan
            accepted, next_fraction = judge_candidate(m, step, result, j, fraction, new.valid, kl,
                                                      new.reward - start.reward, new.cost - start.cost, c, expected)
            if accepted:
                theta.copy_(theta_old + fraction * direction)
                return result
            fraction = next_fraction
        theta.copy_(theta_old)
        result.update(d_reward=0.0, d_cost=0.0)
        return result

    # ------------------------------------------------------------------ update
    def _actor_step(self, k: int, c: float) -> ActorStep:
        """Run ``k``'s actor step on its own (the per-run path), its actor moved."""
        data = self._batch(k)
        step, g, sc, old = self._step_direction(data, c)
        search = self._line_search(data, old, step, g, c)
        kl_mean = self._mean_kl(data, old, self._evaluate(data).policy)
        taken = search["fraction"] * step.direction
        return ActorStep(step, sc, search, kl_mean, step.direction.norm().item(), taken.norm().item(), (g @ taken).item())

    def _batched(self) -> bool:
        return self.device.type != "cpu" if self.batched_actor_step is None else self.batched_actor_step

    def _train(self) -> None:
        m = self.model
        _, critic_lr = self._learning_rates(actor=False)
        mean_ep_costs = self.mean_episode_costs()
        c = mean_ep_costs - float(m.cost_limit)
        self._normalize_advantages()
        self._draw_full_batch_order()
        with th.no_grad():
            if self._batched():
                ro = self.rollout
                assert ro is not None and ro.cost_advantages is not None
                batch = BatchedActorStep(self.nets, m, self.flat_actor, self.actor_optimizer.flat, self.distinct_states(),
                                         ro.actions, ro.log_probs, ro.advantages, ro.cost_advantages)
                steps = batch.run(c)
            else:
                steps = [self._actor_step(k, float(c[k])) for k in range(self.n_runs)]
        value_loss, cost_value_loss = self._train_critics()
        for k, a in enumerate(steps):
            step, sc, search = a.step, a.scalars, a.search
            self._row(
                k, mean_ep_costs[k], None, critic_lr,
                kl=search["kl"],
                kl_mean=a.kl_mean,
                cpo_case=int(step.case),
                accept_step=int(search["accept_step"]),
                line_search_tried=int(search["tried"]),
                step_fraction=search["fraction"],
                lambda_star=step.lam,
                nu_star=step.nu,
                A=step.A,
                B=step.B,
                q=sc.q,
                r=sc.r,
                s=sc.s,
                c=float(c[k]),
                b_norm=math.sqrt(max(sc.bb, 0.0)),
                full_step_norm=a.full_step_norm,
                step_norm=a.step_norm,
                expected_reward_change=a.expected_reward_change,
                surrogate_reward_change=search["d_reward"],
                surrogate_cost_change=search["d_cost"],
                value_loss=float(value_loss[k]),
                cost_value_loss=float(cost_value_loss[k]),
            )
