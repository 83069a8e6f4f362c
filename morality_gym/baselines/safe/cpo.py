r"""Constrained Policy Optimization (Achiam et al., 2017) with a categorical policy.

Each rollout gives one trust-region step of the actor, then ``n_critic_updates`` passes of critic
regression.

Actor step. With ``A_r`` standardised and ``A_c`` centred over the rollout (by default) and
``rho = pi_theta / pi_rollout``::

    L_r(theta) = E_t[rho_t A_r,t]        (reward surrogate)     g = grad L_r at theta_old
    L_c(theta) = E_t[rho_t A_c,t]        (cost surrogate)       b = grad L_c at theta_old
    c = J_c - d                          (constraint value: mean cost of the last ep_cost_window
                                          episodes minus cost_limit)
    H = Fisher matrix of  E_t[KL(pi_old(.|s_t) || pi_theta(.|s_t))]  + cg_damping * I

``v = H^-1 g`` and ``w = H^-1 b`` come from ``cg_max_steps`` conjugate-gradient iterations on
Fisher-vector products (double backward through the mean KL, never forming ``H``;
:func:`.functional.conjugate_gradient`). The case and the full step are in :mod:`.cpo_dual`
(``dual_solution``: ``omnisafe`` as the paper's runs, or ``exact``).

Backtracking line search over ``theta_old + 0.8^j x``, ``j = 0 .. line_search_max_iter - 1`` (20,
as OmniSafe hard-codes it). ``line_search_accept`` chooses the acceptance rule:

* ``omnisafe`` (docs/protocols.md#cpo-line-search): accept the first candidate whose exact mean KL
  is ``<= target_kl`` and whose cost-surrogate change is ``<= max(-c, 0)``; in cases 2-4 the
  reward surrogate must also not get worse. A candidate whose distribution cannot be built
  (``ValueError``, e.g. NaN logits) is skipped with the step shrunk; one with a non-finite KL is
  skipped *without* shrinking (as OmniSafe does).
* ``strict``: as ``omnisafe``, but the reward surrogate must improve whenever the step predicts it
  (``g^T x > 0``), the cost surrogate must decrease otherwise, and a recovery step must decrease it.

If no candidate passes, the actor does not move this epoch (``accept_step`` 0). With
``trust_region_rescale`` a full step that numerical error puts outside the trust region is first
scaled back onto its boundary (OmniSafe does not do this).
"""

from __future__ import annotations

import math
from typing import Any, Literal, Self

import torch as th
from sb3_contrib.common.utils import flat_grad
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from torch.nn.utils import parameters_to_vector, vector_to_parameters

from morality_gym.baselines.safe.base import CostOnPolicyAlgorithm, CriticGradClip, LRAnnealTiming, check_choice
from morality_gym.baselines.safe.buffers import CostRolloutBufferSamples
from morality_gym.baselines.safe.cpo_dual import (
    DUAL_SOLUTIONS,
    CPOScalars,
    CPOStep,
    DualSolution,
    exact_direction,
    line_search_accepts,
    omnisafe_direction,
)
from morality_gym.baselines.safe.functional import AdvantageNormalization, categorical_kl, conjugate_gradient
from morality_gym.baselines.safe.policies import CostActorCriticPolicy, WeightInit

LINE_SEARCH_RULES: tuple[str, ...] = ("omnisafe", "strict")


