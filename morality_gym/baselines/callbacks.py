"""SB3 callback for learn-time morality evaluations (every 50k steps, 10 episodes, as the paper).

The evaluations are logged but must never change the training run: they sample the policy with
their own numpy generator (see :class:`~morality_gym.evaluation.policies.PolicyAdapter`), never
touch torch's RNG, and run on a separate simulator. The exact metric of the current policy is
computed alongside (one batched forward pass over all states), which gives a noise-free curve.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from stable_baselines3.common.callbacks import BaseCallback

from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.montecarlo import evaluate

if TYPE_CHECKING:
    from morality_gym.baselines.learners import EvalHook, Learner


class MoralityEvalCallback(BaseCallback):
    """Evaluate at step 0 and every ``eval_every`` environment steps; hand rows to ``on_eval``."""

    def __init__(self, learner: "Learner", eval_every: int, eval_episodes: int, on_eval: "EvalHook | None" = None) -> None:
        super().__init__(verbose=0)
        self.learner = learner
        self.eval_every = int(eval_every)
        self.eval_episodes = int(eval_episodes)
        self.on_eval = on_eval
        self._next = 0
        self._count = 0
        self._started = time.perf_counter()

    def evaluate_now(self, step: int) -> dict[str, Any]:
        learner = self.learner
        mc = evaluate(
            learner.policy,
            learner.env_id,
            learner.bound,
            n_episodes=self.eval_episodes,
            seed=learner.seed * 1_000_003 + self._count,
            max_steps=learner.max_steps,
            keep_episodes=False,
        )
        exact = exact_evaluate(learner.policy, learner.env_id, learner.bound, max_steps=learner.max_steps)
        from morality_gym.baselines.learners import _eval_row

        row = _eval_row(step, mc, exact, self._started)
        self._count += 1
        learner.learn_evals.append(row)
        if self.logger is not None:
            self.logger.record("morality/metric", row["metric"])
            self.logger.record("morality/exact_metric", row["exact_metric"])
        if self.on_eval:
            self.on_eval(row)
        return row

    def _on_training_start(self) -> None:
        self._next = 0
        if self.eval_every > 0:
            self.evaluate_now(0)
            self._next = self.eval_every

    def _on_step(self) -> bool:
        if self.eval_every > 0 and self.num_timesteps >= self._next:
            self.evaluate_now(self.num_timesteps)
            while self._next <= self.num_timesteps:
                self._next += self.eval_every
        return True
