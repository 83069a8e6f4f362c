"""What the fleet's PPO-Lagrangian and CPO share (``CostOnPolicyAlgorithm``'s helpers, per run).

Separate actor and critic optimisers (Adam with the learner's ``adam_eps``), the critic loss with
its L2 penalty, per-critic (or joint) gradient clipping, the rollout-wide advantage normalisation,
the shuffled full batch and the critics' minibatch regression, each as the single learner computes
it for one run, here for all runs at once (with masks where runs may differ in what they do).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch as th

from morality_gym.baselines.fleet.base import FleetTrainer
from morality_gym.baselines.fleet.compiled import AdamConsts, Net, adam_rates, critic_step, mark_dynamic, mark_static
from morality_gym.baselines.fleet.losses import Policy, mse
from morality_gym.baselines.fleet.nets import Runs
from morality_gym.baselines.fleet.optim import BatchedAdam
from morality_gym.baselines.safe.functional import normalize_advantages


class FleetCostTrainer(FleetTrainer):
    heads = ("pi", "vf", "cf")
    cost_aware = True

    def _check_supported(self) -> None:
        policy = self.model.policy
        for name in ("optimizer", "critic_optimizer"):
            opt = getattr(policy, name)
            if type(opt) is not th.optim.Adam or opt.defaults.get("weight_decay", 0) or opt.defaults.get("amsgrad", False):
                raise self._unsupported(name, type(opt).__name__, "plain Adam")
        if getattr(policy, "share_features_extractor", False):
            raise self._unsupported("share_features_extractor", True, "only False")

    def _setup_optimisers(self) -> None:
        policy = self.model.policy
        self.actor_params = self.nets.params("pi")
        self.reward_critic_params = self.nets.params("vf")
        self.cost_critic_params = self.nets.params("cf")
        self.critic_params = self.reward_critic_params + self.cost_critic_params
        a, c = policy.optimizer.defaults, policy.critic_optimizer.defaults
        self.actor_optimizer = BatchedAdam(self.actor_params, self.n_runs, betas=a["betas"], eps=a["eps"], padded=self.nets.padded("pi"))
        self.critic_optimizer = BatchedAdam(self.critic_params, self.n_runs, betas=c["betas"], eps=c["eps"],
                                            padded=self.nets.padded("vf", "cf"))

    def _optimisers(self) -> dict[str, BatchedAdam]:
        return {"actor": self.actor_optimizer, "critic": self.critic_optimizer}

    @property
    def critic_net(self) -> Net:
        """The critics' static shape for the compiled steps (:mod:`.compiled`)."""
        return Net(tuple(self.spec.net_arch), (1, 1), self.spec.activation)

    @property
    def critic_adam(self) -> AdamConsts:
        """The critics' optimiser constants for the compiled steps: clipped per critic or jointly, with the L2 term."""
        opt, m = self.critic_optimizer, self.model
        split = len(self.reward_critic_params) if m.critic_grad_clip == "per_critic" else 0
        return AdamConsts(opt.beta1, opt.beta2, opt.eps, float(m.max_grad_norm), split, float(m.critic_l2_coef))

    def _export_optimisers(self, k: int, model: Any) -> None:
        self._export_adam(self.actor_optimizer, k, model.policy.optimizer, model.policy, ("pi",))
        self._export_adam(self.critic_optimizer, k, model.policy.critic_optimizer, model.policy, ("vf", "cf"))

    # ------------------------------------------------------------------ per-update helpers
    def _learning_rates(self, actor: bool = True) -> tuple[float | None, float]:
        """The model's own schedules at this update's progress (as its ``_update_learning_rates``),
        from :meth:`~morality_gym.baselines.safe.base.CostOnPolicyAlgorithm.learning_rates_at`;
        ``actor_lr`` is None when not asked for (CPO's actor takes trust-region steps)."""
        actor_lr, critic_lr = self.model.learning_rates_at(self.progress_remaining, self.total_timesteps)
        return (actor_lr if actor else None), critic_lr

    def _normalize_advantages(self) -> None:
        """``_normalize_rollout_advantages`` per run, over each run's ``(n_steps, n_envs)`` rollout."""
        ro, m, e = self.rollout, self.model, self.n_envs
        assert ro is not None
        for field, mode in (("advantages", m.reward_advantage_normalization), ("cost_advantages", m.cost_advantage_normalization)):
            raw = ro.raw[field]  # type: ignore[index]
            runs = [normalize_advantages(np.ascontiguousarray(raw[:, k * e : (k + 1) * e]), mode).T.reshape(-1) for k in range(self.n_runs)]
            setattr(ro, field, self._tensor(np.stack(runs)))

    def _draw_full_batch_order(self) -> None:
        """The permutation the single run's ``_full_batch`` draws. Its whole-rollout computations
        are sums over the rollout, whose order changes only float rounding (here they run over
        :meth:`distinct_states`), but the draw must be mirrored to keep each run's random stream."""
        ro = self.rollout
        assert ro is not None
        self.permutations(ro.actions.shape[1])

    def _critic_grads(
        self, obs: th.Tensor, returns: th.Tensor, cost_returns: th.Tensor, runs: Runs = None
    ) -> tuple[list[th.Tensor], th.Tensor, th.Tensor]:
        """Both critics' gradients of ``MSE(V, R) + MSE(V_c, R_c)`` (``vf`` then ``cf`` tensors, one
        row per computed run) and the two MSEs (``[R]``) of every run (or of ``runs``). The loss's
        L2 term is added by the optimiser step (:meth:`_step_critics`)."""
        reward, cost = self.nets.trace("vf", obs, runs), self.nets.trace("cf", obs, runs)
        value_loss, dvalues = mse(reward.out[:, 0], returns)
        cost_value_loss, dcost_values = mse(cost.out[:, 0], cost_returns)
        grads = self.nets.backward(reward, dvalues) + self.nets.backward(cost, dcost_values)
        return grads, value_loss, cost_value_loss

    def _step_critics(self, grads: Sequence[th.Tensor], critic_lr: float, mask: np.ndarray | None = None) -> None:
        """Add the gradient of the critic loss's ``critic_l2_coef * sum ||theta||^2``, clip per run
        (``critic_grad_clip``) and take one Adam step.

        Autograd computes that L2 gradient as ``coef * (2 * theta)`` in float32 (``mul``, then
        ``pow``'s backward) and adds it to the MSE path's gradient; the optimiser does the same on
        its flat buffers (``l2``): two operations instead of three per tensor."""
        n, total = len(self.reward_critic_params), len(self.critic_params)
        groups = [range(n), range(n, total)] if self.model.critic_grad_clip == "per_critic" else None
        self.critic_optimizer.step(
            grads, critic_lr, mask, max_norm=float(self.model.max_grad_norm), clip_groups=groups, l2=float(self.model.critic_l2_coef)
        )

    def _train_critics(self) -> tuple[np.ndarray, np.ndarray]:
        """``n_critic_updates`` passes of minibatch regression of both critics; per-run mean losses."""
        ro = self.rollout
        assert ro is not None
        _, critic_lr = self._learning_rates(actor=False)
        size, batch = ro.actions.shape[1], int(self.model.batch_size)
        losses = []
        step = self._compile(critic_step) if self.compiled else None
        lr_t = self._runs_tensor(critic_lr)
        opt = self.critic_optimizer
        if step is not None:
            mark_static(opt.flat, opt.exp_avg, opt.exp_avg_sq, opt._step_counts)
        for _ in range(int(self.model.n_critic_updates)):
            for obs, returns, cost_returns in ro.minibatches(self.permutations(size), batch, "obs", "returns", "cost_returns"):
                if step is not None:
                    mark_dynamic(obs, dims=(0, 1, 2))
                    mark_dynamic(opt.flat, opt.exp_avg, opt.exp_avg_sq, returns, cost_returns, dims=(0, 1))
                    rates = adam_rates(opt._step_counts, lr_t, None, self.critic_adam)
                    mark_dynamic(opt._step_counts, rates)
                    pair, grads = step(opt.flat, opt.exp_avg, opt.exp_avg_sq, opt._step_counts, obs, returns, cost_returns, rates,
                                       self.critic_net, self.critic_adam if self.in_graph else None)
                    if grads is not None:
                        self._step_critics(grads, critic_lr)
                    losses.append(pair)
                    continue
                grads, value_loss, cost_value_loss = self._critic_grads(obs, returns, cost_returns)
                self._step_critics(grads, critic_lr)
                losses.append(th.stack([value_loss, cost_value_loss]))
        per_batch = th.stack(losses).double().cpu().numpy()  # [batches, 2, K]
        return per_batch[:, 0].mean(axis=0), per_batch[:, 1].mean(axis=0)

    def _policies(self, runs: Sequence[int] | None = None) -> dict[int, Policy]:
        """The current actor of every run (or of ``runs``) at its rollout's distinct observations."""
        states = self.distinct_states()
        return {
            k: Policy.of(self.nets("pi", states[k].obs.unsqueeze(0), slice(k, k + 1)))
            for k in (range(self.n_runs) if runs is None else runs)
        }

    def _kl_sums(self, old: dict[int, Policy], runs: Sequence[int]) -> dict[int, float]:
        """Per run of ``runs``: the KL of its current actor from ``old``, summed over its rollout's
        transitions (a mean over them is this divided by the rollout size)."""
        states = self.distinct_states()
        new = self._policies(runs)
        return {k: float((new[k].kl_from(old[k])[0] * states[k].counts).sum(dtype=th.float64)) for k in runs}

    def _row(self, k: int, ep_cost: float, actor_lr: float | None, critic_lr: float, **fields: Any) -> None:
        """Append run ``k``'s diagnostics row (``CostOnPolicyAlgorithm._record_update``)."""
        row: dict[str, Any] = {
            "update": len(self.update_logs[k]) + 1,
            "timesteps": int(self.num_timesteps),
            "ep_cost": float(ep_cost),
            "ep_cost_episodes": len(self.ep_cost_buffers[k]),
            "actor_lr": actor_lr,
            "critic_lr": critic_lr,
        }
        row.update(fields)
        self.update_logs[k].append(row)
