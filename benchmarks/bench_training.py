"""Training throughput of each learner on PushOrSwitch-Human-v1 with 8 envs: batched VecEnv vs SB3's DummyVecEnv."""

from __future__ import annotations

from typing import Any

import torch

import morality_gym
from benchmarks import Context, Section, best_time, register
from morality_gym.baselines.learners import build_learner
from morality_gym.baselines.specs import learner_spec

ENV_ID = "PushOrSwitch-Human-v1"


@register("training", "Training steps per second per learner (8 envs, one thread)", order=70)
def training_speed(ctx: Context) -> Section:
    torch.set_num_threads(1)
    bound = morality_gym.bind_chain("DualProcess", ENV_ID)
    # (learner, protocol): the corrected protocol changes PPO-Lag's and CPO's update arithmetic (the
    # early-stop KL, the dual solution), so their cost per update differs; the others ignore it.
    runs = (("ppo", "paper"), ("ppo_shaped", "paper"), ("ppo_lag", "paper"), ("cpo", "paper"),
            ("ppo_lag", "corrected"), ("cpo", "corrected"))
    task = ctx.task("training", len(runs) * 2)
    rows = []
    for name, protocol in runs:
        rates = {}
        for vec_env in ("batched", "dummy"):
            spec = learner_spec(name, {"vec_env": vec_env})
            rollout = spec.hparams["n_steps"] * spec.n_envs
            budget = rollout * ctx.size(2, 1)
            learner: dict[str, Any] = {}

            # the loop's values bound as defaults: best_time calls both before the loop moves on,
            # but a closure over loop variables reads as if it might not
            def setup(learner: dict[str, Any] = learner, spec: Any = spec, protocol: str = protocol) -> None:
                learner["l"] = build_learner(spec, bound, protocol, seed=0)

            def train(learner: dict[str, Any] = learner, budget: int = budget) -> None:
                learner["l"].learn(budget, eval_every=0)

            timing = best_time(train, ctx.repeats if not ctx.quick else 1, setup=setup)
            rates[vec_env] = budget / timing.wall
            task.advance()
        label = spec.label if protocol == "paper" else f"{spec.label} ({protocol} protocol)"
        rows.append([label, f"{rollout:,}", f"{rates['batched']:,.0f}", f"{rates['dummy']:,.0f}", f"{rates['batched'] / rates['dummy']:.2f}x"])
    task.done()
    return Section(
        intro=f"""
`learn()` on `{ENV_ID}` (DualProcess chain) with the paper's hyper-parameters, 8 envs, torch on one thread, wall-clock
steps per second over {ctx.size(2, 1)} rollout(s) including the gradient updates (best of the repeats). "batched" is this
project's `TrolleyVecEnv`; "dummy" is SB3's `DummyVecEnv` over 8 `TrolleyEnv`s. Both go through `VecMonitor` and the cost
wrapper. Rows without a protocol use the paper protocol. Training is bound by gradient steps, so the simulator's own
speed shows mostly in rollout collection. Under the paper protocol PPO-Lag's early stop tests the KL summed over the
rollout's states and so stops after the first of its 40 passes on almost every update; the corrected protocol tests the
mean KL and runs more passes (docs/protocols.md).
""",
        headers=["learner", "steps per rollout", "batched VecEnv steps/s", "DummyVecEnv steps/s", "ratio"],
        rows=rows,
        compare=["batched VecEnv steps/s"],
    )
