r"""PPO-Lagrangian: PPO on a reward that the cost is traded against by a learnt multiplier.

Problem: ``max_pi J_r(pi)  s.t.  J_c(pi) <= d`` (``d = cost_limit``, 0 in the paper's runs).

Once per rollout, *before* the policy update, the multiplier takes one projected Adam step on the
dual (see :mod:`.lagrange`)::

    lambda <- max(0, Adam step on  -lambda * (J_c - d))

where ``J_c`` is the mean undiscounted cost of the last ``ep_cost_window`` (50) finished episodes.
Then up to ``n_epochs`` passes of minibatch PPO maximise the clipped surrogate with the combined,
rescaled advantage (``A_r`` standardised, ``A_c`` centred over the rollout, by default)::

    A_t       = (A_r,t - lambda * A_c,t) / (1 + lambda)
    rho_t     = pi_theta(a_t | s_t) / pi_old(a_t | s_t)
    L^CLIP    = E_t[ min(rho_t A_t, clip(rho_t, 1 - eps, 1 + eps) A_t) ]
    actor loss  = -L^CLIP - ent_coef * E_t[H(pi_theta(.|s_t))]
    critic loss = E_t[(V(s_t) - R_t)^2] + E_t[(V_c(s_t) - R^c_t)^2] + critic_l2_coef * sum ||theta_V, theta_Vc||^2

Each minibatch steps both critics and the actor (disjoint parameters, separate clipping), so the
critics get exactly as many passes as the actor. After each pass the exact per-state
``KL(pi_old || pi_theta)`` over the rollout is reduced (``kl_early_stop_reduction``: ``sum`` over
states as OmniSafe did, or ``mean``) and the loop stops once it exceeds ``target_kl``. With
``sum`` that happens after the first pass on almost every update
(docs/protocols.md#ppo-lag-kl-early-stop-sums-over-states).

Dividing by ``1 + lambda`` keeps the advantage's scale bounded as ``lambda`` grows, so the PPO
step size does not blow up.
"""

from __future__ import annotations

from typing import Any, Self

import numpy as np
import torch as th
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule

from morality_gym.baselines.safe.base import CostOnPolicyAlgorithm, CriticGradClip, LRAnnealTiming, check_choice
from morality_gym.baselines.safe.functional import AdvantageNormalization, KLReduction, categorical_kl, reduce_kl
from morality_gym.baselines.safe.lagrange import LagrangeMultiplier
from morality_gym.baselines.safe.policies import CostActorCriticPolicy, WeightInit

KL_REDUCTIONS: tuple[str, ...] = ("sum", "mean")


