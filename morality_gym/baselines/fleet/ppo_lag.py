"""PPO-Lagrangian for a fleet: :class:`~morality_gym.baselines.safe.ppo_lag.PPOLag`'s update, K runs at once.

Per run, as the single learner: one projected Adam step of its multiplier on its own ``J_c``, then
up to ``n_epochs`` passes of clipped-surrogate minibatches with the combined advantage
``(A_r - lambda A_c) / (1 + lambda)``, both critics and the actor stepped on every minibatch with
their own clipping. After each pass each run tests its own KL (summed or averaged over its states);
a run whose KL exceeds ``target_kl`` is masked out of the passes that follow (no parameter, Adam
moment or step count of it changes, and it draws no further permutation) while the others go on;
once fewer than half the runs go on, the passes compute only those. The KL is computed on each
rollout's distinct observations (:mod:`.dedup`).
The loop ends when every run has stopped or ``n_epochs`` passes are done.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch as th

from morality_gym.baselines.fleet.compiled import AdamConsts, Net, adam_rates, lag_step, mark_dynamic, mark_static
from morality_gym.baselines.fleet.cost_base import FleetCostTrainer
from morality_gym.baselines.fleet.losses import Policy, clipped_surrogate
from morality_gym.baselines.fleet.optim import BatchedAdam
from morality_gym.baselines.specs import PPO_LAG


class FleetPPOLag(FleetCostTrainer):
    algorithm = PPO_LAG

    def _setup_optimisers(self) -> None:
        super()._setup_optimisers()
        lagrange = self.model.lagrange
        if type(lagrange.optimizer) is not th.optim.Adam:
            raise self._unsupported("lagrange optimizer", type(lagrange.optimizer).__name__, "only Adam")
        d = lagrange.optimizer.defaults
        self.lagrange_lr = float(d["lr"])
        self.lagrange_upper = lagrange.upper_bound
        self.lagrange = th.stack([learner.model.lagrange.value_param.detach().clone() for learner in self._learners]).to(self.device)
        self.lagrange_optimizer = BatchedAdam([self.lagrange], self.n_runs, betas=d["betas"], eps=d["eps"])

    def _optimisers(self) -> dict[str, BatchedAdam]:
        return {**super()._optimisers(), "lagrange": self.lagrange_optimizer}

    def _extra_state(self) -> dict[str, th.Tensor]:
        """The runs' multipliers (the Lagrange optimiser's parameter)."""
        return {"lagrange": self.lagrange.detach().cpu().clone()}

    @th.no_grad()
    def _load_extra_state(self, state: dict[str, th.Tensor]) -> None:
        """In place: :attr:`lagrange` is a view into its optimiser's flat buffer."""
        value = state["lagrange"]
        if value.shape != self.lagrange.shape:
            raise ValueError(f"multipliers: expected shape {tuple(self.lagrange.shape)}, got {tuple(value.shape)}")
        self.lagrange.copy_(value)

    def _export_optimisers(self, k: int, model: object) -> None:
        super()._export_optimisers(k, model)
        lag = model.lagrange  # type: ignore[attr-defined]
        with th.no_grad():
            lag.value_param.copy_(self.lagrange[k])
        lag.optimizer.state.clear()
        state = {key: value.cpu() for key, value in self.lagrange_optimizer.state_of(k)[0].items()}
        if float(state["step"]) > 0:
            lag.optimizer.state[lag.value_param] = state

    def _update_multipliers(self, mean_ep_costs: np.ndarray) -> np.ndarray:
        """``LagrangeMultiplier.update`` per run; returns every run's new ``lambda`` (float64)."""
        violation = th.as_tensor(mean_ep_costs - float(self.model.cost_limit), dtype=th.float32, device=self.device)
        self.lagrange_optimizer.step([-violation], self.lagrange_lr)  # d(-lambda * v)/d lambda
        with th.no_grad():
            self.lagrange.clamp_(min=0.0, max=self.lagrange_upper)
        return self.lagrange.double().cpu().numpy().copy()

    def _train(self) -> None:
        m, ro, k_runs = self.model, self.rollout, self.n_runs
        assert ro is not None
        actor_lr, critic_lr = self._learning_rates(actor=True)
        mean_ep_costs = self.mean_episode_costs()
        lam = self._update_multipliers(mean_ep_costs)
        self._normalize_advantages()
        self._draw_full_batch_order()
        old_policies = self._policies()
        step = _PassSettings(
            lam32=th.as_tensor(lam, dtype=th.float32, device=self.device).unsqueeze(1),
            one_plus=th.as_tensor(1.0 + lam, dtype=th.float32, device=self.device).unsqueeze(1),
            actor_lr=actor_lr, critic_lr=critic_lr, size=int(ro.actions.shape[1]), batch=int(m.batch_size),
            clip_range=float(m.clip_range), max_norm=float(m.max_grad_norm), ent_coef=float(m.ent_coef),
        )
        passes = _Passes.start(k_runs)
        for _ in range(int(m.n_epochs)):
            if not passes.active.any():
                break
            passes.stats += self._one_pass(passes.active, step)
            passes.count += passes.active
            self._test_kl(passes, old_policies, step.size)
        self._record_rows(passes, mean_ep_costs, lam, actor_lr, critic_lr)

    def _one_pass(self, active: np.ndarray, step: _PassSettings) -> list[tuple[np.ndarray, th.Tensor]]:
        """One pass over the rollout in minibatches for the runs still ``active``; per minibatch,
        the computed runs and their ``[5, R]`` policy/value/cost_value/entropy/clip_fraction.

        The stopped runs are masked out of the optimiser steps. While at least half the runs go on,
        every run is computed (a stopped run on its rollout in order, its results dropped): cheaper
        than gathering the others' weights for every minibatch. Past that, only the runs still
        passing are (``runs``: their indices). A stopped run draws no further permutation either way.
        """
        if self.compiled:
            return self._one_pass_compiled(active, step)
        ro, k_runs = self.rollout, self.n_runs
        assert ro is not None
        idx = np.flatnonzero(active)
        every = 2 * len(idx) >= k_runs
        mask = None if active.all() else active.copy()
        runs = None if every else self._tensor(idx)
        sub = slice(None) if runs is None else runs
        keep = self._tensor(idx) if every and mask is not None else None  # the computed runs' columns to record
        perms = {k: self.permutation(k, step.size) for k in idx}
        computed = range(k_runs) if every else idx
        order = self._tensor(np.stack([perms[k] if k in perms else np.arange(step.size) for k in computed]))
        stats = []
        for obs, actions, old_log_prob, adv, cadv, returns, cost_returns in ro.minibatches(
            order, step.batch, "obs", "actions", "log_probs", "advantages", "cost_advantages", "returns", "cost_returns", runs=runs
        ):
            actor = self.nets.trace("pi", obs, runs)
            policy = Policy.of(actor.out)
            ent = policy.entropy()
            advantages = (adv - step.lam32[sub] * cadv) / step.one_plus[sub]
            ratio = th.exp(policy.log_prob(actions) - old_log_prob)
            policy_loss, dratio = clipped_surrogate(ratio, advantages, step.clip_range)
            # total = policy_loss - ent_coef * mean(entropy) + critic losses
            dentropy = th.full_like(ratio, -step.ent_coef / ratio.shape[1]) if step.ent_coef else None
            actor_grads = self.nets.backward(actor, policy.dlogits(actions, dratio * ratio, dentropy))
            critic_grads, value_loss, cost_value_loss = self._critic_grads(obs, returns, cost_returns, runs)
            self._step_critics(critic_grads, step.critic_lr, mask)
            self.actor_optimizer.step(actor_grads, step.actor_lr, mask, max_norm=step.max_norm)  # type: ignore[arg-type]
            clip_fraction = ((ratio - 1.0).abs() > step.clip_range).float().mean(dim=1)
            values = th.stack([policy_loss, value_loss, cost_value_loss, ent.mean(dim=1), clip_fraction])
            stats.append((idx, values if keep is None else values[:, keep]))
        return stats

    def _one_pass_compiled(self, active: np.ndarray, step: _PassSettings) -> list[tuple[np.ndarray, th.Tensor]]:
        """:meth:`_one_pass` with every minibatch one compiled step (:func:`~.compiled.lag_step`):
        every run is computed (static shapes), the stopped ones masked out of the optimiser steps."""
        ro = self.rollout
        assert ro is not None and step.actor_lr is not None
        idx = np.flatnonzero(active)
        perms = {k: self.permutation(k, step.size) for k in idx}
        order = self._tensor(np.stack([perms[k] if k in perms else np.arange(step.size) for k in range(self.n_runs)]))
        keep = None if active.all() else self._tensor(idx)
        mask = None if active.all() else active.copy()
        run = self._compile(lag_step)
        a_opt, c_opt = self.actor_optimizer, self.critic_optimizer
        actor_net = Net(tuple(self.spec.net_arch), (6,), self.spec.activation)
        actor_adam = AdamConsts(a_opt.beta1, a_opt.beta2, a_opt.eps, step.max_norm, 0, 0.0)
        live = self._runs_tensor(active, th.bool)
        actor_lr, critic_lr = self._runs_tensor(step.actor_lr), self._runs_tensor(step.critic_lr)
        clip = th.tensor(step.clip_range, dtype=th.float32, device=self.device)
        mark_static(a_opt.flat, a_opt.exp_avg, a_opt.exp_avg_sq, a_opt._step_counts, c_opt.flat, c_opt.exp_avg, c_opt.exp_avg_sq,
                    c_opt._step_counts)
        stats = []
        for fields in ro.minibatches(order, step.batch, "obs", "actions", "log_probs", "advantages", "cost_advantages", "returns",
                                     "cost_returns"):
            mark_dynamic(fields[0], dims=(0, 1, 2))
            mark_dynamic(a_opt.flat, a_opt.exp_avg, a_opt.exp_avg_sq, c_opt.flat, c_opt.exp_avg, c_opt.exp_avg_sq, *fields[1:],
                         dims=(0, 1))
            actor_rates = adam_rates(a_opt._step_counts, actor_lr, live, actor_adam)
            critic_rates = adam_rates(c_opt._step_counts, critic_lr, live, self.critic_adam)
            mark_dynamic(a_opt._step_counts, c_opt._step_counts, step.lam32, step.one_plus, actor_rates, critic_rates, live)
            in_graph = self.in_graph
            values, actor_grads, critic_grads = run(
                a_opt.flat, a_opt.exp_avg, a_opt.exp_avg_sq, a_opt._step_counts, c_opt.flat, c_opt.exp_avg, c_opt.exp_avg_sq,
                c_opt._step_counts, *fields, step.lam32, step.one_plus, actor_rates, critic_rates, clip, live, actor_net, self.critic_net,
                actor_adam if in_graph else None, self.critic_adam if in_graph else None, step.ent_coef)
            if actor_grads is not None and critic_grads is not None:
                self._step_critics(critic_grads, step.critic_lr, mask)
                a_opt.step(actor_grads, step.actor_lr, mask, max_norm=step.max_norm)
            stats.append((idx, values if keep is None else values[:, keep]))
        return stats

    def _test_kl(self, passes: _Passes, old_policies: dict[int, Policy], size: int) -> None:
        """After a pass: each active run's KL from its rollout policy, and the early stop of those above ``target_kl``."""
        m = self.model
        for k, total in self._kl_sums(old_policies, np.flatnonzero(passes.active).tolist()).items():
            passes.kl_mean[k] = total / size
            passes.kl_tested[k] = total if m.kl_early_stop_reduction == "sum" else total / size
        if m.target_kl is not None:
            stop = passes.active & (passes.kl_tested > m.target_kl)
            passes.early |= stop
            passes.active &= ~stop

    def _record_rows(self, passes: _Passes, mean_ep_costs: np.ndarray, lam: np.ndarray, actor_lr: float | None,
                     critic_lr: float) -> None:
        """Each run's diagnostics row: the update's passes, KL, multiplier and mean losses."""
        sums, counts = np.zeros((5, self.n_runs)), np.zeros(self.n_runs)
        for idx, values in passes.stats:
            sums[:, idx] += values.double().cpu().numpy()
            counts[idx] += 1
        means = dict(zip(("policy", "value", "cost_value", "entropy", "clip_fraction"), sums / counts))
        for k in range(self.n_runs):
            self._row(
                k, mean_ep_costs[k], actor_lr, critic_lr,
                passes=int(passes.count[k]),
                kl=float(passes.kl_tested[k]),
                kl_mean=float(passes.kl_mean[k]),
                early_stopped=bool(passes.early[k]),
                lagrange_multiplier=float(lam[k]),
                policy_loss=float(means["policy"][k]),
                value_loss=float(means["value"][k]),
                cost_value_loss=float(means["cost_value"][k]),
                entropy=float(means["entropy"][k]),
                clip_fraction=float(means["clip_fraction"][k]),
            )


@dataclass(frozen=True)
class _PassSettings:
    """What every minibatch of an update reads: the multipliers (float32 columns), the learning
    rates and the model's constants for this update."""

    lam32: th.Tensor
    one_plus: th.Tensor
    actor_lr: float | None
    critic_lr: float
    size: int
    batch: int
    clip_range: float
    max_norm: float
    ent_coef: float


@dataclass
class _Passes:
    """Per run, over an update's passes: still passing, passes made, stopped early, the last KL
    tested and its mean, and every minibatch's statistics."""

    active: np.ndarray
    count: np.ndarray
    early: np.ndarray
    kl_tested: np.ndarray
    kl_mean: np.ndarray
    stats: list[tuple[np.ndarray, th.Tensor]]

    @classmethod
    def start(cls, n_runs: int) -> _Passes:
        return cls(np.ones(n_runs, dtype=bool), np.zeros(n_runs, dtype=np.int64), np.zeros(n_runs, dtype=bool),
                   np.zeros(n_runs), np.zeros(n_runs), [])
