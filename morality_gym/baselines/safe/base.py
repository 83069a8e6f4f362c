"""What PPO-Lagrangian and CPO share: collecting rewards *and costs*, and training the critics.

:class:`CostOnPolicyAlgorithm` is an SB3 :class:`~stable_baselines3.common.on_policy_algorithm.OnPolicyAlgorithm`
whose rollouts also read ``info["cost"]`` from every step, keep a cost critic ``V_c`` next to the
reward critic, and track the cost of finished episodes (``J_c``, the quantity the constraint
``J_c <= cost_limit`` is about). Subclasses implement :meth:`train`.
"""

from __future__ import annotations

import warnings
from collections import deque
from typing import Any, ClassVar, Literal

import numpy as np
import torch as th
import torch.nn.functional as F
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import (
    ConstantSchedule,
    FloatSchedule,
    LinearSchedule,
    explained_variance,
    obs_as_tensor,
    safe_mean,
    update_learning_rate,
)
from stable_baselines3.common.vec_env import VecEnv

from morality_gym.baselines.safe.buffers import CostRolloutBuffer, CostRolloutBufferSamples
from morality_gym.baselines.safe.functional import AdvantageNormalization, categorical_kl, normalize_advantages
from morality_gym.baselines.safe.policies import WEIGHT_INITS, CostActorCriticPolicy, WeightInit

LRAnnealTiming = Literal["epoch", "progress"]
CriticGradClip = Literal["per_critic", "joint"]
LR_ANNEAL_TIMINGS: tuple[str, ...] = ("epoch", "progress")
CRITIC_GRAD_CLIPS: tuple[str, ...] = ("per_critic", "joint")
ADVANTAGE_NORMALIZATIONS: tuple[str, ...] = ("standardize", "center", "none")

#: The info key the cost arrives under.
COST_INFO_KEY = "cost"
#: Who is expected to put it there (named in the error raised when it is missing).
COST_WRAPPER_HINT = (
    "morality_gym.norms.wrappers.MoralityWrapper (single env) or VecMoralityWrapper (VecEnv), which run "
    "the step-wise moral Cost on info['norm_events'] and write info['cost'] on every step"
)


def check_choice(name: str, value: Any, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f"{name}={value!r} is not one of {', '.join(choices)}")


class MissingCostError(KeyError):
    """A step's info dict has no ``"cost"``: the env was not wrapped by the cost wrapper."""

    def __str__(self) -> str:  # KeyError would print the message as a quoted repr
        return str(self.args[0])


