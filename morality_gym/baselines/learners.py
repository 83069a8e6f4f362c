"""One interface for the runners: build a learner from its spec, learn, evaluate, save and load.

``Learner.learn`` trains (logging learn-time evaluations through a callback that uses its own
numpy random generator, so evaluating never changes the training run's random stream),
``final_evaluation`` is the paper's stochastic 100-episode evaluation, ``exact_evaluation`` the
exact expectation of the same policy, and the trained policy (``learner.policy``) plugs into
:func:`morality_gym.evaluate` and :func:`morality_gym.exact_evaluate`.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from morality_gym.baselines.hparams import algorithm_class, validate_learner
from morality_gym.baselines.learn_evals import EvalHook, learn_eval_row
from morality_gym.baselines.specs import (
    LearnerSpec,
    ProtocolSpec,
    RandomReplay,
    SpecError,
    protocol_spec,
    training_steps,
)
from morality_gym.baselines.targets import import_root, resolve
from morality_gym.clitools import write_atomically
from morality_gym.constants import EVAL_EPISODES, LEARN_EVAL_EPISODES, LEARN_EVAL_EVERY, MAX_STEPS, SEED
from morality_gym.envs.registry import parse_env_id
from morality_gym.envs.trolley import TrolleyEnv
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.montecarlo import evaluate, evaluate_sequential
from morality_gym.evaluation.policies import PolicyAdapter, sample_actions
from morality_gym.evaluation.result import EvaluationResult
from morality_gym.norms.metric import BoundChain

if TYPE_CHECKING:  # imported when used: it loads SB3 and torch, which the random learner never needs
    from morality_gym.baselines.callbacks import MoralityEvalCallback


#: Random's settings when no protocol asks for a replay: its final evaluation starts its own stream.
FRESH_STREAM = RandomReplay()


class Learner:
    """Base class: the protocol-independent parts (evaluation, GIFs, save/load bookkeeping).

    A learner that is not an SB3 algorithm subclasses this and is named by its own import path as
    ``_target_`` (as the random baseline is); ``trains = False`` tells planners it needs no budget,
    and :meth:`load_policy` turns its saved files back into a policy.

    ``spec`` is the resolved spec (a protocol's overrides already applied: by the sweep, or by
    :func:`build_learner`); a learner never sees the protocol itself.
    """

    trains: bool = True

    def __init__(
        self,
        spec: LearnerSpec,
        bound: BoundChain,
        seed: int = SEED,
        max_steps: int | None = MAX_STEPS,
    ) -> None:
        self.spec = spec
        self.bound = bound
        self.env_id = bound.env_id
        parse_env_id(self.env_id)
        self.seed = int(seed)
        self.max_steps = max_steps
        self.trained_steps = 0
        self.learn_evals: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ to override
    @property
    def policy(self) -> Any:
        """Something :class:`~morality_gym.evaluation.policies.PolicyAdapter` accepts."""
        raise NotImplementedError

    def learn(
        self, budget: int, eval_every: int = LEARN_EVAL_EVERY, eval_episodes: int = LEARN_EVAL_EPISODES, on_eval: EvalHook | None = None
    ) -> int:
        raise NotImplementedError

    def save(self, path: str | Path) -> Path:
        raise NotImplementedError

    def eval_callback(self, eval_every: int, eval_episodes: int, on_eval: EvalHook | None = None) -> MoralityEvalCallback:
        """The SB3 callback that evaluates this learner's policy while it learns; its rows go to
        :attr:`learn_evals`, then to ``on_eval``."""
        # torch waits: importing morality_gym.baselines.learners must not load it
        from morality_gym.baselines.callbacks import MoralityEvalCallback

        def record(row: dict[str, Any]) -> None:
            self.learn_evals.append(row)
            if on_eval:
                on_eval(row)

        return MoralityEvalCallback(self.policy, self.env_id, self.bound, seed=self.seed, max_steps=self.max_steps,
                                    eval_every=eval_every, eval_episodes=eval_episodes, on_eval=record)

    @classmethod
    def load_policy(cls, path: Path, metadata: dict[str, Any]) -> Any:
        """The policy saved at ``path`` by :meth:`save` (for :func:`~morality_gym.baselines.io.load_model`)."""
        raise NotImplementedError

    def update_diagnostics(self) -> list[dict[str, Any]]:
        """One row per policy update of the last ``learn`` (``[]`` for learners that do not log
        them; PPO-Lag and CPO do, see :class:`~morality_gym.baselines.safe.base.CostOnPolicyAlgorithm`)."""
        return []

    # ------------------------------------------------------------------ shared
    def final_evaluation(self, n_episodes: int = EVAL_EPISODES) -> EvaluationResult:
        """The paper's final evaluation: the stochastic policy, ``n_episodes`` episodes, seeded by the run."""
        return evaluate(self.policy, self.env_id, self.bound, n_episodes=n_episodes, seed=self.seed, max_steps=self.max_steps, keep_episodes=False)

    def exact_evaluation(self) -> EvaluationResult:
        return exact_evaluate(self.policy, self.env_id, self.bound, max_steps=self.max_steps)

    def record_gif(self, path: str | Path, max_steps: int = 50) -> dict[str, Any]:
        """One evaluation episode of the stochastic policy as a GIF (like the reference's render episode)."""
        # PIL waits: importing morality_gym.baselines.learners must not load it
        from morality_gym.evaluation.gif import record_episode

        adapter = PolicyAdapter(self.policy)
        rng = np.random.default_rng(self.seed + 7919)

        def act(obs: np.ndarray) -> int:
            if adapter.is_random:
                return int(rng.integers(6))
            return int(sample_actions(adapter.probabilities(np.asarray(obs, dtype=np.float64)[None]), rng)[0])

        return record_episode(self.env_id, act, path, max_steps=max_steps, env_kwargs={"max_steps": self.max_steps})

    def metadata(self) -> dict[str, Any]:
        return {
            "algo": self.spec.name,
            "label": self.spec.label,
            "target": self.spec.target,
            "env_id": self.env_id,
            "chain": self.bound.chain.name,
            "beta": self.bound.beta,
            "protocol": self.spec.protocol,
            "seed": self.seed,
            "trained_steps": self.trained_steps,
        }