class CPO(CostOnPolicyAlgorithm):
    """CPO with a categorical policy (defaults: the paper's CPO runs).

    :param target_kl: trust-region radius ``delta`` on the mean KL (0.01).
    :param cg_max_steps: conjugate-gradient iterations (15).
    :param cg_damping: damping added to the Fisher matrix (0.1).
    :param cg_residual_tol: conjugate gradients stop once the residual's norm is below it (1e-10).
    :param cg_eps: guard added to the conjugate-gradient denominators (1e-6, OmniSafe's).
    :param dual_solution: ``omnisafe`` (the paper's runs, default) or ``exact``; see :mod:`.cpo_dual`.
    :param line_search_max_iter: candidates of the backtracking line search (20, what OmniSafe
        actually ran; its configured 15 was never used).
    :param line_search_shrinking_factor: step shrink factor between candidates (0.8).
    :param line_search_accept: acceptance rule, ``omnisafe`` (default) or ``strict`` (module docstring).
    :param trust_region_rescale: scale a full step outside the trust region back onto it (``False``).
    :param n_critic_updates: passes of critic regression per rollout (10), minibatches of
        ``batch_size`` (64).

    ``learning_rate`` only sets the (unused) actor optimiser: the step is a trust-region step, so
    nothing of the actor decays. The critics use ``critic_learning_rate`` (default:
    ``learning_rate``, 3e-4, constant). The other parameters are :class:`.CostOnPolicyAlgorithm`'s.
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
        n_critic_updates: int = 10,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        cost_gamma: float = 0.99,
        cost_gae_lambda: float = 0.95,
        target_kl: float = 0.01,
        cg_max_steps: int = 15,
        cg_damping: float = 0.1,
        cg_residual_tol: float = 1e-10,
        cg_eps: float = 1e-6,
        dual_solution: DualSolution = "omnisafe",
        line_search_max_iter: int = 20,
        line_search_shrinking_factor: float = 0.8,
        line_search_accept: Literal["omnisafe", "strict"] = "omnisafe",
        trust_region_rescale: bool = False,
        max_grad_norm: float = 40.0,
        critic_grad_clip: CriticGradClip = "per_critic",
        critic_l2_coef: float = 1e-3,
        cost_limit: float = 0.0,
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
            ent_coef=0.0,
            max_grad_norm=max_grad_norm,
            critic_grad_clip=critic_grad_clip,
            critic_l2_coef=critic_l2_coef,
            n_critic_updates=n_critic_updates,
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
        check_choice("dual_solution", dual_solution, DUAL_SOLUTIONS)
        check_choice("line_search_accept", line_search_accept, LINE_SEARCH_RULES)
        self.target_kl = target_kl
        self.cg_max_steps = cg_max_steps
        self.cg_damping = cg_damping
        self.cg_residual_tol = cg_residual_tol
        self.cg_eps = cg_eps
        self.dual_solution = dual_solution
        self.line_search_max_iter = line_search_max_iter
        self.line_search_shrinking_factor = line_search_shrinking_factor
        self.line_search_accept = line_search_accept
        self.trust_region_rescale = trust_region_rescale
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ actor step

    def _step_direction(
        self, data: CostRolloutBufferSamples, old_logits: th.Tensor, c: float
    ) -> tuple[CPOStep, th.Tensor, CPOScalars]:
        """Gradients, CG solves and the CPO full step; returns ``(step, g, scalars)``."""
        params = self.policy.actor_parameters()
        dist = self.policy.get_distribution(data.observations)
        log_prob = dist.log_prob(data.actions.long().flatten())
        ratio = th.exp(log_prob - data.old_log_prob)  # ~1 at theta_old; carries the gradient
        g = flat_grad((ratio * data.advantages).mean(), params, retain_graph=True)
        b = flat_grad((ratio * data.cost_advantages).mean(), params, retain_graph=True)

        mean_kl = categorical_kl(old_logits, dist.distribution.logits).mean()  # type: ignore[union-attr]
        grad_kl = flat_grad(mean_kl, params, create_graph=True, retain_graph=True)

        def fisher_vector_product(vector: th.Tensor) -> th.Tensor:
            return flat_grad(grad_kl @ vector, params, retain_graph=True) + self.cg_damping * vector

        def solve(rhs: th.Tensor) -> th.Tensor:
            return conjugate_gradient(fisher_vector_product, rhs, self.cg_max_steps, self.cg_residual_tol, self.cg_eps)

        v = solve(g)
        vhv = (v @ fisher_vector_product(v)).item()
        w = solve(b)
        scalars = CPOScalars(q=vhv, r=(g @ w).item(), s=(b @ w).item(), c=c, delta=self.target_kl, bb=(b @ b).item())
        direction_of = omnisafe_direction if self.dual_solution == "omnisafe" else exact_direction
        step = direction_of(v, w, scalars, vhv)
        if self.trust_region_rescale and step.direction.abs().sum() > 0:
            quad = (step.direction @ fisher_vector_product(step.direction)).item()
            if quad > 2 * self.target_kl:
                scaled = step.direction * math.sqrt(2 * self.target_kl / quad)
                step = CPOStep(scaled, step.case, step.lam, step.nu, step.A, step.B)
        return step, g, scalars

    def _surrogate_losses(self, data: CostRolloutBufferSamples) -> tuple[th.Tensor, float, float]:
        """``(logits, L_r, L_c)`` of the current actor, without gradients (``ValueError`` if its
        distribution cannot be built, e.g. NaN parameters)."""
        with th.no_grad():
            dist = self.policy.get_distribution(data.observations)
            ratio = th.exp(dist.log_prob(data.actions.long().flatten()) - data.old_log_prob)
            logits = dist.distribution.logits  # type: ignore[union-attr]
            return logits, (ratio * data.advantages).mean().item(), (ratio * data.cost_advantages).mean().item()

    def _accepts(self, step: CPOStep, d_reward: float, d_cost: float, kl: float, c: float, expected: float) -> bool:
        """The line-search acceptance rule (``line_search_accept``; :func:`.cpo_dual.line_search_accepts`);
        ``kl`` is finite here."""
        return line_search_accepts(self.line_search_accept, self.target_kl, step, d_reward, d_cost, kl, c, expected)

    def _line_search(
        self, data: CostRolloutBufferSamples, old_logits: th.Tensor, step: CPOStep, g: th.Tensor, c: float
    ) -> dict[str, float]:
        """Backtrack along ``step.direction``; leaves the actor at the accepted point (or unchanged)."""
        params = self.policy.actor_parameters()
        theta_old = parameters_to_vector(params).detach().clone()
        _, reward_old, cost_old = self._surrogate_losses(data)
        expected = (g @ step.direction).item()
        result = {"accept_step": 0, "fraction": 0.0, "kl": math.nan, "tried": 0, "d_reward": 0.0, "d_cost": 0.0}
        fraction = 1.0
        for j in range(self.line_search_max_iter):
            vector_to_parameters(theta_old + fraction * step.direction, params)
            result["tried"] = j + 1
            try:
                logits, reward_new, cost_new = self._surrogate_losses(data)
            except ValueError:  # the candidate's distribution is invalid (NaN logits)
                fraction *= self.line_search_shrinking_factor
                continue
            kl = categorical_kl(old_logits, logits).mean().item()
            d_reward, d_cost = reward_new - reward_old, cost_new - cost_old
            result.update(kl=kl, d_reward=d_reward, d_cost=d_cost)
            if not math.isfinite(kl):
                if self.line_search_accept == "omnisafe":
                    continue  # OmniSafe retries the same fraction
                fraction *= self.line_search_shrinking_factor
                continue
            if self._accepts(step, d_reward, d_cost, kl, c, expected):
                result.update(accept_step=j + 1, fraction=fraction)
                vector_to_parameters(theta_old + fraction * step.direction, params)
                return result
            fraction *= self.line_search_shrinking_factor
        vector_to_parameters(theta_old, params)
        result.update(d_reward=0.0, d_cost=0.0)
        return result

    # ------------------------------------------------------------------ update

    def train(self) -> None:
        """One CPO actor step, then the critics."""
        self.policy.set_training_mode(True)
        _, critic_lr = self._update_learning_rates(actor=False)
        mean_ep_cost = self.mean_episode_cost()
        c = mean_ep_cost - self.cost_limit
        self._log_critic_fit()
        self._normalize_rollout_advantages()

        data = self._full_batch()
        with th.no_grad():
            old_logits = self.policy.get_distribution(data.observations).distribution.logits  # type: ignore[union-attr]
        step, g, sc = self._step_direction(data, old_logits, c)
        search = self._line_search(data, old_logits, step, g, c)
        kl_mean = self._mean_kl_to(data.observations, old_logits)
        value_loss, cost_value_loss = self._train_critics()
        self._n_updates += 1

        taken = search["fraction"] * step.direction
        diagnostics = {
            "kl": search["kl"],
            "kl_mean": kl_mean,
            "cpo_case": int(step.case),
            "accept_step": int(search["accept_step"]),
            "line_search_tried": int(search["tried"]),
            "step_fraction": search["fraction"],
            "lambda_star": step.lam,
            "nu_star": step.nu,
            "A": step.A,
            "B": step.B,
            "q": sc.q,
            "r": sc.r,
            "s": sc.s,
            "c": c,
            "b_norm": math.sqrt(max(sc.bb, 0.0)),
            "full_step_norm": step.direction.norm().item(),
            "step_norm": taken.norm().item(),
            "expected_reward_change": (g @ taken).item(),
            "surrogate_reward_change": search["d_reward"],
            "surrogate_cost_change": search["d_cost"],
            "value_loss": value_loss,
            "cost_value_loss": cost_value_loss,
        }
        self._record_update(mean_ep_cost, None, critic_lr, **diagnostics)
        self.logger.record("train/mean_ep_cost", mean_ep_cost)
        self.logger.record("train/constraint_value", c)
        self.logger.record("train/cpo_case_name", step.case.name, exclude="tensorboard")
        for key, value in diagnostics.items():
            self.logger.record(f"train/{key}", value)
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
