"""The learn loop every fleet trainer shares: K runs' start, rollouts, updates, checkpoints.

A fleet trains ``K`` independent runs of one learner (one :class:`LearnerSpec`, one protocol) in
one process. Each run is what :func:`~morality_gym.baselines.learners.build_learner` would train
for its bound chain and seed, and the fleet reproduces that run's arithmetic step for step:

* **Start.** Each run's single-run learner is built (SB3 seeds its RNGs and initialises the policy
  exactly as for a single run); its weights are copied into the run's slice of the stacked
  networks, and torch's and numpy's global RNG states *after* construction become the run's own
  generators (:class:`~.streams.RunStreams`). So a run samples the actions and draws the minibatch
  permutations that its single run would draw, in the same order, and no run's draws depend on
  another run. The learners are kept: they take the trained weights back at the end
  (:meth:`FleetTrainer.learners`) and evaluate, save and render like any single run; their
  hyper-parameters and schedules are read from the model, so no default is defined twice.
* **Rollouts** are :class:`~.rollout.RolloutCollector`'s: all ``K * n_envs`` copies in one
  simulator (:mod:`.env`), every head of every run in one fused network (:class:`~.nets.FusedHeads`).
* **Updates** are the subclasses' (:mod:`.ppo`, :mod:`.ppo_lag`, :mod:`.cpo`), batched over runs
  with hand-written gradients (:mod:`.losses`, :mod:`.nets`), per-run optimiser state
  (:class:`~.optim.BatchedAdam`), per-run clipping and masks; whole-rollout quantities run on each
  rollout's distinct observations (:mod:`.dedup`).
* **Checkpoints**: the training state is the parts' ``state_dict()``s (:meth:`FleetTrainer.state_dict`),
  written by :mod:`.checkpoint`; a killed fleet resumes bit for bit.
* **A run that goes non-finite** (a NaN or infinite weight, moment or multiplier after an update)
  fails alone, as its single run would: it is listed in :attr:`FleetTrainer.failed` with its own
  error, its slice of every network and optimiser is zeroed (so nothing non-finite is checkpointed
  or evaluated) and it is no longer evaluated, while the other runs train on. Runs share no
  arithmetic, so they end with the bits they would have had beside a healthy run.

What the fleet cannot share with its single runs is float rounding: batched products sum in
another order than ``addmm``, ``tanh`` is computed another way, PyTorch's fused Adam rounds as its
fused kernel does, and sums over a rollout are taken per distinct observation. Results agree to
float tolerance (about 2e-7 in the parameters after three updates), not bit for bit.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Protocol

import numpy as np
import torch as th
from stable_baselines3.common.logger import configure

from morality_gym.baselines.callbacks import MoralityEvalCallback
from morality_gym.baselines.device import Device
from morality_gym.baselines.fleet.compiled import (
    DEFAULT_UPDATE_ENGINE,
    UPDATE_ENGINES,
    Backend,
    Step,
    adam_in_graph,
    compiled_step,
)
from morality_gym.baselines.fleet.dedup import DistinctStates
from morality_gym.baselines.fleet.drawn_env import DrawnFleetEnv
from morality_gym.baselines.fleet.env import DeviceFleetEnv, FleetEnv, Simulator, fleet_env
from morality_gym.baselines.fleet.nets import FleetNetworks, policy_linears
from morality_gym.baselines.fleet.optim import BatchedAdam
from morality_gym.baselines.fleet.rollout import Rollout, RolloutCollector, RolloutSettings
from morality_gym.baselines.fleet.state import CheckpointMismatch, key_difference, plain_data
from morality_gym.baselines.fleet.streams import RunStreams
from morality_gym.baselines.learners import make_learner
from morality_gym.baselines.sb3_learner import SB3Learner
from morality_gym.baselines.specs import LearnerSpec, ProtocolSpec, SpecError, protocol_spec, training_steps
from morality_gym.baselines.targets import resolve
from morality_gym.constants import LEARN_EVAL_EPISODES, MAX_STEPS
from morality_gym.norms.metric import BoundChain

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
    """One run of a fleet: the chain bound to its env id (any variant of the fleet's scenario) and its seed.

    With a ``pool`` (the generalisation track: :meth:`mixture`) the run trains on the mixture of the
    pool's dilemmas instead, each episode drawn by the run's seed, seen through the compact
    observation (:mod:`.drawn_env`); ``bound`` is then the pool's first entry (:meth:`where` names
    the mixture on messages).
    """

    bound: BoundChain
    seed: int
    pool: tuple[BoundChain, ...] = ()

    @classmethod
    def mixture(cls, pool: Sequence[BoundChain], seed: int) -> FleetRun:
        """A run on the mixture of ``pool`` (each a dilemma bound to the run's chain)."""
        if not pool:
            raise SpecError("a mixture run needs a pool of at least one bound chain")
        return cls(pool[0], seed, tuple(pool))

    def where(self) -> str:
        """What the run trains on, for messages: its env id, or its mixture (not the pool's first entry)."""
        if self.pool:
            return f"the mixture of {len(self.pool)} dilemmas"
        return self.bound.env_id

    def pool_digest(self) -> str:
        """What identifies the pool in a checkpoint: SHA-256 of its (env id, chain, beta) entries."""
        text = "\n".join(f"{b.env_id}\t{b.chain.name}\t{float(b.beta)!r}" for b in self.pool)
        return hashlib.sha256(text.encode()).hexdigest()


def fleet_device(device: str | th.device | Device, here: bool = True) -> th.device:
    """``device`` as a torch device, refused (:class:`SpecError`) when it is not one the fleet
    engine runs on, or, with ``here``, when torch cannot use it in this process (a dry run, or a
    SLURM submission whose GPUs are on the compute nodes, passes ``here=False``).

    A :class:`~morality_gym.baselines.device.Device` (what a sweep resolves once and carries down)
    is not parsed or checked again: it was checked on this machine, or is checked now if it was
    not (:meth:`~morality_gym.baselines.device.Device.usable`). A string is a library caller's."""
    if isinstance(device, Device):
        if here:
            device.usable()
        return th.device(device.name)
    try:
        dev = th.device(device)
    except RuntimeError as exc:
        raise SpecError(f"device={device!r}: not a torch device ({exc}); use cpu or cuda") from None
    if here and dev.type == "cuda" and not th.cuda.is_available():
        raise SpecError(f"device={device!r}: torch sees no GPU here (torch.cuda.is_available() is False); use device=cpu")
    if dev.type not in ("cpu", "cuda"):
        raise SpecError(f"device={device!r}: the fleet engine runs on cpu or cuda")
    return dev


def update_engine(update: str) -> str:
    """``update`` checked: one of :data:`~.compiled.UPDATE_ENGINES` (a :class:`SpecError` otherwise)."""
    if update not in UPDATE_ENGINES:
        raise SpecError(f"update={update!r}: the fleet's update engines are {' and '.join(UPDATE_ENGINES)}")
    return update


class FleetTrainer:
    """Base of the fleet trainers (see the module docstring). Subclasses set :attr:`algorithm` (the
    import path of the single-run class they reproduce) and :attr:`heads` and implement :meth:`_train` (one update of every run from :attr:`rollout`)."""

    algorithm: ClassVar[str] = ""
    heads: ClassVar[tuple[str, ...]] = ("pi", "vf")
    #: PPO's truncation bootstrap adds ``gamma * V`` in float32 (SB3), the constrained learners in float64.
    cost_aware: ClassVar[bool] = False
    #: The ``torch.compile`` backend of the compiled engine: None is inductor (CUDA graphs on a GPU);
    #: tests set :func:`~.compiled.static_check`, which checks the graph without generating code.
    compile_backend: Backend = None
    #: Whether the compiled steps take their Adam step in the graph (None: :func:`~.compiled.adam_in_graph`).
    adam_in_graph: bool | None = None

    def __init__(
        self,
        spec: LearnerSpec,
        runs: Sequence[FleetRun],
        protocol: ProtocolSpec | str = "paper",
        max_steps: int | None = MAX_STEPS,
        device: str | th.device | Device = "cpu",
        simulator: Simulator = "auto",
        update: str = DEFAULT_UPDATE_ENGINE,
        table_cache: Path | None = None,
    ) -> None:
        self.device = fleet_device(device)
        #: Where a mixture's tables are kept between processes (:mod:`morality_gym.envs.table_cache`).
        self.table_cache = table_cache
        #: ``eager`` or ``compiled`` (:mod:`.compiled`): how the minibatch steps run.
        self.update_engine = update_engine(update)
        self.protocol = protocol_spec(protocol)  # what its checkpoints are keyed by
        if spec.protocol != self.protocol.name:
            raise SpecError(f"learner {spec.name!r} is not resolved for protocol {self.protocol.name!r} "
                            f"(it carries {spec.protocol!r}); use build_fleet, which applies the protocol")
        self.spec = spec
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
        # The simulator first: it pads the observations of runs of different scenarios to one width.
        env = self._make_env(simulator, max_steps)
        self._learners, self.streams = self._build_learners()
        self.model = self._learners[0].model  # hyper-parameters and schedules (the same for every run)
        self._check_supported()
        outputs = {"pi": 6, "vf": 1, "cf": 1}
        self.nets = FleetNetworks(
            self.n_runs, env.obs_dim, list(self.spec.net_arch), {h: outputs[h] for h in self.heads}, self.spec.activation,
            device=self.device, in_dims=env.run_obs_dims,
        )
        for k, learner in enumerate(self._learners):
            self.nets.load_run(k, learner.model.policy)
        self.collector = RolloutCollector(env, self.n_runs, self.n_envs, RolloutSettings.of(self.model, self.cost_aware), self.device)
        self.num_timesteps = 0
        self.total_timesteps = 0
        self.progress_remaining = 1.0
        #: One list of diagnostics rows per run (the single learner's ``update_log``).
        self.update_logs: list[list[dict[str, Any]]] = [[] for _ in self.runs]
        self.rollout: Rollout | None = None
        self._distinct: list[DistinctStates] | None = None
        self._callbacks: list[MoralityEvalCallback] = []
        self._eval_every, self._eval_episodes, self._next_eval = 0, LEARN_EVAL_EPISODES, 0
        #: Runs that went non-finite: run index -> why (see the module docstring); checkpointed.
        self.failed: dict[int, str] = {}
        self._setup_optimisers()

    def _make_env(self, simulator: Simulator, max_steps: int | None) -> FleetEnv | DeviceFleetEnv | DrawnFleetEnv:
        """The runs' simulator: :func:`.env.fleet_env`, or the drawn mixture when the runs have pools."""
        pooled = [bool(r.pool) for r in self.runs]
        if not any(pooled):
            return fleet_env(simulator, [r.bound for r in self.runs], self.n_envs, self.spec.reward_cost(), max_steps, self.device)
        if not all(pooled):
            raise SpecError("a fleet trains either mixture runs (with a pool) or single-env runs, not both")
        if simulator == "device":
            raise SpecError("simulator='device': the mixture is simulated on the host (its tables are large); "
                            "use simulator='auto' or 'host' (the networks still train on the device)")
        return DrawnFleetEnv([r.pool for r in self.runs], [r.seed for r in self.runs], self.n_envs,
                             self.spec.reward_cost(), max_steps, self.device, table_cache=self.table_cache)

    def _build_learners(self) -> tuple[list[SB3Learner], RunStreams]:
        """The runs' single-run learners (initial weights, and the shells the trained weights go
        back into) and their random streams: the global RNG states each construction left behind.
        The global RNG states are restored afterwards."""
        saved = th.get_rng_state(), np.random.get_state()
        learners: list[SB3Learner] = []
        streams = RunStreams()
        try:
            for run in self.runs:
                learner = make_learner(self.spec, run.bound, seed=run.seed, max_steps=self.max_steps,
                                       obs_type="compact" if run.pool else "flat")
                assert isinstance(learner, SB3Learner)
                learners.append(learner)
                streams.capture()
        finally:
            th.set_rng_state(saved[0])
            np.random.set_state(saved[1])
        return learners, streams

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

    @property
    def compiled(self) -> bool:
        """Whether the minibatch steps run compiled (:mod:`.compiled`)."""
        return self.update_engine == "compiled"

    @property
    def in_graph(self) -> bool:
        """Whether the compiled steps take their Adam step in the graph."""
        return adam_in_graph(self.device) if self.adam_in_graph is None else self.adam_in_graph

    def _compile(self, fn: Step) -> Step:
        """A step function of :mod:`.compiled` as this fleet runs it (compiled on its device)."""
        return compiled_step(fn, self.device, self.compile_backend)

    def _runs_tensor(self, values: np.ndarray | float, dtype: th.dtype = th.float32) -> th.Tensor:
        """``[K]`` per-run values (a learning rate, a mask) as a tensor on the device, for a compiled step."""
        return th.as_tensor(np.broadcast_to(np.asarray(values), (self.n_runs,)).copy(), dtype=dtype, device=self.device)

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
            self.rollout = self.collector.collect(self.nets, self.heads, self.streams, self._on_step)
            self._distinct = None
            self.progress_remaining = 1.0 - float(self.num_timesteps) / float(self.total_timesteps)
            self._train()
            self._fail_non_finite_runs()
            if on_progress is not None:
                on_progress(self.num_timesteps, self.total_timesteps)
            if checkpoint is not None and checkpoint.due():
                checkpoint.write(self)
        if checkpoint is not None:
            checkpoint.write(self)  # a kill while the runs are recorded does not retrain them
        self._finish()
        return self.num_timesteps

    def _start_training(self) -> None:
        """The state of the runs at step 0: every copy reset, no episode cost recorded yet."""
        self.num_timesteps, self.progress_remaining = 0, 1.0
        self.failed = {}
        self.collector.start()

    # ------------------------------------------------------------------ runs that go non-finite
    def _trained_tensors(self) -> list[th.Tensor]:
        """Every tensor an update changes, each ``[K, ...]``: the networks, and every optimiser's
        parameters (PPO-Lag's multipliers among them) and moments."""
        tensors = list(self.nets.params(*self.nets.heads))
        for opt in self._optimisers().values():
            tensors += [opt.flat, opt.exp_avg, opt.exp_avg_sq]
        return tensors

    @th.no_grad()
    def _fail_non_finite_runs(self) -> None:
        """Fail each run holding a non-finite value after an update (one device sync per update)."""
        tensors = self._trained_tensors()
        finite = th.stack([th.isfinite(t.reshape(self.n_runs, -1)).all(dim=1) for t in tensors]).all(dim=0)
        bad = [int(k) for k in th.nonzero(~finite).flatten().tolist()]
        for k in bad:
            if k not in self.failed:
                run = self.runs[k]
                self.failed[k] = (f"training went non-finite (a NaN or infinite weight, moment or multiplier) in the update "
                                  f"ending at step {self.num_timesteps:,} of run {k} ({run.where()}, "
                                  f"{run.bound.chain.name}, seed {run.seed}); the other runs of its fleet trained on")
            for t in tensors:
                t[k].zero_()

    def _evaluated(self, k: int) -> bool:
        return k not in self.failed

    def _on_step(self) -> None:
        """After every simulator step of a rollout: count the steps (each run's ``n_envs``) and
        make the learn-time evaluations that are due, as SB3's callbacks do."""
        self.num_timesteps += self.n_envs
        self._evaluate_if_due()

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

    # ------------------------------------------------------------------ learn-time evaluations
    def _start_evaluations(self, eval_every: int, eval_episodes: int, on_eval: FleetEvalHook | None) -> None:
        self._eval_every = int(eval_every)
        self._eval_episodes = int(eval_episodes)
        self._next_eval = 0
        self._callbacks = []
        if any(r.pool for r in self.runs):
            if self._eval_every > 0 or on_eval is not None:
                raise SpecError("learn-time evaluations of mixture runs are not made here: they would evaluate one env "
                                "id through the flat observation; score the runs on the track's sets (runners.track)")
            return
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
            if not self._evaluated(k):
                continue  # a failed run is not evaluated (its weights are zeroed, its number would mean nothing)
            self.nets.export_run(k, learner.model.policy)
            callback.evaluate_now(self.num_timesteps)
        if self._eval_every <= 0:
            self._next_eval = np.iinfo(np.int64).max
            return
        while self._next_eval <= self.num_timesteps:
            self._next_eval += self._eval_every

    # ------------------------------------------------------------------ what the updates read
    def distinct_states(self) -> list[DistinctStates]:
        """Each run's rollout as distinct observations (:mod:`.dedup`), computed once per rollout."""
        if self._distinct is None:
            assert self.rollout is not None
            self._distinct = [DistinctStates.of(self.rollout.obs[k], self.device) for k in range(self.n_runs)]
        return self._distinct

    @property
    def ep_cost_buffers(self) -> list[Any]:
        """Each run's recent episode costs (the single learner's ``ep_cost_buffer``)."""
        return self.collector.ep_cost_buffers

    def mean_episode_costs(self) -> np.ndarray:
        """``J_c`` of every run (``CostOnPolicyAlgorithm.mean_episode_cost`` per run), ``[K]`` float64."""
        return self.collector.mean_episode_costs()

    def permutation(self, k: int, size: int) -> np.ndarray:
        """Run ``k``'s next permutation of ``size`` transitions (its single run's ``np.random.permutation``)."""
        return self.streams.permutation(k, size)

    def permutations(self, size: int) -> th.Tensor:
        """``[K, size]``: every run's next permutation."""
        return self.streams.permutations(size, self.device)

    def _tensor(self, arr: np.ndarray) -> th.Tensor:
        """A numpy array as a tensor on the fleet's device (shared memory on the CPU)."""
        return th.from_numpy(arr).to(self.device)

    # ------------------------------------------------------------------ checkpoints
    def checkpoint_key(self) -> dict[str, Any]:
        """What a checkpoint of this fleet's training only fits: the learner (every hyper-parameter),
        the protocol, each run's env id, chain and seed, the budget, the evaluation schedule, the
        device and the simulator. :meth:`load_state_dict` refuses a state of another key. (Not a
        run's identity, :mod:`morality_gym.results.identity`: a fleet of the same runs on another
        device is the same runs, but not the same training state.)"""
        return {
            "algorithm": self.algorithm,
            "spec": repr(self.spec),
            "protocol": repr(self.protocol),
            "runs": [[r.bound.env_id, r.bound.chain.name, float(r.bound.beta), int(r.seed)]
                     + ([f"pool of {len(r.pool)}: {r.pool_digest()}"] if r.pool else []) for r in self.runs],
            "max_steps": self.max_steps,
            "n_envs": self.n_envs,
            "total_timesteps": self.total_timesteps,
            "eval_every": self._eval_every,
            "eval_episodes": self._eval_episodes,
            "device": str(self.device),
            "simulator": self.collector.env.name,
            # Only when compiled: the eager engine's checkpoints from before the setting existed still fit.
            **({"update": self.update_engine} if self.compiled else {}),
        }

    def state_dict(self) -> dict[str, Any]:
        """The whole training state between two updates (call it at an update boundary of
        :meth:`learn`), as tensors (on the CPU) and plain Python data, so that it can be written
        with ``torch.save`` and read back with ``torch.load(weights_only=True)``.

        Everything an update or a rollout reads and changes: the stacked networks, every
        optimiser's moments and step counts (and a subclass's :meth:`_extra_state`, PPO-Lag's
        multipliers), each run's random streams, the rollout collector (simulator, cost memory,
        last observations, episode-cost record), the step count and progress, the diagnostics rows,
        and the learn-time evaluations' schedule, seed counters and rows. What is rebuilt each
        rollout and what never changes (hyper-parameters, schedules) is not kept. Nothing of
        training uses the global RNGs (the runs' generators are their own, evaluations seed their
        own), so they are not kept either (a test changes them between interruption and resume).
        """
        return {
            "identity": self.checkpoint_key(),  # stored under its old name: earlier checkpoints still resume
            "num_timesteps": int(self.num_timesteps),
            "progress_remaining": float(self.progress_remaining),
            "next_eval": int(self._next_eval),
            "nets": self.nets.state_dict(),
            "optimisers": {name: opt.state_dict() for name, opt in self._optimisers().items()},
            "extra": self._extra_state(),
            **self.streams.state_dict(),  # torch_generators, np_generators
            **self.collector.state_dict(),  # env, last_obs, last_starts, running_ep_cost, ep_cost_buffers
            "update_logs": plain_data(self.update_logs),
            "evaluations": [cb.state_dict() for cb in self._callbacks],
            "learn_evals": [plain_data(learner.learn_evals) for learner in self._learners],
            "failed": [[k, why] for k, why in sorted(self.failed.items())],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Continue from :meth:`state_dict` of a fleet of the same :meth:`checkpoint_key` (raises
        :class:`CheckpointMismatch` otherwise, before changing anything). Called by :meth:`learn`
        after it set up step 0 and the evaluations. Tensors are copied *in place*: the networks'
        parameters are views into their optimisers' flat buffers. Should a part fail to load
        (a damaged file), the state from before the call is put back and the error raised."""
        mine, theirs = self.checkpoint_key(), state.get("identity")
        if theirs != mine:
            raise CheckpointMismatch(key_difference(mine, theirs))
        before = self.state_dict()
        try:
            self._load(state)
        except Exception:
            self._load(before)
            raise

    @th.no_grad()
    def _load(self, state: dict[str, Any]) -> None:
        self.nets.load_state_dict(state["nets"])
        self._load_optimisers(state["optimisers"])
        self._load_extra_state(state["extra"])
        self.streams.load_state_dict(state)
        self.collector.load_state_dict(state)
        self.num_timesteps = int(state["num_timesteps"])
        self.progress_remaining = float(state["progress_remaining"])
        self._next_eval = int(state["next_eval"])
        if len(state["update_logs"]) != self.n_runs:
            raise ValueError(f"diagnostics rows: expected {self.n_runs} runs, got {len(state['update_logs'])}")
        self.update_logs = [[dict(row) for row in rows] for rows in state["update_logs"]]
        self._load_evaluations(state["evaluations"], state["learn_evals"])
        failed = {int(k): str(why) for k, why in state["failed"]}
        if any(not 0 <= k < self.n_runs for k in failed):
            raise ValueError(f"failed runs {sorted(failed)} outside the fleet's {self.n_runs}")
        self.failed = failed

    def _load_optimisers(self, saved: dict[str, Any]) -> None:
        optimisers = self._optimisers()
        if set(saved) != set(optimisers):
            raise ValueError(f"optimisers: expected {sorted(optimisers)}, got {sorted(saved)}")
        for name, opt in optimisers.items():
            opt.load_state_dict(saved[name])

    def _load_evaluations(self, evaluations: list[Any], learn_evals: list[Any]) -> None:
        if len(evaluations) != len(self._callbacks) or len(learn_evals) != self.n_runs:
            raise ValueError("evaluation state does not fit the fleet's evaluations")
        for callback, cb_state in zip(self._callbacks, evaluations):
            callback.load_state_dict(cb_state)
        for learner, rows in zip(self._learners, learn_evals):
            learner.learn_evals = [dict(row) for row in rows]
