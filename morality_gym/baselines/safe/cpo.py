r"""Constrained Policy Optimization (Achiam et al., 2017) with a categorical policy.

Each rollout gives one trust-region step of the actor and ``n_critic_updates`` of critic regression.

Actor step. With ``A_r``, ``A_c`` normalised over the rollout and ``rho = pi_theta / pi_old``::

    L_r(theta) = E_t[rho_t A_r,t]        (reward surrogate)     g = grad L_r at theta_old
    L_c(theta) = E_t[rho_t A_c,t]        (cost surrogate)       b = grad L_c at theta_old
    c = J_c - d                          (constraint value: mean cost of the last ep_cost_window
                                          episodes minus cost_limit)
    H = Fisher matrix of  E_t[KL(pi_old(.|s_t) || pi_theta(.|s_t))]  + cg_damping * I

``H^-1 g`` and ``H^-1 b`` come from ``cg_max_steps`` conjugate-gradient iterations on Fisher-vector
products (double backward through the mean KL, never forming ``H``). The full step ``x`` solves
``max g^T x  s.t.  c + b^T x <= 0,  x^T H x / 2 <= target_kl`` in closed form through its dual;
the cases (infeasible -> recovery step ``-sqrt(2 delta / s) H^-1 b``, constraint inactive -> TRPO
step, feasible -> dual solution ``(H^-1 g - nu* H^-1 b) / lambda*``) and their equations are in
:mod:`.cpo_dual`. Should numerical error put ``x`` outside the trust region, it is scaled back
onto its boundary.

Backtracking line search over ``theta_old + 0.8^j x``, ``j = 0 .. line_search_max_iter - 1``; the
first candidate is accepted whose exact mean KL is ``<= target_kl`` and

* recovery: the cost surrogate decreases, ``dL_c < 0``;
* otherwise: ``dL_c <= max(-c, 0)`` (the linearised constraint holds, or, if it is violated, the
  cost surrogate does not grow), and the reward surrogate improves, ``dL_r > 0`` -- unless the
  dual solution itself predicts a reward loss (``g^T x <= 0``, possible only when ``c > 0``), in
  which case the cost surrogate must decrease instead.

If no candidate passes, the actor is left unchanged for this rollout.
"""

from __future__ import annotations

import math
from typing import Any, Self

import torch as th
from sb3_contrib.common.utils import conjugate_gradient_solver, flat_grad
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from torch.nn.utils import parameters_to_vector, vector_to_parameters

from morality_gym.baselines.safe.base import CostOnPolicyAlgorithm
from morality_gym.baselines.safe.buffers import CostRolloutBufferSamples
from morality_gym.baselines.safe.cpo_dual import CPOCase, CPOStep, cpo_direction
from morality_gym.baselines.safe.functional import AdvantageNormalization, categorical_kl
from morality_gym.baselines.safe.policies import CostActorCriticPolicy


