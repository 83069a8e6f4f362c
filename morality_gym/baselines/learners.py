"""One interface for the runners: build a learner from its spec, learn, evaluate, save and load.

``Learner.learn`` trains (logging learn-time evaluations through a callback that uses its own
numpy random generator, so evaluating never changes the training run's random stream),
``final_evaluation`` is the paper's stochastic 100-episode evaluation, ``exact_evaluation`` the
exact expectation of the same policy, and the trained policy (``learner.policy``) plugs into
:func:`morality_gym.evaluate` and :func:`morality_gym.exact_evaluate`.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from morality_gym.baselines.learn_evals import EvalHook, learn_eval_row
from morality_gym.baselines.specs import (
    LearnerSpec,
    ProtocolSpec,
    RandomReplay,
    SpecError,
    protocol_spec,
)
from morality_gym.baselines.targets import resolve
from morality_gym.clitools import write_atomically
from morality_gym.constants import EVAL_EPISODES, LEARN_EVAL_EPISODES, LEARN_EVAL_EVERY, MAX_STEPS, SEED
from morality_gym.envs.registry import parse_env_id
from morality_gym.envs.trolley import TrolleyEnv
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.gif import record_episode
from morality_gym.evaluation.montecarlo import evaluate, evaluate_sequential
from morality_gym.evaluation.policies import PolicyAdapter, sample_actions
from morality_gym.evaluation.result import EvaluationResult
from morality_gym.norms.metric import BoundChain

#: The learner that drives an SB3 algorithm, named like any learner (:mod:`morality_gym.baselines.targets`):
#: it imports SB3 and torch, which the random learner and the sweep's planning never need, and an
#: SB3 target has loaded them by the time it is resolved.
SB3_DRIVER = "morality_gym.baselines.sb3_learner.SB3Learner"


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
    settings) or an SB3 algorithm (driven by :class:`~morality_gym.baselines.sb3_learner.SB3Learner`)."""
    cls = resolve(spec.target, where=f"learner {spec.name!r}: _target_")
    if issubclass(cls, RandomLearner):
        return cls(spec, bound, seed=seed, max_steps=max_steps, replay=replay)
    if issubclass(cls, Learner) and obs_type == "flat":  # a self-driving learner: SB3 is not loaded for it
        return cls(spec, bound, seed=seed, max_steps=max_steps)
    driver = resolve(SB3_DRIVER)
    learner_cls = cls if issubclass(cls, Learner) else driver
    if not issubclass(learner_cls, driver):  # only SB3 learners build their policy on another observation
        raise SpecError(f"learner {spec.name!r}: obs_type={obs_type!r} needs an SB3 algorithm")
    if obs_type != "flat":
        return learner_cls(spec, bound, seed=seed, max_steps=max_steps, obs_type=obs_type)
    return learner_cls(spec, bound, seed=seed, max_steps=max_steps)
