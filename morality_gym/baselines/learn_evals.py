"""What a learn-time evaluation reports: one row per evaluation, handed to an :data:`EvalHook`.

One definition for every learner that evaluates while it learns (the SB3 callback of
:mod:`morality_gym.baselines.callbacks`, the random learner's replayed evaluations, the fleet
trainer), kept free of Stable-Baselines3 and torch so that the random learner does not load them.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from morality_gym.evaluation.result import EvaluationResult

#: Called with each learn-time evaluation: {"step", "metric", "exact_metric", "functions", ...}.
EvalHook = Callable[[dict[str, Any]], None]


def learn_eval_row(step: int, mc: EvaluationResult, exact: EvaluationResult | None, started: float) -> dict[str, Any]:
    """The row of one learn-time evaluation at ``step``: the Monte Carlo result ``mc``, the exact
    metric if computed (else NaN) and the wall time since ``started`` (a ``time.perf_counter()``)."""
    return {
        "step": int(step),
        "metric": mc.metric,
        "exact_metric": exact.metric if exact is not None else float("nan"),
        "mean_return": mc.mean_return,
        "mean_cost": mc.mean_cost if mc.mean_cost is not None else float("nan"),
        "mean_length": mc.mean_length,
        "functions": dict(mc.functions),
        "wall_time_s": time.perf_counter() - started,
    }
