"""PPO and PPO-Shaped for a fleet: Stable-Baselines3's ``PPO.train`` for K runs at once.

Per epoch each run draws its own permutation of its rollout (its single run's
``np.random.permutation``) and walks it in minibatches of ``batch_size``; on every minibatch each
run's advantages are standardised over its minibatch (``normalize_advantage``), and its loss
``policy + ent_coef * entropy + vf_coef * value`` is differentiated with respect to its own slice
of the stacked actor and critic, clipped by its own gradient norm over all of its parameters
(SB3's ``clip_grad_norm_(policy.parameters())``) and stepped by its own Adam (SB3's eps 1e-5). The
gradients are the loss's closed-form gradient with respect to the logits and values
(:mod:`.losses`), back-propagated by hand through the stacked networks (:mod:`.nets`).
PPO-Shaped differs from PPO only in the reward the environment hands out (:mod:`.env`).

As the single learner, PPO logs no per-update diagnostics rows.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th

from morality_gym.baselines.fleet.base import FleetTrainer
from morality_gym.baselines.fleet.compiled import AdamConsts, Net, adam_rates, mark_dynamic, mark_static, ppo_step
from morality_gym.baselines.fleet.losses import Policy, clipped_surrogate, mse
from morality_gym.baselines.fleet.optim import BatchedAdam
from morality_gym.baselines.specs import SB3_PPO


class FleetPPO(FleetTrainer):
    algorithm = SB3_PPO
    heads = ("pi", "vf")

    def _check_supported(self) -> None:
        m = self.model
        if m.clip_range_vf is not None:
            raise self._unsupported("clip_range_vf", m.clip_range_vf, "only None")
        if m.target_kl is not None:
            raise self._unsupported("target_kl", m.target_kl, "only None")
        if m.use_sde:
            raise self._unsupported("use_sde", m.use_sde, "only False")
        if type(m.policy.optimizer) is not th.optim.Adam:
            raise self._unsupported("optimizer", type(m.policy.optimizer).__name__, "only Adam")

    def _setup_optimisers(self) -> None:
        defaults = self.model.policy.optimizer.defaults
        if defaults.get("weight_decay", 0) or defaults.get("amsgrad", False):
            raise self._unsupported("optimizer_kwargs", defaults, "plain Adam")
        self.params = self.nets.params("pi", "vf")
        self.optimizer = BatchedAdam(self.params, self.n_runs, betas=defaults["betas"], eps=defaults["eps"],
                                     padded=self.nets.padded("pi", "vf"))

    def _optimisers(self) -> dict[str, BatchedAdam]:
        return {"policy": self.optimizer}

    def _export_optimisers(self, k: int, model: Any) -> None:
        self._export_adam(self.optimizer, k, model.policy.optimizer, model.policy, ("pi", "vf"))

    def _train(self) -> None:
        m, ro = self.model, self.rollout
        assert ro is not None
        lr = np.full(self.n_runs, float(m.lr_schedule(self.progress_remaining)))
        clip_range = float(m.clip_range(self.progress_remaining))
        ent_coef, vf_coef = float(m.ent_coef), float(m.vf_coef)
        size = ro.actions.shape[1]
        batch = int(m.batch_size)
        if self.compiled:
            self._train_compiled(lr, clip_range)
            return
        for _ in range(int(m.n_epochs)):
            for obs, actions, old_log_prob, advantages, returns in ro.minibatches(
                self.permutations(size), batch, "obs", "actions", "log_probs", "advantages", "returns"
            ):
                actor = self.nets.trace("pi", obs)
                critic = self.nets.trace("vf", obs)
                policy = Policy.of(actor.out)
                if m.normalize_advantage and advantages.shape[1] > 1:
                    advantages = (advantages - advantages.mean(dim=1, keepdim=True)) / (advantages.std(dim=1, keepdim=True) + 1e-8)
                ratio = th.exp(policy.log_prob(actions) - old_log_prob)
                _, dratio = clipped_surrogate(ratio, advantages, clip_range)
                # loss = policy + ent_coef * (-mean entropy) + vf_coef * value
                dentropy = th.full_like(ratio, -ent_coef / ratio.shape[1]) if ent_coef else None
                dlogits = policy.dlogits(actions, dratio * ratio, dentropy)
                _, dvalues = mse(critic.out[:, 0], returns)
                grads = self.nets.backward(actor, dlogits) + self.nets.backward(critic, dvalues.mul_(vf_coef))
                self.optimizer.step(grads, lr, max_norm=float(m.max_grad_norm))  # clipped per run over all parameters

    def _train_compiled(self, lr: np.ndarray, clip_range: float) -> None:
        """The same passes with every minibatch one compiled step (:func:`~.compiled.ppo_step`)."""
        m, ro, opt = self.model, self.rollout, self.optimizer
        assert ro is not None
        step = self._compile(ppo_step)
        net = Net(tuple(self.spec.net_arch), (6, 1), self.spec.activation)
        adam = AdamConsts(opt.beta1, opt.beta2, opt.eps, float(m.max_grad_norm), 0, 0.0)
        lr_t, clip_t = self._runs_tensor(lr), th.tensor(clip_range, dtype=th.float32, device=self.device)
        ent_coef, vf_coef = float(m.ent_coef), float(m.vf_coef)
        mark_static(opt.flat, opt.exp_avg, opt.exp_avg_sq, opt._step_counts)
        for _ in range(int(m.n_epochs)):
            for obs, actions, old_log_prob, advantages, returns in ro.minibatches(
                self.permutations(ro.actions.shape[1]), int(m.batch_size), "obs", "actions", "log_probs", "advantages", "returns"
            ):
                mark_dynamic(obs, dims=(0, 1, 2))
                mark_dynamic(opt.flat, opt.exp_avg, opt.exp_avg_sq, actions, old_log_prob, advantages, returns, dims=(0, 1))
                rates = adam_rates(opt._step_counts, lr_t, None, adam)
                mark_dynamic(opt._step_counts, rates)
                grads = step(opt.flat, opt.exp_avg, opt.exp_avg_sq, opt._step_counts, obs, actions, old_log_prob, advantages,
                             returns, rates, clip_t, net, adam if self.in_graph else None, ent_coef, vf_coef,
                             bool(m.normalize_advantage and advantages.shape[1] > 1))
                if grads is not None:
                    opt.step(grads, lr, max_norm=float(m.max_grad_norm))