class CPO(CostOnPolicyAlgorithm):
    """CPO with a categorical policy (defaults: the paper's CPO runs).

    :param target_kl: trust-region radius ``delta`` on the mean KL (0.01).
    :param cg_max_steps: conjugate-gradient iterations (15).
    :param cg_damping: damping added to the Fisher matrix (0.1).
    :param line_search_max_iter: maximum candidates of the backtracking line search (15).
    :param line_search_shrinking_factor: step shrink factor between candidates (0.8).
    :param n_critic_updates: passes of critic regression per rollout (10), minibatches of
        ``batch_size`` (64).

    ``learning_rate`` only sets the (unused) actor optimiser; the critics use
    ``critic_learning_rate`` (default: ``learning_rate``, 3e-4, decaying linearly to 0). The other
    parameters are :class:`.CostOnPolicyAlgorithm`'s.
    """

    def __init__(
        self,
        policy: str | type[CostActorCriticPolicy],
        env: GymEnv | str | None,
        learning_rate: float | Schedule = 3e-4,
        critic_learning_rate: float | Schedule | None = None,
        anneal_lr: bool = True,
        n_steps: int | None = None,
        steps_per_rollout: int = 2048,
        batch_size: int = 64,
        n_critic_updates: int = 10,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        cost_gamma: float = 0.99,
        cost_gae_lambda: float = 0.95,
        target_kl: float = 0.01,
        cg_max_steps: int = 15,
        cg_damping: float = 0.1,
        line_search_max_iter: int = 15,
        line_search_shrinking_factor: float = 0.8,
        max_grad_norm: float = 40.0,
        critic_l2_coef: float = 1e-3,
        cost_limit: float = 0.0,
        ep_cost_window: int = 50,
        reward_advantage_normalization: AdvantageNormalization = "standardize",
        cost_advantage_normalization: AdvantageNormalization = "standardize",
        reset_envs_each_rollout: bool = False,
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
            n_steps=n_steps,
            steps_per_rollout=steps_per_rollout,
            gamma=gamma,
            gae_lambda=gae_lambda,
            cost_gamma=cost_gamma,
            cost_gae_lambda=cost_gae_lambda,
            ent_coef=0.0,
            max_grad_norm=max_grad_norm,
            critic_l2_coef=critic_l2_coef,
            n_critic_updates=n_critic_updates,
            batch_size=batch_size,
            cost_limit=cost_limit,
            ep_cost_window=ep_cost_window,
            reward_advantage_normalization=reward_advantage_normalization,
            cost_advantage_normalization=cost_advantage_normalization,
            reset_envs_each_rollout=reset_envs_each_rollout,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            monitor_wrapper=monitor_wrapper,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        self.target_kl = target_kl
        self.cg_max_steps = cg_max_steps
        self.cg_damping = cg_damping
        self.line_search_max_iter = line_search_max_iter
        self.line_search_shrinking_factor = line_search_shrinking_factor
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ actor step

    def _step_direction(
        self, data: CostRolloutBufferSamples, old_logits: th.Tensor, c: float
    ) -> tuple[CPOStep, th.Tensor, th.Tensor, dict[str, float]]:
        """Gradients, CG solves and the closed-form CPO step; returns ``(step, g, b, scalars)``."""
        params = self.policy.actor_parameters()
        dist = self.policy.get_distribution(data.observations)
        log_prob = dist.log_prob(data.actions.long().flatten())
        ratio = th.exp(log_prob - log_prob.detach())  # 1 at theta_old, but carries the gradient
        g = flat_grad((ratio * data.advantages).mean(), params, retain_graph=True)
        b = flat_grad((ratio * data.cost_advantages).mean(), params, retain_graph=True)

        mean_kl = categorical_kl(old_logits, dist.distribution.logits).mean()  # type: ignore[union-attr]
        grad_kl = flat_grad(mean_kl, params, create_graph=True, retain_graph=True)

        def fisher_vector_product(vector: th.Tensor) -> th.Tensor:
            return flat_grad(grad_kl @ vector, params, retain_graph=True) + self.cg_damping * vector

        v = conjugate_gradient_solver(fisher_vector_product, g, max_iter=self.cg_max_steps)
        w = conjugate_gradient_solver(fisher_vector_product, b, max_iter=self.cg_max_steps)
        q, r, s = (g @ v).item(), (g @ w).item(), (b @ w).item()
        step = cpo_direction(v, w, q, r, s, c, self.target_kl)

        x = step.direction
        quad = (x @ fisher_vector_product(x)).item() if step.case != CPOCase.NO_STEP else 0.0
        if quad > 2 * self.target_kl:  # numerical safety: back onto the trust-region boundary
            x = x * math.sqrt(2 * self.target_kl / quad)
            step = CPOStep(x, step.case, step.lam, step.nu)
        return step, g, b, {"q": q, "r": r, "s": s}

    def _surrogates(self, data: CostRolloutBufferSamples, old_log_prob: th.Tensor) -> tuple[th.Tensor, float, float]:
        """``(new logits, L_r, L_c)`` of the current actor parameters, without gradients."""
        with th.no_grad():
            dist = self.policy.get_distribution(data.observations)
            ratio = th.exp(dist.log_prob(data.actions.long().flatten()) - old_log_prob)
            logits = dist.distribution.logits  # type: ignore[union-attr]
            return logits, (ratio * data.advantages).mean().item(), (ratio * data.cost_advantages).mean().item()

    def _line_search(
        self,
        data: CostRolloutBufferSamples,
        old_logits: th.Tensor,
        old_log_prob: th.Tensor,
        step: CPOStep,
        g: th.Tensor,
        c: float,
    ) -> dict[str, float]:
        """Backtrack along ``step.direction``; leaves the actor at the accepted point (or unchanged)."""
        params = self.policy.actor_parameters()
        theta_old = parameters_to_vector(params).detach().clone()
        _, reward_old, cost_old = self._surrogates(data, old_log_prob)
        recovery = step.case == CPOCase.INFEASIBLE
        reward_expected_to_rise = (g @ step.direction).item() > 0
        result = {
            "accepted": 0.0,
            "step_fraction": 0.0,
            "kl": 0.0,
            "iters": 0.0,
            "reward_change": 0.0,
            "cost_change": 0.0,
        }
        if step.case == CPOCase.NO_STEP:
            return result
        for j in range(self.line_search_max_iter):
            fraction = self.line_search_shrinking_factor**j
            vector_to_parameters(theta_old + fraction * step.direction, params)
            logits, reward_new, cost_new = self._surrogates(data, old_log_prob)
            kl = categorical_kl(old_logits, logits).mean().item()
            d_reward, d_cost = reward_new - reward_old, cost_new - cost_old
            if recovery:
                improves = d_cost < 0
            else:
                improves = (d_reward > 0 if reward_expected_to_rise else d_cost < 0) and d_cost <= max(-c, 0.0)
            result.update(iters=float(j + 1), kl=kl, reward_change=d_reward, cost_change=d_cost)
            if math.isfinite(kl) and kl <= self.target_kl and improves:
                result.update(accepted=1.0, step_fraction=fraction)
                return result
        vector_to_parameters(theta_old, params)
        result.update(kl=0.0, reward_change=0.0, cost_change=0.0)
        return result

    # ------------------------------------------------------------------ update

    def train(self) -> None:
        """One CPO actor step, then the critics."""
        self.policy.set_training_mode(True)
        self._update_learning_rates(actor=False)
        mean_ep_cost = self.mean_episode_cost()
        c = mean_ep_cost - self.cost_limit
        self._log_critic_fit()
        self._normalize_rollout_advantages()

        data = self._full_batch()
        with th.no_grad():
            old_dist = self.policy.get_distribution(data.observations)
            old_logits = old_dist.distribution.logits  # type: ignore[union-attr]
            old_log_prob = old_dist.log_prob(data.actions.long().flatten())
        step, g, b, scalars = self._step_direction(data, old_logits, c)
        search = self._line_search(data, old_logits, old_log_prob, step, g, c)
        value_loss, cost_value_loss = self._train_critics()
        self._n_updates += 1

        full_norm = step.direction.norm().item()
        self.logger.record("train/cpo_case", int(step.case))
        self.logger.record("train/cpo_case_name", step.case.name, exclude="tensorboard")
        self.logger.record("train/constraint_value", c)
        self.logger.record("train/mean_ep_cost", mean_ep_cost)
        self.logger.record("train/dual_lambda", step.lam)
        self.logger.record("train/dual_nu", step.nu)
        for key, value in scalars.items():
            self.logger.record(f"train/{key}", value)
        self.logger.record("train/expected_reward_change", (g @ step.direction).item() * search["step_fraction"])
        self.logger.record("train/expected_cost_change", (b @ step.direction).item() * search["step_fraction"])
        self.logger.record("train/step_fraction", search["step_fraction"])
        self.logger.record("train/step_size", full_norm * search["step_fraction"])
        self.logger.record("train/kl", search["kl"])
        self.logger.record("train/line_search_iters", search["iters"])
        self.logger.record("train/accepted", search["accepted"])
        self.logger.record("train/surrogate_reward_change", search["reward_change"])
        self.logger.record("train/surrogate_cost_change", search["cost_change"])
        self.logger.record("train/value_loss", value_loss)
        self.logger.record("train/cost_value_loss", cost_value_loss)
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")

    def learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "CPO",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> Self:
        return super().learn(total_timesteps, callback, log_interval, tb_log_name, reset_num_timesteps, progress_bar)