class RandomLearner(Learner):
    """Uniformly random actions; nothing to learn.

    With ``replay.learn_evals`` (the ``paper`` protocol's setting) its evaluations replay the
    reference's random stream: one generator seeded with the run seed feeds, in order, the
    learn-time evaluations at steps 0 and 50,000 (10 episodes each, each followed by a render
    episode of up to 50 steps) and then the final 100-episode evaluation. This reproduces the
    paper's Random column to the last digit.
    """

    trains = False

    def __init__(self, spec: LearnerSpec, bound: BoundChain, seed: int = SEED, max_steps: int | None = MAX_STEPS,
                 replay: RandomReplay = FRESH_STREAM) -> None:
        super().__init__(spec, bound, seed=seed, max_steps=max_steps)
        self.replay = replay
        self._final: EvaluationResult | None = None
        self._rng = np.random.default_rng(self.seed)

    @property
    def policy(self) -> Any:
        return "random"

    def _act(self, obs: Any) -> int:
        return int(self._rng.integers(6))

    def _render_episode(self, env: TrolleyEnv) -> None:
        env.reset()
        for _ in range(self.replay.render_episode_steps):
            _, _, terminated, truncated, _ = env.step(self._act(None))
            if terminated or truncated:
                break

    def learn(
        self, budget: int, eval_every: int = LEARN_EVAL_EVERY, eval_episodes: int = LEARN_EVAL_EPISODES, on_eval: EvalHook | None = None
    ) -> int:
        started = time.perf_counter()
        self._rng = np.random.default_rng(self.seed)
        self._env = TrolleyEnv(self.env_id, max_steps=self.max_steps)
        if self.replay.learn_evals:
            for step in self.replay.steps:
                mc = evaluate_sequential(self._act, self._env, self.bound, eval_episodes, keep_episodes=False)
                self._render_episode(self._env)
                row = learn_eval_row(step, mc, None, started)
                self.learn_evals.append(row)
                if on_eval:
                    on_eval(row)
        self.trained_steps = 0
        return 0

    def final_evaluation(self, n_episodes: int = EVAL_EPISODES) -> EvaluationResult:
        if not hasattr(self, "_env"):
            self.learn(0)
        return evaluate_sequential(self._act, self._env, self.bound, n_episodes, keep_episodes=False)

    @classmethod
    def load_policy(cls, path: Path, metadata: dict[str, Any]) -> Any:
        return "random"

    def save(self, path: str | Path) -> Path:
        path = Path(path).with_suffix(".json")
        text = json.dumps({**self.metadata(), "policy": "uniform random"}, indent=1)
        return write_atomically(path, lambda fh: fh.write(text.encode()))


