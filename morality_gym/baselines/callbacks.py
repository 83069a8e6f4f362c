"""SB3 callback for learn-time morality evaluations (every 50k steps, 10 episodes, as the paper).

The evaluations are logged but must never change the training run: they sample the policy with
their own numpy generator (see :class:`~morality_gym.evaluation.policies.PolicyAdapter`), never
touch torch's RNG, and run on a separate simulator. The exact metric of the current policy is
computed alongside (one batched forward pass over all states), which gives a noise-free curve.

The callback takes what it evaluates (a policy, an env id, a bound chain, a seed) and where the
rows go (``on_eval``), not the learner that owns them: learners build callbacks, never the
other way round.
"""

from __future__ import annotations

import time
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from morality_gym.baselines.learn_evals import EvalHook, learn_eval_row
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.montecarlo import evaluate
from morality_gym.norms.metric import BoundChain


class MoralityEvalCallback(BaseCallback):
    """Evaluate ``policy`` at step 0 and every ``eval_every`` environment steps; hand rows to ``on_eval``.

    ``policy`` is anything :class:`~morality_gym.evaluation.policies.PolicyAdapter` accepts (for an
    SB3 model, the model being trained: it is read at each evaluation, so the rows follow
    training). The ``k``-th evaluation's episodes are seeded ``seed * 1_000_003 + k``.
    """

    def __init__(
        self,
        policy: Any,
        env_id: str,
        bound: BoundChain,
        *,
        seed: int,
        max_steps: int | None,
        eval_every: int,
        eval_episodes: int,
        on_eval: EvalHook | None = None,
    ) -> None:
        super().__init__(verbose=0)
        self.policy = policy
        self.env_id = env_id
        self.bound = bound
        self.seed = int(seed)
        self.max_steps = max_steps
        self.eval_every = int(eval_every)
        self.eval_episodes = int(eval_episodes)
        self.on_eval = on_eval
        self._next = 0
        self._count = 0
        self._started = time.perf_counter()

    def evaluate_now(self, step: int) -> dict[str, Any]:
        mc = evaluate(
            self.policy,
            self.env_id,
            self.bound,
            n_episodes=self.eval_episodes,
            seed=self.seed * 1_000_003 + self._count,
            max_steps=self.max_steps,
            keep_episodes=False,
        )
        exact = exact_evaluate(self.policy, self.env_id, self.bound, max_steps=self.max_steps)
        row = learn_eval_row(step, mc, exact, self._started)
        self._count += 1
        if "model" in vars(self):  # attached to a model that is learning (not a step-0-only evaluation)
            self.logger.record("morality/metric", row["metric"])
            self.logger.record("morality/exact_metric", row["exact_metric"])
        if self.on_eval:
            self.on_eval(row)
        return row

    def state_dict(self) -> dict[str, Any]:
        """What carries from one evaluation to the next: the evaluation count (it seeds the next
        evaluation's episodes), the next step due and the wall time since the start (the rows'
        ``wall_time_s``). For a fleet's training checkpoint (:mod:`morality_gym.baselines.fleet.checkpoint`)."""
        return {"count": self._count, "next": self._next, "elapsed_s": time.perf_counter() - self._started}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Continue from :meth:`state_dict`: the next evaluation is seeded as it would have been,
        and its ``wall_time_s`` counts the time before the checkpoint too."""
        self._count = int(state["count"])
        self._next = int(state["next"])
        self._started = time.perf_counter() - float(state["elapsed_s"])

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