class PPOLag(CostOnPolicyAlgorithm):
    """PPO-Lagrangian with a categorical policy (defaults: the paper's PPO-Lag runs).

    :param n_epochs: maximum passes over the rollout per update (40), cut short by ``target_kl``.
    :param batch_size: minibatch size (64).
    :param clip_range: PPO clip ``eps`` (0.2).
    :param target_kl: stop the passes once the reduced KL to the rollout policy exceeds it (0.02);
        ``None`` disables early stopping.
    :param kl_early_stop_reduction: how the per-state KLs are reduced for that test: ``sum``
        (OmniSafe's, the default: in effect one pass per update) or ``mean``.
    :param lagrange_init: ``lambda`` before the first update (0.001).
    :param lagrange_lr: Adam learning rate of ``lambda`` (0.035).
    :param lagrange_upper_bound: optional cap on ``lambda`` (``None``).

    The other parameters are :class:`.CostOnPolicyAlgorithm`'s: rollouts of ``steps_per_rollout``
    (2048) steps over the vec env, gamma/GAE 0.99/0.95 for both streams, ``max_grad_norm`` 40 per
    critic and for the actor, ``critic_l2_coef`` 0.001, actor lr 3e-4 decaying linearly to 0 over the
    epochs, critics' lr constant, ``cost_limit`` 0, Kaiming-uniform initialisation, Adam eps 1e-8.
    """

    def __init__(
        self,
        policy: str | type[CostActorCriticPolicy],
        env: GymEnv | str | None,
        learning_rate: float | Schedule = 3e-4,
        critic_learning_rate: float | Schedule | None = None,
        anneal_lr: bool = True,
        anneal_lr_timing: LRAnnealTiming = "epoch",
        anneal_critic_lr: bool = False,
        n_steps: int | None = None,
        steps_per_rollout: int = 2048,
        batch_size: int = 64,
        n_epochs: int = 40,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        cost_gamma: float = 0.99,
        cost_gae_lambda: float = 0.95,
        clip_range: float = 0.2,
        ent_coef: float = 0.0,
        max_grad_norm: float = 40.0,
        critic_grad_clip: CriticGradClip = "per_critic",
        critic_l2_coef: float = 1e-3,
        target_kl: float | None = 0.02,
        kl_early_stop_reduction: KLReduction = "sum",
        cost_limit: float = 0.0,
        lagrange_init: float = 0.001,
        lagrange_lr: float = 0.035,
        lagrange_upper_bound: float | None = None,
        ep_cost_window: int = 50,
        reward_advantage_normalization: AdvantageNormalization = "standardize",
        cost_advantage_normalization: AdvantageNormalization = "center",
        reset_envs_each_rollout: bool = False,
        weight_init: WeightInit = "kaiming_uniform",
        adam_eps: float = 1e-8,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        monitor_wrapper: bool = True,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "cpu",
        _init_setup_model: bool = True,
    ):
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            critic_learning_rate=critic_learning_rate,
            anneal_lr=anneal_lr,
            anneal_lr_timing=anneal_lr_timing,
            anneal_critic_lr=anneal_critic_lr,
            n_steps=n_steps,
            steps_per_rollout=steps_per_rollout,
            gamma=gamma,
            gae_lambda=gae_lambda,
            cost_gamma=cost_gamma,
            cost_gae_lambda=cost_gae_lambda,
            ent_coef=ent_coef,
            max_grad_norm=max_grad_norm,
            critic_grad_clip=critic_grad_clip,
            critic_l2_coef=critic_l2_coef,
            n_critic_updates=n_epochs,
            batch_size=batch_size,
            cost_limit=cost_limit,
            ep_cost_window=ep_cost_window,
            reward_advantage_normalization=reward_advantage_normalization,
            cost_advantage_normalization=cost_advantage_normalization,
            reset_envs_each_rollout=reset_envs_each_rollout,
            weight_init=weight_init,
            adam_eps=adam_eps,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            monitor_wrapper=monitor_wrapper,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        check_choice("kl_early_stop_reduction", kl_early_stop_reduction, KL_REDUCTIONS)
        self.n_epochs = n_epochs
        self.clip_range = clip_range
        self.target_kl = target_kl
        self.kl_early_stop_reduction = kl_early_stop_reduction
        self.lagrange_init = lagrange_init
        self.lagrange_lr = lagrange_lr
        self.lagrange_upper_bound = lagrange_upper_bound
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        # On load, SB3 restores the learnt value and Adam moments into this module afterwards.
        self.lagrange = LagrangeMultiplier(self.lagrange_init, self.lagrange_lr, self.lagrange_upper_bound)

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        return [*state_dicts, "lagrange", "lagrange.optimizer"], variables

    @property
    def lagrange_multiplier(self) -> float:
        """The current Lagrange multiplier ``lambda >= 0``."""
        return self.lagrange.value

    def train(self) -> None:
        """Multiplier step, then up to ``n_epochs`` passes of clipped-surrogate minibatch updates."""
        self.policy.set_training_mode(True)
        actor_lr, critic_lr = self._update_learning_rates(actor=True)
        mean_ep_cost = self.mean_episode_cost()
        lam = self.lagrange.update(mean_ep_cost, self.cost_limit)
        self._log_critic_fit()
        self._normalize_rollout_advantages()

        full = self._full_batch()
        with th.no_grad():
            old_logits = self.policy.get_distribution(full.observations).distribution.logits  # type: ignore[union-attr]
        actor_params = self.policy.actor_parameters()
        stats: dict[str, list[float]] = {k: [] for k in ("policy", "value", "cost_value", "entropy", "clip_fraction")}
        kl_tested, kl_mean, passes, early_stopped = 0.0, 0.0, 0, False
        for _ in range(self.n_epochs):
            for batch in self.rollout_buffer.get(self.batch_size):
                dist = self.policy.get_distribution(batch.observations)
                log_prob = dist.log_prob(batch.actions.long().flatten())
                entropy = dist.entropy()
                advantages = (batch.advantages - lam * batch.cost_advantages) / (1.0 + lam)
                ratio = th.exp(log_prob - batch.old_log_prob)
                clipped = th.clamp(ratio, 1.0 - self.clip_range, 1.0 + self.clip_range)
                policy_loss = -th.min(ratio * advantages, clipped * advantages).mean()
                entropy_mean = entropy.mean() if entropy is not None else th.zeros(())
                critic_loss, value_loss, cost_value_loss = self._critic_loss(
                    batch.observations, batch.returns, batch.cost_returns
                )
                self.policy.optimizer.zero_grad()
                self.policy.critic_optimizer.zero_grad()
                # Disjoint parameters: one backward yields each network's own gradient, exactly as
                # OmniSafe's three separate steps (reward critic, cost critic, actor) per minibatch.
                (policy_loss - self.ent_coef * entropy_mean + critic_loss).backward()
                self._step_critics()
                self._clip_and_step(self.policy.optimizer, actor_params)

                stats["policy"].append(policy_loss.item())
                stats["value"].append(value_loss.item())
                stats["cost_value"].append(cost_value_loss.item())
                stats["entropy"].append(entropy_mean.item())
                stats["clip_fraction"].append(((ratio - 1.0).abs() > self.clip_range).float().mean().item())
            passes += 1
            with th.no_grad():
                new_logits = self.policy.get_distribution(full.observations).distribution.logits  # type: ignore[union-attr]
                per_state = categorical_kl(old_logits, new_logits)
                kl_tested = reduce_kl(per_state, self.kl_early_stop_reduction).item()
                kl_mean = per_state.mean().item()
            if self.target_kl is not None and kl_tested > self.target_kl:
                early_stopped = True
                break
        self._n_updates += passes

        means = {key: float(np.mean(values)) for key, values in stats.items()}
        self._record_update(
            mean_ep_cost,
            actor_lr,
            critic_lr,
            passes=passes,
            kl=kl_tested,
            kl_mean=kl_mean,
            early_stopped=early_stopped,
            lagrange_multiplier=lam,
            policy_loss=means["policy"],
            value_loss=means["value"],
            cost_value_loss=means["cost_value"],
            entropy=means["entropy"],
            clip_fraction=means["clip_fraction"],
        )
        self.logger.record("train/lagrange_multiplier", lam)
        self.logger.record("train/mean_ep_cost", mean_ep_cost)
        self.logger.record("train/kl", kl_tested)
        self.logger.record("train/kl_mean", kl_mean)
        self.logger.record("train/approx_kl", kl_mean)
        self.logger.record("train/epochs", passes)
        self.logger.record("train/early_stopped", int(early_stopped))
        self.logger.record("train/policy_gradient_loss", means["policy"])
        self.logger.record("train/value_loss", means["value"])
        self.logger.record("train/cost_value_loss", means["cost_value"])
        self.logger.record("train/entropy_loss", -means["entropy"])
        self.logger.record("train/clip_fraction", means["clip_fraction"])
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")

    def learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "PPOLag",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> Self:
        return super().learn(total_timesteps, callback, log_interval, tb_log_name, reset_num_timesteps, progress_bar)