class SB3Learner(Learner):
    """Any SB3 algorithm named by the spec's ``target``: PPO and PPO-Shaped on SB3's PPO,
    PPO-Lagrangian and CPO on this package's subclasses, and any user's (A2C, TRPO, ...)."""

    def __init__(self, *args: Any, model: Any = None, obs_type: str = "flat", **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        #: ``flat`` (the env id's own vector) or ``compact`` (one width for every env id: a policy
        #: for the generalisation track's mixture, trained by a fleet; :mod:`morality_gym.envs.drawn`).
        self.obs_type = obs_type
        self.model = model if model is not None else self._build()

    def _algorithm_class(self) -> type:
        return algorithm_class(self.spec.target)

    def make_vec_env(self) -> Any:
        """The training VecEnv: batched simulator (or SB3 DummyVecEnv) -> VecMonitor -> cost/reward wrapper."""
        # torch waits: importing morality_gym.baselines.learners must not load it
        from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

        from morality_gym.envs.vector import TrolleyVecEnv
        from morality_gym.norms.wrappers import VecMoralityWrapper

        if self.spec.vec_env == "batched" or self.obs_type != "flat":
            venv: Any = TrolleyVecEnv(self.env_id, self.spec.n_envs, max_steps=self.max_steps, obs_type=self.obs_type)
        else:
            env_id, max_steps = self.env_id, self.max_steps
            venv = DummyVecEnv([lambda: TrolleyEnv(env_id, max_steps=max_steps) for _ in range(self.spec.n_envs)])
        venv = VecMonitor(venv)
        return VecMoralityWrapper(venv, self.bound, self.spec.reward_cost())

    def _build(self) -> Any:
        import torch  # torch waits: importing morality_gym.baselines.learners must not load it

        validate_learner(self.spec)  # sweeps check this before planning; library users get the same messages
        cls = self._algorithm_class()
        activation = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}[self.spec.activation]
        arch = list(self.spec.net_arch)
        policy_kwargs: dict[str, Any] = {"activation_fn": activation}
        # torch waits: importing morality_gym.baselines.learners must not load it
        from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

        if issubclass(cls, OnPolicyAlgorithm):  # actor-critic: one network each (and a cost critic for ours)
            keys = _net_arch_keys(cls)
            policy_kwargs["net_arch"] = {key: arch for key in ("pi", "vf", "cf") if key in keys}
        else:  # off-policy algorithms (DQN, ...) take one list
            policy_kwargs["net_arch"] = arch
        model = cls(
            "MlpPolicy",
            self.make_vec_env(),
            seed=self.seed,
            device="cpu",
            verbose=0,
            policy_kwargs=policy_kwargs,
            **dict(self.spec.hparams),
        )
        model.set_logger(silent_logger())
        return model

    @property
    def policy(self) -> Any:
        return self.model

    def update_diagnostics(self) -> list[dict[str, Any]]:
        return [dict(row) for row in getattr(self.model, "update_log", [])]

    def learn(
        self, budget: int, eval_every: int = LEARN_EVAL_EVERY, eval_episodes: int = LEARN_EVAL_EPISODES, on_eval: EvalHook | None = None
    ) -> int:
        total = training_steps(self.spec, budget)
        callback = self.eval_callback(eval_every, eval_episodes, on_eval)
        if total > 0:
            self.model.learn(total_timesteps=total, callback=callback, reset_num_timesteps=True)
        else:
            callback.evaluate_now(0)
        self.trained_steps = int(self.model.num_timesteps)
        return self.trained_steps

    def save(self, path: str | Path) -> Path:
        # Each file under a temporary name, renamed into place (a kill or a full disk never leaves
        # a truncated model.zip); the sidecar last, so a model.json always has its model.zip.
        path = Path(path).with_suffix(".zip")
        write_atomically(path, self.model.save)
        meta = {**self.metadata(), "spec": _spec_dict(self.spec), **({"obs_type": self.obs_type} if self.obs_type != "flat" else {})}
        root = import_root(type(self.model))
        if root is not None:  # a user's class from a plain file: where to import it from again
            meta["import_root"] = root
        text = json.dumps(meta, indent=1)
        write_atomically(path.with_suffix(".json"), lambda fh: fh.write(text.encode()))
        return path