class CostOnPolicyAlgorithm(OnPolicyAlgorithm):
    """Base of the constrained on-policy learners (categorical policies only).

    :param policy: ``"MlpPolicy"`` or a :class:`CostActorCriticPolicy` subclass.
    :param env: the env or VecEnv; every step's info must carry a float ``info["cost"]``.
    :param learning_rate: actor learning rate (a float or an SB3 schedule).
    :param critic_learning_rate: learning rate of both critics; ``None``: same as ``learning_rate``.
    :param anneal_lr: turn the actor's float learning rate into a linear decay to 0 over the run.
    :param anneal_lr_timing: where in the run each update reads the decaying rate. ``epoch``
        (OmniSafe, whose ``LinearLR`` is stepped after each epoch's update): update ``k`` of ``E``
        (0-based) trains at ``lr * (1 - k / E)``, the first at the full rate, the last at ``lr / E``.
        ``progress`` (SB3): ``lr * progress_remaining`` measured after the rollout, i.e. one epoch
        later, so the last update trains at 0.
    :param anneal_critic_lr: whether the critics' rate decays like the actor's. OmniSafe attaches
        its scheduler to the actor alone, so the paper's critics kept 3e-4 throughout
        (docs/protocols.md#only-the-actors-learning-rate-decays); default ``False``.
    :param n_steps: steps per env per rollout; ``None``: ``steps_per_rollout // n_envs``.
    :param steps_per_rollout: total steps per rollout over the vec env (2048 in the paper's runs).
    :param gamma: reward discount.
    :param gae_lambda: reward GAE lambda.
    :param cost_gamma: cost discount.
    :param cost_gae_lambda: cost GAE lambda.
    :param ent_coef: entropy bonus in the actor loss (where there is one).
    :param max_grad_norm: gradient-norm clip, applied to the actor and the critics separately.
    :param critic_grad_clip: ``per_critic`` (OmniSafe: the reward critic and the cost critic each clip
        their own gradient norm at ``max_grad_norm``) or ``joint`` (one norm over both).
    :param critic_l2_coef: coefficient of ``sum ||theta||^2`` over the critics' parameters, added to
        the critic loss.
    :param n_critic_updates: passes over the rollout for the critic regression (PPO-Lag trains its
        critics inside its own ``n_epochs`` loop instead; the name follows sb3-contrib's TRPO).
    :param batch_size: minibatch size of the critic (and, for PPO-Lag, actor) updates.
    :param cost_limit: ``d`` in ``J_c <= d``; ``J_c`` is the mean undiscounted episode cost.
    :param ep_cost_window: number of recent finished episodes ``J_c`` averages over.
    :param reward_advantage_normalization: ``"standardize"``, ``"center"`` or ``"none"``, over the
        whole rollout.
    :param cost_advantage_normalization: the same for cost advantages. ``center`` (the default) is
        OmniSafe's: its "standardized" cost advantages are only centred, and the small moral costs
        keep their scale (docs/protocols.md#cost-advantages-are-only-centred).
    :param weight_init: ``kaiming_uniform`` (OmniSafe's, the default) or ``orthogonal`` (SB3's); see
        :mod:`.policies`.
    :param adam_eps: ``eps`` of the actor's and critics' Adam: 1e-8 (PyTorch's default, which OmniSafe
        keeps); SB3's policies use 1e-5.
    :param reset_envs_each_rollout: reset every env at the start of each rollout, cutting the
        episodes in progress (they are bootstrapped with the critics at the rollout's end, like
        any unfinished episode, and never count as finished for ``J_c``). This is what OmniSafe,
        which ran the paper's PPO-Lag and CPO, does at every epoch
        (docs/protocols.md#training-envs-restart-every-epoch): with 256 steps per
        env per epoch and episodes of up to 201 steps, it changes which states training sees, so
        the paper's settings turn it on. Off by default, as in SB3, where episodes run on across
        rollouts.

    The rest are SB3's ``OnPolicyAlgorithm`` parameters.

    Every update appends one row to :attr:`update_log` (``update``, ``timesteps``, ``actor_lr``,
    ``critic_lr``, ``ep_cost``, the losses and what the subclass adds), the per-update diagnostics
    that runs write to ``runs/<run_id>.updates.parquet``.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": CostActorCriticPolicy}
    #: Keys ``policy_kwargs["net_arch"]`` may have: actor, reward critic, cost critic.
    net_arch_keys: ClassVar[tuple[str, ...]] = ("pi", "vf", "cf")
    rollout_buffer: CostRolloutBuffer
    policy: CostActorCriticPolicy

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
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        cost_gamma: float = 0.99,
        cost_gae_lambda: float = 0.95,
        ent_coef: float = 0.0,
        max_grad_norm: float = 40.0,
        critic_grad_clip: CriticGradClip = "per_critic",
        critic_l2_coef: float = 1e-3,
        n_critic_updates: int = 10,
        batch_size: int = 64,
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
        check_choice("anneal_lr_timing", anneal_lr_timing, LR_ANNEAL_TIMINGS)
        check_choice("critic_grad_clip", critic_grad_clip, CRITIC_GRAD_CLIPS)
        check_choice("weight_init", weight_init, WEIGHT_INITS)
        check_choice("reward_advantage_normalization", reward_advantage_normalization, ADVANTAGE_NORMALIZATIONS)
        check_choice("cost_advantage_normalization", cost_advantage_normalization, ADVANTAGE_NORMALIZATIONS)
        if not adam_eps > 0:
            raise ValueError(f"adam_eps must be > 0, got {adam_eps!r}")
        policy_kwargs = dict(policy_kwargs or {})
        policy_kwargs.setdefault("weight_init", weight_init)
        policy_kwargs.setdefault("optimizer_kwargs", {"eps": adam_eps})
        super().__init__(
            policy,
            env,  # type: ignore[arg-type]
            learning_rate=learning_rate,
            n_steps=n_steps or steps_per_rollout,  # placeholder until n_envs is known
            gamma=gamma,
            gae_lambda=gae_lambda,
            ent_coef=ent_coef,
            vf_coef=1.0,  # unused: actor and critics have separate optimisers
            max_grad_norm=max_grad_norm,
            use_sde=False,
            sde_sample_freq=-1,
            rollout_buffer_class=CostRolloutBuffer,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            monitor_wrapper=monitor_wrapper,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
            supported_action_spaces=(spaces.Discrete,),
        )
        if n_steps is None and self.env is not None:
            n_steps = max(1, steps_per_rollout // self.n_envs)
            if n_steps * self.n_envs != steps_per_rollout:
                warnings.warn(
                    f"steps_per_rollout={steps_per_rollout} is not a multiple of n_envs={self.n_envs}: "
                    f"rollouts will have {n_steps * self.n_envs} steps",
                    stacklevel=2,
                )
        self.n_steps = n_steps or steps_per_rollout
        self.steps_per_rollout = steps_per_rollout
        self.critic_learning_rate = critic_learning_rate
        self.anneal_lr = anneal_lr
        self.anneal_lr_timing = anneal_lr_timing
        self.anneal_critic_lr = anneal_critic_lr
        self.critic_grad_clip = critic_grad_clip
        self.weight_init = weight_init
        self.adam_eps = adam_eps
        #: One row per update (see the class docstring); not saved with the model.
        self.update_log: list[dict[str, Any]] = []
        self.cost_gamma = cost_gamma
        self.cost_gae_lambda = cost_gae_lambda
        self.critic_l2_coef = critic_l2_coef
        self.n_critic_updates = n_critic_updates
        self.batch_size = batch_size
        self.cost_limit = cost_limit
        self.ep_cost_window = ep_cost_window
        self.reward_advantage_normalization = reward_advantage_normalization
        self.cost_advantage_normalization = cost_advantage_normalization
        self.reset_envs_each_rollout = reset_envs_each_rollout
        # Costs of finished episodes (for J_c) and of the episodes in progress, one per env.
        self.ep_cost_buffer: deque[float] = deque(maxlen=ep_cost_window)
        self._running_ep_cost = np.zeros(self.n_envs if self.env is not None else 1, dtype=np.float64)

    # ------------------------------------------------------------------ setup

    def _setup_model(self) -> None:
        self.rollout_buffer_class = CostRolloutBuffer
        self.rollout_buffer_kwargs = {"cost_gamma": self.cost_gamma, "cost_gae_lambda": self.cost_gae_lambda}
        super()._setup_model()
        if not isinstance(self.policy, CostActorCriticPolicy):
            raise TypeError(f"{type(self).__name__} needs a CostActorCriticPolicy, got {type(self.policy).__name__}")

    @staticmethod
    def _make_schedule(value: float | Schedule, anneal: bool) -> Schedule:
        if callable(value):
            return FloatSchedule(value)
        if anneal:
            return LinearSchedule(float(value), 0.0, 1.0)  # lr * progress_remaining
        return ConstantSchedule(float(value))

    def _setup_lr_schedule(self) -> None:
        """The actor's schedule (a float decays linearly to 0 when ``anneal_lr``) and the critics'
        (constant unless ``anneal_critic_lr``)."""
        self.lr_schedule = self._make_schedule(self.learning_rate, self.anneal_lr)
        critic_lr = self.learning_rate if self.critic_learning_rate is None else self.critic_learning_rate
        self.critic_lr_schedule = self._make_schedule(critic_lr, self.anneal_lr and self.anneal_critic_lr)

    def schedule_progress(self, progress_remaining: float, total_timesteps: int) -> float:
        """The progress (1 -> 0) the learning-rate schedules read for an update made when
        ``progress_remaining`` of a run of ``total_timesteps`` steps is left (SB3's
        ``1 - num_timesteps / total_timesteps`` after the update's rollout). With
        ``anneal_lr_timing="epoch"`` it is moved back to the start of the update's epoch, as OmniSafe
        decays the rate per epoch; ``"progress"`` reads SB3's value as it is. Clipped to [0, 1]."""
        progress = progress_remaining
        if self.anneal_lr_timing == "epoch" and total_timesteps > 0:
            progress += self.n_steps * self.n_envs / total_timesteps  # the epoch's start
        return float(min(1.0, max(0.0, progress)))

    def learning_rates_at(self, progress_remaining: float, total_timesteps: int) -> tuple[float, float]:
        """``(actor_lr, critic_lr)``: the learning rates this model's schedules give an update made
        when ``progress_remaining`` (1 -> 0) of a run of ``total_timesteps`` steps is left.

        The model's own updates use exactly these (:meth:`_update_learning_rates`, at the model's
        current progress); a trainer that runs the model's updates itself (the fleet,
        :mod:`morality_gym.baselines.fleet`) asks here instead of setting SB3's private progress
        attributes. ``actor_lr`` decays linearly to 0 when ``anneal_lr``; ``critic_lr`` is constant
        unless ``anneal_critic_lr`` (CPO's actor takes trust-region steps and ignores ``actor_lr``).
        """
        progress = self.schedule_progress(progress_remaining, total_timesteps)
        return float(self.lr_schedule(progress)), float(self.critic_lr_schedule(progress))

    def _update_learning_rates(self, actor: bool = True) -> tuple[float | None, float]:
        """Set the optimisers' learning rates for this update and log them; returns
        ``(actor_lr or None when the actor does not use one, critic_lr)``."""
        progress = self.schedule_progress(self._current_progress_remaining, self._total_timesteps)
        actor_lr = None
        if actor:
            actor_lr = float(self.lr_schedule(progress))
            update_learning_rate(self.policy.optimizer, actor_lr)
            self.logger.record("train/learning_rate", actor_lr)
        critic_lr = float(self.critic_lr_schedule(progress))
        update_learning_rate(self.policy.critic_optimizer, critic_lr)
        self.logger.record("train/critic_learning_rate", critic_lr)
        return actor_lr, critic_lr

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", "policy.optimizer", "policy.critic_optimizer"], []

    def _excluded_save_params(self) -> list[str]:
        # The diagnostics belong to the run that produced them (written beside the model), and a
        # loaded model starts a fresh log.
        return [*super()._excluded_save_params(), "update_log"]

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        env_will_reset = reset_num_timesteps or self._last_obs is None
        result = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        assert self.env is not None
        if env_will_reset or len(self._running_ep_cost) != self.env.num_envs:
            self._running_ep_cost = np.zeros(self.env.num_envs, dtype=np.float64)
        if reset_num_timesteps:  # like SB3's episode-reward buffer
            self.ep_cost_buffer = deque(maxlen=self.ep_cost_window)
        return result

    # ------------------------------------------------------------------ rollouts

    def _costs_from_infos(self, infos: list[dict[str, Any]]) -> np.ndarray:
        costs = np.empty(len(infos), dtype=np.float32)
        for idx, info in enumerate(infos):
            if COST_INFO_KEY not in info:
                raise MissingCostError(
                    f"{type(self).__name__} reads the cost from info[{COST_INFO_KEY!r}], but env {idx}'s step info "
                    f"has no such key (keys: {sorted(info)}). Wrap every env in {COST_WRAPPER_HINT} "
                    "before vectorising it."
                )
            costs[idx] = float(info[COST_INFO_KEY])
        if not np.all(np.isfinite(costs)):
            raise ValueError(f"non-finite cost in info[{COST_INFO_KEY!r}]: {costs}")
        return costs

    def _track_episode_costs(self, costs: np.ndarray, dones: np.ndarray) -> None:
        """Accumulate the *undiscounted, un-bootstrapped* cost of each env's episode; file it on done."""
        self._running_ep_cost += costs
        for idx in np.flatnonzero(dones):
            self.ep_cost_buffer.append(float(self._running_ep_cost[idx]))
            self._running_ep_cost[idx] = 0.0

    def _bootstrap_truncations(
        self, rewards: np.ndarray, costs: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
    ) -> None:
        """SB3's time-limit convention, for both streams: a truncated (not terminated) episode did
        not end in a terminal state, so its last reward gets ``+ gamma * V(terminal_obs)`` and its
        last cost ``+ cost_gamma * V_c(terminal_obs)``; GAE can then cut the episode at ``done``."""
        for idx, done in enumerate(dones):
            info = infos[idx]
            if done and info.get("terminal_observation") is not None and info.get("TimeLimit.truncated", False):
                terminal_obs = self.policy.obs_to_tensor(info["terminal_observation"])[0]
                with th.no_grad():
                    rewards[idx] += self.gamma * self.policy.predict_values(terminal_obs)[0].item()  # type: ignore[arg-type]
                    costs[idx] += self.cost_gamma * self.policy.predict_cost_values(terminal_obs)[0].item()  # type: ignore[arg-type]

    def collect_rollouts(
        self,
        env: VecEnv,
        callback: BaseCallback,
        rollout_buffer: CostRolloutBuffer,  # type: ignore[override]
        n_rollout_steps: int,
    ) -> bool:
        """Fill the buffer with ``n_rollout_steps`` vec-env steps of rewards *and* costs.

        Same contract as SB3's: callbacks see the step's locals (``infos``, ``dones``, ...,
        plus ``costs``) and may stop the rollout by returning ``False``.
        """
        assert self._last_obs is not None, "No previous observation was provided"
        if self.reset_envs_each_rollout:
            self._reset_envs_for_rollout(env)
        self.policy.set_training_mode(False)
        rollout_buffer.reset()
        callback.on_rollout_start()
        n_steps = 0
        while n_steps < n_rollout_steps:
            with th.no_grad():
                obs_tensor = obs_as_tensor(self._last_obs, self.device)  # type: ignore[arg-type]
                actions, values, log_probs = self.policy(obs_tensor)
                cost_values = self.policy.predict_cost_values(obs_tensor)
            actions = actions.cpu().numpy()
            new_obs, rewards, dones, infos = env.step(actions)
            costs = self._costs_from_infos(infos)
            self.num_timesteps += env.num_envs

            callback.update_locals(locals())
            if not callback.on_step():
                return False

            self._update_info_buffer(infos, dones)
            self._track_episode_costs(costs, dones)
            n_steps += 1
            self._bootstrap_truncations(rewards, costs, dones, infos)
            rollout_buffer.add(
                self._last_obs,  # type: ignore[arg-type]
                actions.reshape(-1, 1),
                rewards,
                self._last_episode_starts,  # type: ignore[arg-type]
                values,
                log_probs,
                costs,
                cost_values,
            )
            self._last_obs = new_obs  # type: ignore[assignment]
            self._last_episode_starts = dones

        with th.no_grad():
            last_obs = obs_as_tensor(new_obs, self.device)  # type: ignore[arg-type]
            last_values = self.policy.predict_values(last_obs)
            last_cost_values = self.policy.predict_cost_values(last_obs)
        rollout_buffer.compute_returns_and_advantage(last_values, dones, last_cost_values)
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True

    def _reset_envs_for_rollout(self, env: VecEnv) -> None:
        """Cut the episodes in progress and start every env afresh (``reset_envs_each_rollout``).

        Skipped when every env has just started an episode (right after ``learn()``'s own reset,
        or when all episodes ended on the last step): a reset would change nothing there. The cut
        episodes' partial costs are dropped, not filed as finished episodes.
        """
        if self._last_episode_starts is not None and np.all(self._last_episode_starts):
            return
        self._last_obs = env.reset()  # type: ignore[assignment]
        self._last_episode_starts = np.ones((env.num_envs,), dtype=bool)
        self._running_ep_cost[:] = 0.0

    def mean_episode_cost(self) -> float:
        """``J_c``: the mean undiscounted cost of the last ``ep_cost_window`` finished episodes.

        Before any episode has finished there is no such mean; the estimate is then the mean, over
        the envs, of the cost accumulated so far by each env's unfinished episode, i.e. the
        rollout's per-episode cost so far. It is a lower bound on those episodes' costs, and it is
        only ever used during the first rollouts of runs whose episodes outlast a rollout.
        """
        if self.ep_cost_buffer:
            return float(np.mean(self.ep_cost_buffer))
        return float(np.mean(self._running_ep_cost))

    def dump_logs(self, iteration: int = 0) -> None:
        if self.ep_cost_buffer:
            self.logger.record("rollout/ep_cost_mean", safe_mean(list(self.ep_cost_buffer)))
        super().dump_logs(iteration)

    # ------------------------------------------------------------------ training helpers

    def _normalize_rollout_advantages(self) -> None:
        """Normalise the rollout's reward and cost advantages in place, once per update (the
        buffer is rebuilt every rollout; returns, the critics' targets, stay raw)."""
        buf = self.rollout_buffer
        buf.advantages = normalize_advantages(buf.advantages, self.reward_advantage_normalization)
        buf.cost_advantages = normalize_advantages(buf.cost_advantages, self.cost_advantage_normalization)

    def _full_batch(self) -> CostRolloutBufferSamples:
        """The whole rollout as one batch (shuffled, which does not matter for batch means)."""
        return next(self.rollout_buffer.get(batch_size=None))

    def _critic_loss(
        self, observations: th.Tensor, returns: th.Tensor, cost_returns: th.Tensor
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """``MSE(V, R) + MSE(V_c, R_c) + critic_l2_coef * sum ||theta_critic||^2``.

        :return: ``(total loss, reward-value loss, cost-value loss)``.
        """
        values = self.policy.predict_values(observations).flatten()  # type: ignore[arg-type]
        cost_values = self.policy.predict_cost_values(observations).flatten()  # type: ignore[arg-type]
        value_loss = F.mse_loss(values, returns)
        cost_value_loss = F.mse_loss(cost_values, cost_returns)
        l2 = sum(p.pow(2).sum() for p in self.policy.critic_parameters())
        return value_loss + cost_value_loss + self.critic_l2_coef * l2, value_loss, cost_value_loss

    def _clip_and_step(self, optimizer: th.optim.Optimizer, parameters: list[th.nn.Parameter]) -> None:
        th.nn.utils.clip_grad_norm_(parameters, self.max_grad_norm)
        optimizer.step()

    def _step_critics(self) -> None:
        """Clip the critics' gradients (``critic_grad_clip``) and take one Adam step on both."""
        if self.critic_grad_clip == "per_critic":
            th.nn.utils.clip_grad_norm_(self.policy.reward_critic_parameters(), self.max_grad_norm)
            th.nn.utils.clip_grad_norm_(self.policy.cost_critic_parameters(), self.max_grad_norm)
        else:
            th.nn.utils.clip_grad_norm_(self.policy.critic_parameters(), self.max_grad_norm)
        self.policy.critic_optimizer.step()

    def _train_critics(self) -> tuple[float, float]:
        """``n_critic_updates`` passes of minibatch regression of ``V`` and ``V_c`` on their
        returns; returns the mean reward- and cost-value losses."""
        value_losses, cost_value_losses = [], []
        for _ in range(self.n_critic_updates):
            for batch in self.rollout_buffer.get(self.batch_size):
                loss, value_loss, cost_value_loss = self._critic_loss(
                    batch.observations, batch.returns, batch.cost_returns
                )
                self.policy.critic_optimizer.zero_grad()
                loss.backward()
                self._step_critics()
                value_losses.append(value_loss.item())
                cost_value_losses.append(cost_value_loss.item())
        return float(np.mean(value_losses)), float(np.mean(cost_value_losses))

    def _mean_kl_to(self, observations: th.Tensor, old_logits: th.Tensor) -> float:
        """Mean ``KL(pi_old || pi_theta)`` over ``observations`` for the current actor."""
        with th.no_grad():
            logits = self.policy.get_distribution(observations).distribution.logits  # type: ignore[union-attr]
            return float(categorical_kl(old_logits, logits).mean())

    def _record_update(self, ep_cost: float, actor_lr: float | None, critic_lr: float, **fields: Any) -> None:
        """Append this update's diagnostics row (columns common to both learners first)."""
        row: dict[str, Any] = {
            "update": len(self.update_log) + 1,
            "timesteps": int(self.num_timesteps),
            "ep_cost": float(ep_cost),
            "ep_cost_episodes": len(self.ep_cost_buffer),
            "actor_lr": actor_lr,
            "critic_lr": critic_lr,
        }
        row.update(fields)
        self.update_log.append(row)

    def _log_critic_fit(self) -> None:
        """Explained variance of both critics on the rollout they were fitted to (before the fit)."""
        buf = self.rollout_buffer
        self.logger.record("train/explained_variance", explained_variance(buf.values.flatten(), buf.returns.flatten()))
        self.logger.record(
            "train/cost_explained_variance", explained_variance(buf.cost_values.flatten(), buf.cost_returns.flatten())
        )
