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
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

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


class Checkpointer(Protocol):
    """What :meth:`FleetTrainer.learn` asks of a checkpoint (:class:`~.checkpoint.FleetCheckpoint`
    is the one we ship). Declared here, so that the learn loop does not depend on the file format."""

    def restore(self, fleet: FleetTrainer) -> bool:
        """Load a saved state into ``fleet`` (at step 0); True if training resumes from it."""
        ...

    def due(self) -> bool:
        """True when a state should be written at this update boundary."""
        ...

    def write(self, fleet: FleetTrainer) -> None:
        """Write ``fleet``'s state."""
        ...


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

    def _optimisers(self) -> dict[str, BatchedAdam]:
        """Every optimiser of the trainer by name (their moments and step counts are checkpointed)."""
        raise NotImplementedError

    def _extra_state(self) -> dict[str, Any]:
        """State a subclass keeps between updates besides networks and optimisers (checkpointed)."""
        return {}

    def _load_extra_state(self, state: dict[str, Any]) -> None:
        """Restore :meth:`_extra_state` (in place where other tensors view it)."""

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
        checkpoint: Checkpointer | None = None,
    ) -> int:
        """Train every run on ``budget`` environment steps (as :meth:`SB3Learner.learn` counts
        them); learn-time evaluations as the single runs make them when ``eval_every > 0``;
        ``on_progress(steps, total)`` after every update (a fleet at the paper's budget trains for
        many minutes before its first run is written). Returns the steps each run trained.

        With a ``checkpoint`` (:class:`~.checkpoint.FleetCheckpoint`) the training state is written
        to its file at update boundaries (at most every ``every_s`` seconds, and once when training
        ends), and a matching file found at the start is restored first: training continues from
        its step count and ends exactly (bit for bit) as it would have without the interruption.
        ``on_progress`` is then told the resumed step count before the first update."""
        self.total_timesteps = training_steps(self.spec, budget)
        self._start_evaluations(eval_every, eval_episodes, on_eval)
        self._start_training()
        if checkpoint is not None and checkpoint.restore(self) and on_progress is not None:
            on_progress(self.num_timesteps, self.total_timesteps)
        self._evaluate_if_due()
        while self.num_timesteps < self.total_timesteps:
            self._collect_rollout()
            self.progress_remaining = 1.0 - float(self.num_timesteps) / float(self.total_timesteps)
            self._train()
            if on_progress is not None:
                on_progress(self.num_timesteps, self.total_timesteps)
            if checkpoint is not None and checkpoint.due():
                checkpoint.write(self)
        if checkpoint is not None:
            checkpoint.write(self)  # a kill while the runs are recorded does not retrain them
        self._finish()
        return self.num_timesteps

    def _start_training(self) -> None:
        """The state of a run at step 0: every copy reset, no episode cost recorded yet."""
        self.num_timesteps = 0
        self.progress_remaining = 1.0
        self._last_obs = self.env.reset()
        self._last_starts = np.ones(self.n_runs * self.n_envs, dtype=bool)
        self._running_ep_cost = np.zeros(self.n_runs * self.n_envs, dtype=np.float64)
        window = int(getattr(self.model, "ep_cost_window", 1))
        self.ep_cost_buffers: list[deque[float]] = [deque(maxlen=window) for _ in self.runs]

    # ------------------------------------------------------------------ checkpoints
    def identity(self) -> dict[str, Any]:
        """What a checkpoint of this fleet's training only fits: the learner (every hyper-parameter),
        the protocol, each run's env id, chain and seed, the budget, the evaluation schedule and the
        device. :meth:`load_state_dict` refuses a state of another identity."""
        return {
            "algorithm": self.algorithm,
            "spec": repr(self.spec),
            "protocol": repr(self.protocol),
            "runs": [[r.bound.env_id, r.bound.chain.name, float(r.bound.beta), int(r.seed)] for r in self.runs],
            "max_steps": self.max_steps,
            "n_envs": self.n_envs,
            "total_timesteps": self.total_timesteps,
            "eval_every": self._eval_every,
            "eval_episodes": self._eval_episodes,
            "device": str(self.device),
        }

    def state_dict(self) -> dict[str, Any]:
        """The whole training state between two updates (call it at an update boundary of
        :meth:`learn`), as tensors (on the CPU) and plain Python data, so that it can be written
        with ``torch.save`` and read back with ``torch.load(weights_only=True)``.

        Everything an update or a rollout reads and changes: the stacked networks, every
        optimiser's moments and step counts (and a subclass's :meth:`_extra_state`, PPO-Lag's
        multipliers), each run's torch and numpy generator, the simulator and the cost memory,
        the last observations and episode starts, the episode-cost bookkeeping, the step count and
        progress, the diagnostics rows, and the learn-time evaluations' schedule, seed counters and
        rows. What is rebuilt each rollout (the rollout, its action noise and distinct states) and
        what never changes (hyper-parameters, schedules) is not kept. Nothing of training uses the
        global RNGs (the runs' generators are their own, evaluations seed their own), so they are
        not kept either (a test changes them between interruption and resume).
        """
        return {
            "identity": self.identity(),
            "num_timesteps": int(self.num_timesteps),
            "progress_remaining": float(self.progress_remaining),
            "next_eval": int(self._next_eval),
            "nets": {head: [t.detach().cpu().clone() for layer in layers for t in layer] for head, layers in self.nets.heads.items()},
            "optimisers": {name: opt.state_dict() for name, opt in self._optimisers().items()},
            "extra": self._extra_state(),
            "torch_generators": [g.get_state() for g in self.torch_generators],
            "np_generators": [_random_state_dict(rng) for rng in self.np_generators],
            "env": _tensors(self.env.state_dict()),
            "last_obs": th.from_numpy(self._last_obs.copy()),
            "last_starts": th.from_numpy(self._last_starts.copy()),
            "running_ep_cost": th.from_numpy(self._running_ep_cost.copy()),
            "ep_cost_buffers": [[float(c) for c in buf] for buf in self.ep_cost_buffers],
            "update_logs": plain_data(self.update_logs),
            "evaluations": [cb.state_dict() for cb in self._callbacks],
            "learn_evals": [plain_data(learner.learn_evals) for learner in self._learners],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Continue from :meth:`state_dict` of a fleet of the same :meth:`identity` (raises
        :class:`CheckpointMismatch` otherwise, before changing anything). Called by :meth:`learn`
        after it set up step 0 and the evaluations. Tensors are copied *in place*: the networks'
        parameters are views into their optimisers' flat buffers. Should a part fail to load
        (a damaged file), the state from before the call is put back and the error raised."""
        mine, theirs = self.identity(), state.get("identity")
        if theirs != mine:
            raise CheckpointMismatch(_difference(mine, theirs))
        before = self.state_dict()
        try:
            self._load(state)
        except Exception:
            self._load(before)
            raise

    @th.no_grad()
    def _load(self, state: dict[str, Any]) -> None:
        for head, layers in self.nets.heads.items():
            saved = state["nets"][head]
            tensors = [t for layer in layers for t in layer]
            if len(saved) != len(tensors) or any(a.shape != b.shape for a, b in zip(saved, tensors)):
                raise ValueError(f"head {head!r}: the saved layers do not fit the network")
            for t, value in zip(tensors, saved):
                t.copy_(value)
        optimisers = self._optimisers()
        if set(state["optimisers"]) != set(optimisers):
            raise ValueError(f"optimisers: expected {sorted(optimisers)}, got {sorted(state['optimisers'])}")
        for name, opt in optimisers.items():
            opt.load_state_dict(state["optimisers"][name])
        self._load_extra_state(state["extra"])
        if len(state["torch_generators"]) != self.n_runs or len(state["np_generators"]) != self.n_runs:
            raise ValueError("one generator per run expected")
        for gen, gen_state in zip(self.torch_generators, state["torch_generators"]):
            gen.set_state(gen_state)
        for rng, rng_state in zip(self.np_generators, state["np_generators"]):
            _load_random_state(rng, rng_state)
        self.env.load_state_dict(state["env"])
        self._last_obs = _array_like(self._last_obs, state["last_obs"], "last observations")
        self._last_starts = _array_like(self._last_starts, state["last_starts"], "episode starts")
        self._running_ep_cost = _array_like(self._running_ep_cost, state["running_ep_cost"], "running episode costs")
        window = int(getattr(self.model, "ep_cost_window", 1))
        self.ep_cost_buffers = [deque((float(c) for c in costs), maxlen=window) for costs in state["ep_cost_buffers"]]
        self.num_timesteps = int(state["num_timesteps"])
        self.progress_remaining = float(state["progress_remaining"])
        self._next_eval = int(state["next_eval"])
        self.update_logs = [[dict(row) for row in rows] for rows in state["update_logs"]]
        if len(state["evaluations"]) != len(self._callbacks) or len(state["learn_evals"]) != self.n_runs:
            raise ValueError("evaluation state does not fit the fleet's evaluations")
        for callback, cb_state in zip(self._callbacks, state["evaluations"]):
            callback.load_state_dict(cb_state)
        for learner, rows in zip(self._learners, state["learn_evals"]):
            learner.learn_evals = [dict(row) for row in rows]
        if len(self.update_logs) != self.n_runs or len(self.ep_cost_buffers) != self.n_runs:
            raise ValueError("per-run state of another number of runs")

    def _start_evaluations(self, eval_every: int, eval_episodes: int, on_eval: FleetEvalHook | None) -> None:
        # torch waits: importing morality_gym.baselines.fleet.base must not load it
        from stable_baselines3.common.logger import configure

        self._eval_every = int(eval_every)
        self._eval_episodes = int(eval_episodes)
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
        # drawn on the CPU, where the runs' generators live, so the draws are the single runs' bits
        self._action_noise = th.stack(
            [th.empty(shape, device="cpu").exponential_(1, generator=g) for g in self.torch_generators]
        ).to(self.device)

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



class CheckpointMismatch(ValueError):
    """A saved training state that belongs to another fleet (learner, runs, budget, device...)."""


def _difference(mine: dict[str, Any], theirs: Any) -> str:
    """The first field in which a saved identity differs from this fleet's, in words."""
    if not isinstance(theirs, dict):
        return "the file holds no fleet identity"
    for key, value in mine.items():
        if theirs.get(key) != value:
            return f"{key} differs (saved {theirs.get(key)!r}, this fleet {value!r})"
    return f"saved fields {sorted(set(theirs) - set(mine))} are unknown here"


def plain_data(value: Any) -> Any:
    """``value`` (dicts, lists, scalars, as diagnostics and evaluation rows hold them) with numpy
    scalars as Python scalars and tuples as lists, which ``torch.load(weights_only=True)`` reads back.
    Exact: a float64 is a Python float, an integer an int."""
    if isinstance(value, dict):
        return {k: plain_data(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, deque)):
        return [plain_data(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _tensors(value: Any) -> Any:
    """``value`` with every numpy array as a tensor (unsigned 32-bit as int64: exact, and a type
    ``torch.save`` handles everywhere); readers cast back to their arrays' dtypes."""
    if isinstance(value, dict):
        return {k: _tensors(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_tensors(v) for v in value]
    if isinstance(value, np.ndarray):
        arr = value.astype(np.int64) if value.dtype == np.uint32 else value
        return th.from_numpy(np.ascontiguousarray(arr).copy())
    return value


def _array_like(current: np.ndarray, value: th.Tensor, what: str) -> np.ndarray:
    """``value`` as a numpy array of ``current``'s shape and dtype (a copy)."""
    arr = value.numpy()
    if arr.shape != current.shape:
        raise ValueError(f"{what}: expected shape {current.shape}, got {arr.shape}")
    return arr.astype(current.dtype, copy=True)


def _random_state_dict(rng: np.random.RandomState) -> dict[str, Any]:
    """A ``RandomState``'s Mersenne Twister state as a tensor and plain numbers."""
    name, keys, pos, has_gauss, gauss = rng.get_state(legacy=True)  # type: ignore[misc]
    return {"name": str(name), "keys": th.from_numpy(keys.astype(np.int64)), "pos": int(pos), "has_gauss": int(has_gauss),
            "gauss": float(gauss)}


def _load_random_state(rng: np.random.RandomState, state: dict[str, Any]) -> None:
    keys = state["keys"].numpy().astype(np.uint32)
    rng.set_state((state["name"], keys, int(state["pos"]), int(state["has_gauss"]), float(state["gauss"])))