def silent_logger() -> Any:
    """An SB3 logger that writes nothing anywhere.

    Why: SB3's ``learn()`` configures its own logger unless one is set, and even at ``verbose=0``
    that creates a directory ``$TMPDIR/SB3-<date>`` and leaves it behind: one per run, thousands
    per sweep. Our learners record what they report themselves (``update_log``, the run files)."""
    # SB3 waits: importing morality_gym.baselines.learners must not load torch
    from stable_baselines3.common.logger import Logger

    return Logger(folder=None, output_formats=[])


def _net_arch_keys(cls: type) -> set[str]:
    keys = getattr(cls, "net_arch_keys", None)
    return set(keys) if keys else {"pi", "vf"}


def _spec_dict(spec: LearnerSpec) -> dict[str, Any]:
    out = dataclasses.asdict(spec)
    out["hparams"] = dict(spec.hparams)
    return out


def build_learner(
    spec: LearnerSpec,
    bound: BoundChain,
    protocol: ProtocolSpec | str = "paper",
    seed: int = SEED,
    max_steps: int | None = MAX_STEPS,
) -> Learner:
    """The learner of ``spec`` under ``protocol`` for one env id and chain (see
    :mod:`morality_gym.baselines.specs`): the library's entry, which resolves ``spec`` for the
    protocol (:meth:`~morality_gym.baselines.specs.ProtocolSpec.apply`), then :func:`make_learner`.
    """
    protocol = protocol_spec(protocol)
    return make_learner(protocol.apply(spec), bound, seed=seed, max_steps=max_steps, replay=protocol.random_replay())


def make_learner(
    spec: LearnerSpec,
    bound: BoundChain,
    seed: int = SEED,
    max_steps: int | None = MAX_STEPS,
    replay: RandomReplay = FRESH_STREAM,
    obs_type: str = "flat",
) -> Learner:
    """The learner of a resolved ``spec`` (a sweep's run carries one): ``spec.target`` is either a
    :class:`Learner` subclass (built directly; the random baseline also gets its ``replay``
    settings) or an SB3 algorithm (driven by :class:`SB3Learner`)."""
    cls = resolve(spec.target, where=f"learner {spec.name!r}: _target_")
    if issubclass(cls, RandomLearner):
        return cls(spec, bound, seed=seed, max_steps=max_steps, replay=replay)
    learner_cls = cls if issubclass(cls, Learner) else SB3Learner
    if obs_type != "flat":  # only SB3 learners build their policy on another observation
        if not issubclass(learner_cls, SB3Learner):
            raise SpecError(f"learner {spec.name!r}: obs_type={obs_type!r} needs an SB3 algorithm")
        return learner_cls(spec, bound, seed=seed, max_steps=max_steps, obs_type=obs_type)
    return learner_cls(spec, bound, seed=seed, max_steps=max_steps)
