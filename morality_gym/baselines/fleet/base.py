"""What every fleet trainer shares: K runs' start, their rollouts in one simulator, the learn loop.

A fleet trains ``K`` independent runs of one learner (one :class:`LearnerSpec`, one protocol) in
one process. Each run is what :func:`~morality_gym.baselines.learners.build_learner` would train
for its bound chain and seed, and the fleet reproduces that run's arithmetic step for step:

* **Start.** Each run's single-run learner is built (SB3 seeds its RNGs and initialises the policy
  exactly as for a single run); its weights are copied into the run's slice of the stacked
  networks, and torch's and numpy's global RNG states *after* construction become the run's own
  generators. So a run samples the actions (``torch.multinomial``'s arithmetic on the run's ``torch.Generator``)
  and draws the minibatch permutations (``RandomState.permutation``) that its single run would
  draw, in the same order, and no run's draws depend on another run. The learners are kept: they
  take the trained weights back at the end (:meth:`FleetTrainer.learners`) and evaluate, save and
  render like any single run; their hyper-parameters and schedules are read from the model, so no
  default is defined twice.
* **Rollouts.** One :class:`~.env.FleetEnv` steps all ``K * n_envs`` copies; each step's forward
  pass of every head of every run is one fused network (:class:`~.nets.FusedHeads`). Truncated
  episodes are bootstrapped with the run's critics as SB3 does, in the same float precision as the
  single learner (PPO adds a float32 product, the constrained learners a float64 one).
* **Updates** are the subclasses' (:mod:`.ppo`, :mod:`.ppo_lag`, :mod:`.cpo`), batched over runs
  with hand-written gradients (:mod:`.losses`, :mod:`.nets`), per-run optimiser state
  (:class:`~.optim.BatchedAdam`), per-run clipping and masks; whole-rollout quantities run on each
  rollout's distinct observations (:mod:`.dedup`).

What the fleet cannot share with its single runs is float rounding: batched products sum in
another order than ``addmm``, ``tanh`` is computed another way, PyTorch's fused Adam rounds as its
fused kernel does, and sums over a rollout are taken per distinct observation. Results agree to
float tolerance (about 2e-7 in the parameters after three updates), not bit for bit.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import torch as th

from morality_gym.baselines.fleet.dedup import DistinctStates
from morality_gym.baselines.fleet.env import FleetEnv
from morality_gym.baselines.fleet.losses import Policy
from morality_gym.baselines.fleet.nets import FleetNetworks, policy_linears
from morality_gym.baselines.fleet.optim import BatchedAdam
from morality_gym.baselines.learners import SB3Learner, build_learner
from morality_gym.baselines.specs import LearnerSpec, ProtocolSpec, SpecError, protocol_spec, training_steps
from morality_gym.baselines.targets import resolve
from morality_gym.constants import LEARN_EVAL_EPISODES, MAX_STEPS
from morality_gym.norms.metric import BoundChain

if TYPE_CHECKING:
    from morality_gym.baselines.callbacks import MoralityEvalCallback

#: Called with (run index, learn-time evaluation row) as a single run's ``on_eval`` is with the row.
FleetEvalHook = Callable[[int, dict[str, Any]], None]


@dataclass(frozen=True)
class FleetRun:
    """One run of a fleet: the chain bound to its env id (any variant of the fleet's scenario) and its seed."""

    bound: BoundChain
    seed: int


@dataclass
class Rollout:
    """One rollout of all runs, flattened per run as SB3's buffers flatten it (env-major:
    transition ``e * n_steps + t`` of run ``k`` is step ``t`` of its env ``e``)."""

    obs: th.Tensor  # [K, M, obs_dim]
    actions: th.Tensor  # [K, M] int64
    values: th.Tensor  # [K, M]
    log_probs: th.Tensor  # [K, M]
    advantages: th.Tensor  # [K, M]
    returns: th.Tensor  # [K, M]
    cost_values: th.Tensor | None = None
    cost_advantages: th.Tensor | None = None
    cost_returns: th.Tensor | None = None

    def gather(self, index: th.Tensor, *names: str, runs: th.Tensor | None = None) -> list[th.Tensor]:
        """The named fields at per-run positions ``index`` (``[K, B]``; with ``runs``, ``index`` has
        one row per listed run). One ``index_select`` over the runs' rows laid end to end (4x
        faster than indexing by run and position)."""
        rows = (th.arange(index.shape[0], device=index.device) if runs is None else runs).unsqueeze(1)
        fields = [getattr(self, n) for n in names]
        size = fields[0].shape[1]
        flat = (index + rows * size).reshape(-1)
        return [f.reshape(-1, *f.shape[2:]).index_select(0, flat).view(*index.shape, *f.shape[2:]) for f in fields]

    def minibatches(
        self, order: th.Tensor, batch_size: int, *names: str, runs: th.Tensor | None = None
    ) -> Iterator[tuple[th.Tensor, ...]]:
        """The named fields in each run's ``order`` (``[K, M]``, or one row per run of ``runs``),
        ``batch_size`` transitions at a time (the last batch may be shorter, as SB3's). Gathered
        once per call; the minibatches are contiguous blocks when ``batch_size`` divides ``M``
        (faster batched products)."""
        fields = self.gather(order, *names, runs=runs)
        size = order.shape[1]
        if size % batch_size == 0:
            blocks = [f.reshape(f.shape[0], size // batch_size, batch_size, *f.shape[2:]).movedim(1, 0).contiguous() for f in fields]
            for i in range(size // batch_size):
                yield tuple(b[i] for b in blocks)
            return
        for start in range(0, size, batch_size):
            yield tuple(f[:, start : start + batch_size] for f in fields)


def flatten_runs(arr: np.ndarray, n_runs: int) -> np.ndarray:
    """``[T, K * E, ...] -> [K, E * T, ...]`` in SB3's env-major order (``swap_and_flatten`` per run)."""
    t, n = arr.shape[:2]
    e = n // n_runs
    out = arr.reshape(t, n_runs, e, *arr.shape[2:]).swapaxes(0, 1).swapaxes(1, 2)
    return np.ascontiguousarray(out).reshape(n_runs, e * t, *arr.shape[2:])


def fleet_device(device: str | th.device) -> th.device:
    """``device`` as a torch device, refused (:class:`SpecError`) when torch cannot use it here."""
    try:
        dev = th.device(device)
    except RuntimeError as exc:
        raise SpecError(f"device={device!r}: not a torch device ({exc}); use cpu or cuda") from None
    if dev.type == "cuda" and not th.cuda.is_available():
        raise SpecError(f"device={device!r}: torch sees no GPU here (torch.cuda.is_available() is False); use device=cpu")
    if dev.type not in ("cpu", "cuda"):
        raise SpecError(f"device={device!r}: the fleet engine runs on cpu or cuda")
    return dev


class FleetTrainer:
    """Base of the fleet trainers (see the module docstring). Subclasses set :attr:`algorithm` (the
    import path of the single-run class they reproduce) and :attr:`heads` and implement :meth:`_train` (one update of every run from :attr:`rollout`)."""

    algorithm: ClassVar[str] = ""
    heads: ClassVar[tuple[str, ...]] = ("pi", "vf")
    #: PPO's truncation bootstrap adds ``gamma * V`` in float32 (SB3), the constrained learners in float64.
    cost_aware: ClassVar[bool] = False

    def __init__(
        self,
        spec: LearnerSpec,
        runs: Sequence[FleetRun],
        protocol: ProtocolSpec | str = "paper",
        max_steps: int | None = MAX_STEPS,
        device: str | th.device = "cpu",
    ) -> None:
        self.device = fleet_device(device)
        self.protocol = protocol_spec(protocol)
        self.spec = self.protocol.apply(spec)
        if resolve(self.spec.target) is not resolve(self.algorithm):
            raise SpecError(
                f"learner {self.spec.name!r} is trained by {self.spec.target!r}, "
                f"but {type(self).__name__} reproduces {self.algorithm!r}; use build_fleet"
            )
        self.runs = list(runs)
        if not self.runs:
            raise SpecError("a fleet needs at least one run")
        self.n_runs = len(self.runs)
        self.max_steps = max_steps
        self.n_envs = self.spec.n_envs
        # The simulator first: it refuses env ids of different observation sizes before any
        # learner is built.
        self.env = FleetEnv([r.bound for r in self.runs], self.n_envs, self.spec.reward_cost(), max_steps)
        # The runs' single-run learners: initial weights, RNG states after construction, and the
        # shells the trained weights go back into. Global RNG states are restored afterwards.
        saved = th.get_rng_state(), np.random.get_state()
        self._learners: list[SB3Learner] = []
        self.torch_generators: list[th.Generator] = []
        self.np_generators: list[np.random.RandomState] = []
        try:
            for run in self.runs:
                learner = build_learner(self.spec, run.bound, self.protocol, seed=run.seed, max_steps=max_steps)
                assert isinstance(learner, SB3Learner)
                self._learners.append(learner)
                gen = th.Generator()
                gen.set_state(th.get_rng_state())
                self.torch_generators.append(gen)
                rng = np.random.RandomState()
                rng.set_state(np.random.get_state())
                self.np_generators.append(rng)
        finally:
            th.set_rng_state(saved[0])
            np.random.set_state(saved[1])
        self.model = self._learners[0].model  # hyper-parameters and schedules (the same for every run)
        self._check_supported()
        outputs = {"pi": 6, "vf": 1, "cf": 1}
        self.nets = FleetNetworks(
            self.n_runs, self.env.obs_dim, list(self.spec.net_arch), {h: outputs[h] for h in self.heads}, self.spec.activation,
            device=self.device,
        )
        for k, learner in enumerate(self._learners):
            self.nets.load_run(k, learner.model.policy)
        self.n_steps = int(self.model.n_steps)
        self.gamma = float(self.model.gamma)
        self.gae_lambda = float(self.model.gae_lambda)
        self.num_timesteps = 0
        self.total_timesteps = 0
        self.progress_remaining = 1.0
        #: One list of diagnostics rows per run (the single learner's ``update_log``).
        self.update_logs: list[list[dict[str, Any]]] = [[] for _ in self.runs]
        self.rollout: Rollout | None = None
        self._setup_optimisers()

    # ------------------------------------------------------------------ to override
    def _check_supported(self) -> None:
        """Raise :class:`SpecError` for a setting of :attr:`model` this fleet does not reproduce."""

    def _setup_optimisers(self) -> None:
        raise NotImplementedError

    def _train(self) -> None:
        raise NotImplementedError

    def _export_optimisers(self, k: int, model: Any) -> None:
        """Copy run ``k``'s optimiser state into its single-run model (for saving)."""

    # ------------------------------------------------------------------ helpers
    def _unsupported(self, setting: str, value: Any, supported: str) -> SpecError:
        return SpecError(
            f"learner {self.spec.name!r}: {setting}={value!r} is not reproduced by the fleet engine "
            f"({supported}); run it with the single engine"
        )

    @staticmethod
    def _export_adam(optimiser: BatchedAdam, k: int, torch_adam: th.optim.Optimizer, policy: Any, heads: Sequence[str]) -> None:
        """Run ``k``'s slices of ``optimiser`` (over the stacked ``heads``) into the single-run
        ``torch_adam`` over the same layers of ``policy``."""
        torch_params = [p for head in heads for lin in policy_linears(policy, head) for p in (lin.weight, lin.bias)]
        torch_adam.state.clear()
        for param, state in zip(torch_params, optimiser.state_of(k)):
            if float(state["step"]) == 0:
                continue
            torch_adam.state[param] = {
                "step": state["step"].cpu(),
                "exp_avg": state["exp_avg"].reshape(param.shape).cpu().clone(),  # biases are stored [out, 1]
                "exp_avg_sq": state["exp_avg_sq"].reshape(param.shape).cpu().clone(),
            }

    # ------------------------------------------------------------------ learning
    def learn(
        self,
        budget: int,
        eval_every: int = 0,
        eval_episodes: int = LEARN_EVAL_EPISODES,
        on_eval: FleetEvalHook | None = None,
        on_progress: Callable[[int, int], None] | None = None,
    ) -> int:
        """Train every run on ``budget`` environment steps (as :meth:`SB3Learner.learn` counts
        them); learn-time evaluations as the single runs make them when ``eval_every > 0``;
        ``on_progress(steps, total)`` after every update (a fleet at the paper's budget trains for
        many minutes before its first run is written). Returns the steps each run trained."""
        self.total_timesteps = training_steps(self.spec, budget)
        self._start_evaluations(eval_every, eval_episodes, on_eval)
        self.num_timesteps = 0
        self.progress_remaining = 1.0
        self._last_obs = self.env.reset()
        self._last_starts = np.ones(self.n_runs * self.n_envs, dtype=bool)
        self._running_ep_cost = np.zeros(self.n_runs * self.n_envs, dtype=np.float64)
        window = int(getattr(self.model, "ep_cost_window", 1))
        self.ep_cost_buffers: list[deque[float]] = [deque(maxlen=window) for _ in self.runs]
        self._evaluate_if_due()
        while self.num_timesteps < self.total_timesteps:
            self._collect_rollout()
            self.progress_remaining = 1.0 - float(self.num_timesteps) / float(self.total_timesteps)
            self._train()
            if on_progress is not None:
                on_progress(self.num_timesteps, self.total_timesteps)
        self._finish()
        return self.num_timesteps

    def _start_evaluations(self, eval_every: int, eval_episodes: int, on_eval: FleetEvalHook | None) -> None:
        # torch waits: importing morality_gym.baselines.fleet.base must not load it
        from stable_baselines3.common.logger import configure

        self._eval_every = int(eval_every)
        self._next_eval = 0
        self._callbacks: list[MoralityEvalCallback] = []
        if self._eval_every <= 0 and self.total_timesteps > 0:
            return
        for k, learner in enumerate(self._learners):
            hook = (lambda row, k=k: on_eval(k, row)) if on_eval is not None else None
            callback = learner.eval_callback(self._eval_every, eval_episodes, hook)
            learner.model.set_logger(configure(None, []))  # evaluations record into a silent logger
            callback.model = learner.model
            self._callbacks.append(callback)

    def _evaluate_if_due(self) -> None:
        if not self._callbacks or self.num_timesteps < self._next_eval:
            return
        for k, (learner, callback) in enumerate(zip(self._learners, self._callbacks)):
            self.nets.export_run(k, learner.model.policy)
            callback.evaluate_now(self.num_timesteps)
        if self._eval_every <= 0:
            self._next_eval = np.iinfo(np.int64).max
            return
        while self._next_eval <= self.num_timesteps:
            self._next_eval += self._eval_every

    def _finish(self) -> None:
        """Hand every run's weights, optimiser state, step count and diagnostics to its learner."""
        for k, learner in enumerate(self._learners):
            model = learner.model
            self.nets.export_run(k, model.policy)
            self._export_optimisers(k, model)
            model.num_timesteps = self.num_timesteps
            if hasattr(model, "update_log"):
                model.update_log = [dict(row) for row in self.update_logs[k]]
            learner.trained_steps = self.num_timesteps

    def learners(self) -> list[SB3Learner]:
        """The runs' single-run learners, holding the fleet's trained weights after :meth:`learn`."""
        return list(self._learners)

    # ------------------------------------------------------------------ rollouts
    def _draw_action_noise(self) -> None:
        """Every run's exponential noise for the whole coming rollout, from its own generator.

        ``torch.multinomial(probs, 1)`` (how ``Categorical.sample`` draws one action) is
        ``argmax(probs / q)`` with ``q = empty_like(probs).exponential_(1)`` on the caller's
        generator, element after element. Drawing a rollout's ``q`` in one call per run consumes
        each generator exactly as the rollout's per-step draws would (a test checks the actions
        against ``torch.multinomial``), and turns K sampling calls per step into one ``argmax``.
        """
        shape = (self.n_steps, self.n_envs, 6)
        self._action_noise = th.stack([th.empty(shape).exponential_(1, generator=g) for g in self.torch_generators]).to(self.device)

    def _policy_step(self, obs: th.Tensor, t: int) -> tuple[th.Tensor, ...]:
        """Actions (sampled per run from its own noise, step ``t`` of the rollout), values,
        log-probs and cost values."""
        outputs = self._rollout_nets(obs)
        policy = Policy.of(outputs[0])
        actions = (policy.p / self._action_noise[:, t].transpose(1, 2)).argmax(dim=1)
        log_probs = policy.log_prob(actions)
        values = outputs[1][:, 0]
        cost_values = outputs[2][:, 0] if self.cost_aware else None
        return actions, values, log_probs, cost_values

    def _reset_runs_for_rollout(self) -> None:
        """``reset_envs_each_rollout`` per run: each run whose envs have not all just started an
        episode is reset, and its partial episode costs dropped (as the single learner)."""
        starts = self._last_starts.reshape(self.n_runs, self.n_envs)
        cut = ~starts.all(axis=1)
        if not cut.any():
            return
        copies = self.env.copies_of(cut)
        obs = self.env.reset(cut)
        self._last_obs = np.where(copies[:, None], obs, self._last_obs)
        self._last_starts = self._last_starts | copies
        self._running_ep_cost[copies] = 0.0

    def _collect_rollout(self) -> None:
        k_runs, e, t_steps, d = self.n_runs, self.n_envs, self.n_steps, self.env.obs_dim
        n = k_runs * e
        if self.cost_aware and getattr(self.model, "reset_envs_each_rollout", False):
            self._reset_runs_for_rollout()
        obs_buf = np.zeros((t_steps, n, d), dtype=np.float32)
        act_buf = np.zeros((t_steps, n), dtype=np.int64)
        rew_buf = np.zeros((t_steps, n), dtype=np.float32)
        start_buf = np.zeros((t_steps, n), dtype=np.float32)
        val_buf = np.zeros((t_steps, n), dtype=np.float32)
        logp_buf = np.zeros((t_steps, n), dtype=np.float32)
        if self.cost_aware:
            cost_buf = np.zeros((t_steps, n), dtype=np.float32)
            cval_buf = np.zeros((t_steps, n), dtype=np.float32)
            cost_gamma = float(self.model.cost_gamma)
        self._draw_action_noise()
        self._rollout_nets = self.nets.fused(self.heads)
        for t in range(t_steps):
            with th.no_grad():
                actions, values, log_probs, cost_values = self._policy_step(self._tensor(self._last_obs).view(k_runs, e, d), t)
            act = actions.reshape(n).cpu().numpy()
            step = self.env.step(act)
            self.num_timesteps += e
            self._evaluate_if_due()
            rewards = step.rewards
            bootstrap = step.truncated if step.final_obs is not None else None
            if self.cost_aware:
                costs = step.costs.astype(np.float32)
                self._track_episode_costs(costs, step.dones)
            if bootstrap is not None and bootstrap.any():
                with th.no_grad():
                    final = self._tensor(step.final_obs).view(k_runs, e, d)
                    v_end = self.nets("vf", final).reshape(n).cpu()
                    if self.cost_aware:
                        vc_end = self.nets("cf", final).reshape(n).cpu()
                if self.cost_aware:
                    # rewards[i] += gamma * V.item(): a float64 product added to a float32 (NEP 50).
                    rewards = np.where(bootstrap, rewards + (self.gamma * v_end.double().numpy()).astype(np.float32), rewards)
                    costs = np.where(bootstrap, costs + (cost_gamma * vc_end.double().numpy()).astype(np.float32), costs)
                else:
                    # rewards[i] += gamma * V (a float32 tensor): float32 throughout.
                    rewards = np.where(bootstrap, rewards + (self.gamma * v_end).numpy(), rewards)
            obs_buf[t] = self._last_obs
            act_buf[t] = act
            rew_buf[t] = rewards
            start_buf[t] = self._last_starts
            val_buf[t] = values.reshape(n).cpu().numpy()
            logp_buf[t] = log_probs.reshape(n).cpu().numpy()
            if self.cost_aware:
                cost_buf[t] = costs
                cval_buf[t] = cost_values.reshape(n).cpu().numpy()  # type: ignore[union-attr]
            self._last_obs = step.obs
            self._last_starts = step.dones

        # torch waits: importing morality_gym.baselines.fleet.base must not load it
        from morality_gym.baselines.safe.functional import gae

        with th.no_grad():
            last = self._tensor(step.obs).view(k_runs, e, d)
            last_v = self.nets("vf", last).reshape(n).cpu().numpy()
            last_vc = self.nets("cf", last).reshape(n).cpu().numpy() if self.cost_aware else None
        adv, ret = gae(rew_buf, val_buf, start_buf, last_v, step.dones, self.gamma, self.gae_lambda)
        fields: dict[str, np.ndarray] = {
            "obs": obs_buf, "actions": act_buf, "values": val_buf, "log_probs": logp_buf, "advantages": adv, "returns": ret,
        }
        if self.cost_aware:
            cadv, cret = gae(
                cost_buf, cval_buf, start_buf, last_vc, step.dones, cost_gamma, float(self.model.cost_gae_lambda)  # type: ignore[arg-type]
            )
            fields.update(cost_values=cval_buf, cost_advantages=cadv, cost_returns=cret)
            self._rollout_raw = {"advantages": adv, "cost_advantages": cadv}  # (T, K*E), for per-run normalisation
        self.rollout = Rollout(**{name: self._tensor(flatten_runs(arr, k_runs)) for name, arr in fields.items()})
        self._distinct: list[DistinctStates] | None = None

    def distinct_states(self) -> list[DistinctStates]:
        """Each run's rollout as distinct observations (:mod:`.dedup`), computed once per rollout."""
        if self._distinct is None:
            assert self.rollout is not None
            self._distinct = [DistinctStates.of(self.rollout.obs[k], self.device) for k in range(self.n_runs)]
        return self._distinct

    def _track_episode_costs(self, costs: np.ndarray, dones: np.ndarray) -> None:
        self._running_ep_cost += costs
        for i in np.flatnonzero(dones):
            self.ep_cost_buffers[i // self.n_envs].append(float(self._running_ep_cost[i]))
            self._running_ep_cost[i] = 0.0

    def mean_episode_costs(self) -> np.ndarray:
        """``J_c`` of every run (``CostOnPolicyAlgorithm.mean_episode_cost`` per run), ``[K]`` float64."""
        running = self._running_ep_cost.reshape(self.n_runs, self.n_envs)
        return np.array([
            float(np.mean(buf)) if buf else float(np.mean(running[k])) for k, buf in enumerate(self.ep_cost_buffers)
        ])

    def permutation(self, k: int, size: int) -> np.ndarray:
        """Run ``k``'s next permutation of ``size`` transitions (its single run's ``np.random.permutation``)."""
        return self.np_generators[k].permutation(size)

    def permutations(self, size: int) -> th.Tensor:
        """``[K, size]``: every run's next permutation."""
        return self._tensor(np.stack([self.permutation(k, size) for k in range(self.n_runs)]))

    def _tensor(self, arr: np.ndarray) -> th.Tensor:
        """A numpy array as a tensor on the fleet's device (shared memory on the CPU)."""
        return th.from_numpy(arr).to(self.device)

