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

import numpy as np
import torch as th

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
        lam32 = th.as_tensor(lam, dtype=th.float32, device=self.device).unsqueeze(1)
        one_plus = th.as_tensor(1.0 + lam, dtype=th.float32, device=self.device).unsqueeze(1)
        size, batch = ro.actions.shape[1], int(m.batch_size)
        clip_range, max_norm, ent_coef = float(m.clip_range), float(m.max_grad_norm), float(m.ent_coef)

        active = np.ones(k_runs, dtype=bool)
        passes = np.zeros(k_runs, dtype=np.int64)
        early = np.zeros(k_runs, dtype=bool)
        kl_tested = np.zeros(k_runs)
        kl_mean = np.zeros(k_runs)
        stats: list[tuple[np.ndarray, th.Tensor]] = []  # (runs computed, [5, R] policy/value/cost_value/entropy/clip_fraction)
        for _ in range(int(m.n_epochs)):
            if not active.any():
                break
            # The stopped runs are masked out of the optimiser steps. While at least half the runs
            # go on, every run is computed (a stopped run on its rollout in order, its results
            # dropped): cheaper than gathering the others' weights for every minibatch. Past that,
            # only the runs still passing are (``runs``: their indices). A stopped run draws no
            # further permutation either way.
            idx = np.flatnonzero(active)
            every = 2 * len(idx) >= k_runs
            mask = None if active.all() else active.copy()
            runs = None if every else self._tensor(idx)
            sub = slice(None) if runs is None else runs
            keep = self._tensor(idx) if every and mask is not None else None  # the computed runs' columns to record
            perms = {k: self.permutation(k, size) for k in idx}
            computed = range(k_runs) if every else idx
            order = self._tensor(np.stack([perms[k] if k in perms else np.arange(size) for k in computed]))
            for obs, actions, old_log_prob, adv, cadv, returns, cost_returns in ro.minibatches(
                order, batch, "obs", "actions", "log_probs", "advantages", "cost_advantages", "returns", "cost_returns", runs=runs
            ):
                actor = self.nets.trace("pi", obs, runs)
                policy = Policy.of(actor.out)
                ent = policy.entropy()
                advantages = (adv - lam32[sub] * cadv) / one_plus[sub]
                ratio = th.exp(policy.log_prob(actions) - old_log_prob)
                policy_loss, dratio = clipped_surrogate(ratio, advantages, clip_range)
                # total = policy_loss - ent_coef * mean(entropy) + critic losses
                dentropy = th.full_like(ratio, -ent_coef / ratio.shape[1]) if ent_coef else None
                actor_grads = self.nets.backward(actor, policy.dlogits(actions, dratio * ratio, dentropy))
                critic_grads, value_loss, cost_value_loss = self._critic_grads(obs, returns, cost_returns, runs)
                self._step_critics(critic_grads, critic_lr, mask)
                self.actor_optimizer.step(actor_grads, actor_lr, mask, max_norm=max_norm)  # type: ignore[arg-type]
                clip_fraction = ((ratio - 1.0).abs() > clip_range).float().mean(dim=1)
                values = th.stack([policy_loss, value_loss, cost_value_loss, ent.mean(dim=1), clip_fraction])
                stats.append((idx, values if keep is None else values[:, keep]))
            passes += active
            kl_sums = self._kl_sums(old_policies, idx.tolist())
            for k, total in kl_sums.items():
                kl_mean[k] = total / size
                kl_tested[k] = total if m.kl_early_stop_reduction == "sum" else total / size
            if m.target_kl is not None:
                stop = active & (kl_tested > m.target_kl)
                early |= stop
                active &= ~stop

        sums, counts = np.zeros((5, k_runs)), np.zeros(k_runs)
        for idx, values in stats:
            sums[:, idx] += values.double().cpu().numpy()
            counts[idx] += 1
        means = dict(zip(("policy", "value", "cost_value", "entropy", "clip_fraction"), sums / counts))
        for k in range(k_runs):
            self._row(
                k, mean_ep_costs[k], actor_lr, critic_lr,
                passes=int(passes[k]),
                kl=float(kl_tested[k]),
                kl_mean=float(kl_mean[k]),
                early_stopped=bool(early[k]),
                lagrange_multiplier=float(lam[k]),
                policy_loss=float(means["policy"][k]),
                value_loss=float(means["value"][k]),
                cost_value_loss=float(means["cost_value"][k]),
                entropy=float(means["entropy"][k]),
                clip_fraction=float(means["clip_fraction"][k]),
            )
