"""The learner that drives any SB3 algorithm: builds its model and its training VecEnv, learns, saves.

Split from :mod:`morality_gym.baselines.learners` (the interface, the random baseline and
:func:`~morality_gym.baselines.learners.make_learner`) because everything here needs SB3 and torch,
imported at the top; ``make_learner`` names this class (``SB3_DRIVER``) and resolves it only for an
SB3 algorithm, whose own import has loaded them already.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import torch
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

from morality_gym.baselines.callbacks import MoralityEvalCallback
from morality_gym.baselines.hparams import algorithm_class, validate_learner
from morality_gym.baselines.learn_evals import EvalHook
from morality_gym.baselines.learners import Learner
from morality_gym.baselines.specs import LearnerSpec, training_steps
from morality_gym.baselines.targets import import_root
from morality_gym.clitools import write_atomically
from morality_gym.constants import LEARN_EVAL_EPISODES, LEARN_EVAL_EVERY
from morality_gym.envs.trolley import TrolleyEnv
from morality_gym.envs.vector import TrolleyVecEnv
from morality_gym.norms.wrappers import VecMoralityWrapper


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

    def eval_callback(self, eval_every: int, eval_episodes: int, on_eval: EvalHook | None = None) -> MoralityEvalCallback:
        """The SB3 callback that evaluates this learner's policy while it learns; its rows go to
        :attr:`learn_evals`, then to ``on_eval``."""
        def record(row: dict[str, Any]) -> None:
            self.learn_evals.append(row)
            if on_eval:
                on_eval(row)

        return MoralityEvalCallback(self.policy, self.env_id, self.bound, seed=self.seed, max_steps=self.max_steps,
                                    eval_every=eval_every, eval_episodes=eval_episodes, on_eval=record)

    def make_vec_env(self) -> Any:
        """The training VecEnv: batched simulator (or SB3 DummyVecEnv) -> VecMonitor -> cost/reward wrapper."""
        if self.spec.vec_env == "batched" or self.obs_type != "flat":
            venv: Any = TrolleyVecEnv(self.env_id, self.spec.n_envs, max_steps=self.max_steps, obs_type=self.obs_type)
        else:
            env_id, max_steps = self.env_id, self.max_steps
            venv = DummyVecEnv([lambda: TrolleyEnv(env_id, max_steps=max_steps) for _ in range(self.spec.n_envs)])
        venv = VecMonitor(venv)
        return VecMoralityWrapper(venv, self.bound, self.spec.reward_cost())

    def _build(self) -> Any:
        validate_learner(self.spec)  # sweeps check this before planning; library users get the same messages
        cls = self._algorithm_class()
        activation = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}[self.spec.activation]
        arch = list(self.spec.net_arch)
        policy_kwargs: dict[str, Any] = {"activation_fn": activation}
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
    return Logger(folder=None, output_formats=[])


def _net_arch_keys(cls: type) -> set[str]:
    keys = getattr(cls, "net_arch_keys", None)
    return set(keys) if keys else {"pi", "vf"}


def _spec_dict(spec: LearnerSpec) -> dict[str, Any]:
    out = dataclasses.asdict(spec)
    out["hparams"] = dict(spec.hparams)
    return out
