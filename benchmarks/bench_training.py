"""Training throughput of each learner on PushOrSwitch-Human-v1 with 8 envs: batched VecEnv vs SB3's DummyVecEnv."""

from __future__ import annotations

from benchmarks import Context, Section, best_time, register

ENV_ID = "PushOrSwitch-Human-v1"


@register("training", "Training steps per second per learner (8 envs, one thread)", order=70)
def training_speed(ctx: Context) -> Section:
    import torch

    import morality_gym
    from morality_gym.baselines.learners import build_learner
    from morality_gym.baselines.specs import learner_spec

    torch.set_num_threads(1)
    bound = morality_gym.bind_chain("DualProcess", ENV_ID)
    learners = ("ppo", "ppo_shaped", "ppo_lag", "cpo")
    task = ctx.task("training", len(learners) * 2)
    rows = []
    for name in learners:
        rates = {}
        for vec_env in ("batched", "dummy"):
            spec = learner_spec(name, {"vec_env": vec_env})
            rollout = spec.hparams["n_steps"] * spec.n_envs
            budget = rollout * ctx.size(2, 1)
            learner = {}

            def setup() -> None:
                learner["l"] = build_learner(spec, bound, "paper", seed=0)

            timing = best_time(lambda: learner["l"].learn(budget, eval_every=0), ctx.repeats if not ctx.quick else 1, setup=setup)
            rates[vec_env] = budget / timing.wall
            task.advance()
        rows.append([spec.label, f"{rollout:,}", f"{rates['batched']:,.0f}", f"{rates['dummy']:,.0f}", f"{rates['batched'] / rates['dummy']:.2f}x"])
    task.done()
    return Section(
        intro=f"""
`learn()` on `{ENV_ID}` (DualProcess chain) with the paper's hyper-parameters, 8 envs, torch on one thread, wall-clock
steps per second over {ctx.size(2, 1)} rollout(s) including the gradient updates (best of the repeats). "batched" is this
project's `TrolleyVecEnv`; "dummy" is SB3's `DummyVecEnv` over 8 `TrolleyEnv`s. Both go through `VecMonitor` and the cost
wrapper. Training is bound by gradient steps (PPO-Lag runs 40 epochs per 2,048-step rollout), so the simulator's own
speed shows mostly in rollout collection.
""",
        headers=["learner", "steps per rollout", "batched VecEnv steps/s", "DummyVecEnv steps/s", "ratio"],
        rows=rows,
    )
