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

from morality_gym.baselines.fleet.base import FleetTrainer, categorical
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
        self.actor_optimizer = BatchedAdam(self.actor_params, self.n_runs, betas=a["betas"], eps=a["eps"])
        self.critic_optimizer = BatchedAdam(self.critic_params, self.n_runs, betas=c["betas"], eps=c["eps"])

    def _export_optimisers(self, k: int, model: Any) -> None:
        self._export_adam(self.actor_optimizer, k, model.policy.optimizer, model.policy, ("pi",))
        self._export_adam(self.critic_optimizer, k, model.policy.critic_optimizer, model.policy, ("vf", "cf"))

    # ------------------------------------------------------------------ per-update helpers
    def _learning_rates(self, actor: bool = True) -> tuple[float | None, float]:
        """The model's own schedules at this update's progress (``_update_learning_rates``)."""
        m = self.model
        m._current_progress_remaining = self.progress_remaining
        m._total_timesteps = self.total_timesteps
        progress = m._schedule_progress()
        actor_lr = float(m.lr_schedule(progress)) if actor else None
        return actor_lr, float(m.critic_lr_schedule(progress))

    def _normalize_advantages(self) -> None:
        """``_normalize_rollout_advantages`` per run, over each run's ``(n_steps, n_envs)`` rollout."""
        ro, m, e = self.rollout, self.model, self.n_envs
        assert ro is not None
        for field, mode in (("advantages", m.reward_advantage_normalization), ("cost_advantages", m.cost_advantage_normalization)):
            raw = self._rollout_raw[field]
            runs = [normalize_advantages(np.ascontiguousarray(raw[:, k * e : (k + 1) * e]), mode).T.reshape(-1) for k in range(self.n_runs)]
            setattr(ro, field, th.from_numpy(np.stack(runs)))

    def _full_batch(self, *names: str) -> list[th.Tensor]:
        """Each run's whole rollout (the named fields) in the order of its single run's
        ``_full_batch``, which draws a permutation: it only changes the order of sums, but the draw
        must be mirrored to keep the run's random stream."""
        ro = self.rollout
        assert ro is not None
        return ro.gather(self.permutations(ro.actions.shape[1]), *names)

    def _critic_loss(
        self, obs: th.Tensor, returns: th.Tensor, cost_returns: th.Tensor, runs: th.Tensor | None = None
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """Per run ``[K]`` (or per run of ``runs``): ``(MSE(V, R) + MSE(V_c, R_c), MSE(V, R), MSE(V_c, R_c))``.

        The single learner's loss also has ``critic_l2_coef * sum ||theta_critic||^2``; its gradient
        is added by :meth:`_with_l2` instead of being differentiated (the loss value itself is
        never logged)."""
        values = self.nets("vf", obs, runs)[..., 0]
        cost_values = self.nets("cf", obs, runs)[..., 0]
        value_loss = ((values - returns) ** 2).mean(dim=1)
        cost_value_loss = ((cost_values - cost_returns) ** 2).mean(dim=1)
        return value_loss + cost_value_loss, value_loss, cost_value_loss

    def _with_l2(self, grads: Sequence[th.Tensor]) -> list[th.Tensor]:
        """The critics' gradients plus that of ``critic_l2_coef * sum ||theta||^2``.

        Autograd computes that term's gradient as ``coef * (2 * theta)`` in float32 (``mul``, then
        ``pow``'s backward) and adds it to the MSE path's gradient; so does this, and float addition
        and multiplication commute, so the sum is bit for bit autograd's, for a dozen fewer
        operations forward and backward per minibatch."""
        coef = th.tensor(float(self.model.critic_l2_coef), dtype=th.float32)
        return [g + coef * (2 * p.detach()) for g, p in zip(grads, self.critic_params)]

    def _step_critics(self, grads: Sequence[th.Tensor], critic_lr: float, mask: np.ndarray | None = None) -> None:
        """Clip the critics' gradients (``critic_grad_clip``) per run and take one Adam step."""
        n, total = len(self.reward_critic_params), len(self.critic_params)
        groups = [range(n), range(n, total)] if self.model.critic_grad_clip == "per_critic" else None
        self.critic_optimizer.step(grads, critic_lr, mask, max_norm=float(self.model.max_grad_norm), clip_groups=groups)

    def _train_critics(self) -> tuple[np.ndarray, np.ndarray]:
        """``n_critic_updates`` passes of minibatch regression of both critics; per-run mean losses."""
        ro = self.rollout
        assert ro is not None
        _, critic_lr = self._learning_rates(actor=False)
        size, batch = ro.actions.shape[1], int(self.model.batch_size)
        value_losses, cost_value_losses = [], []
        for _ in range(int(self.model.n_critic_updates)):
            for obs, returns, cost_returns in ro.minibatches(self.permutations(size), batch, "obs", "returns", "cost_returns"):
                loss, value_loss, cost_value_loss = self._critic_loss(obs, returns, cost_returns)
                grads = self._with_l2(th.autograd.grad(loss.sum(), self.critic_params))
                self._step_critics(grads, critic_lr)
                value_losses.append(value_loss.detach().numpy().astype(np.float64))
                cost_value_losses.append(cost_value_loss.detach().numpy().astype(np.float64))
        return np.mean(value_losses, axis=0), np.mean(cost_value_losses, axis=0)

    def _logits(self, obs: th.Tensor, runs: th.Tensor | None = None) -> th.Tensor:
        """Normalised logits (``dist.distribution.logits``) of every run's actor (or of ``runs``)."""
        return categorical(self.nets("pi", obs, runs))[0]

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
