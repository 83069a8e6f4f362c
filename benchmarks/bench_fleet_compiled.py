"""The fleet's update engines side by side: eager vs compiled (``update=compiled``), CPU core time per learner."""

from __future__ import annotations

import os
import tempfile
from typing import Any

import numpy as np

import morality_gym
from benchmarks import Context, Section, best_time, register
from morality_gym.baselines.specs import learner_spec

SCENARIO = "PushOrSwitch"
#: The compiled step function each learner's updates run (learners sharing one share its graph).
STEP = {"ppo": "ppo_step", "ppo_shaped": "ppo_step", "ppo_lag": "lag_step", "cpo": "critic_step"}
#: (learner, protocol, rollouts per measurement), as the fleet benchmark's.
RUNS = (
    ("ppo", "paper", 1),
    ("ppo_shaped", "paper", 1),
    ("ppo_lag", "paper", 4),
    ("ppo_lag", "corrected", 1),
    ("cpo", "paper", 4),
    ("cpo", "corrected", 4),
)
TARGET = 2.0


def _distinct_share(obs: np.ndarray, batch: int, rng: np.random.Generator) -> float:
    """The mean share of distinct observations in a run's minibatches of ``batch`` (random order):
    the most a minibatch's forward pass on its distinct states only could save of its rows."""
    rows = obs.view(np.dtype((np.void, obs.dtype.itemsize * obs.shape[1])))[:, 0]
    order = rng.permutation(len(rows))
    blocks = [rows[order[i : i + batch]] for i in range(0, len(rows) - batch + 1, batch)]
    return float(np.mean([len(np.unique(b)) / batch for b in blocks]))


@register("fleet_compiled", "Fleet update engines: eager vs compiled, CPU core time per learner", order=77)
def fleet_compiled(ctx: Context) -> Section:
    # torch waits: only the benchmarks that train load it
    import torch
    import torch._dynamo

    from morality_gym.baselines.fleet import FleetRun, build_fleet, compiled

    torch.set_num_threads(1)
    cache = tempfile.mkdtemp(prefix="inductor-bench-")
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = cache  # an empty cache: the first compile is a cold one
    k = 2 if ctx.quick else 12
    ids = morality_gym.env_ids(SCENARIO)
    runs = [FleetRun(morality_gym.bind_chain("DualProcess", ids[i % len(ids)]), i) for i in range(k)]
    task = ctx.task("fleet_compiled", len(RUNS) * 4)
    rows, ratios, shares = [], [], []
    seen: set[str] = set()
    for name, protocol, rollouts in RUNS:
        spec = learner_spec(name)
        budget = spec.hparams["n_steps"] * spec.n_envs * rollouts
        held: dict[str, Any] = {}

        def build(update: str, held: dict[str, Any] = held, spec: Any = spec, protocol: str = protocol) -> None:
            held["f"] = build_fleet(spec, runs, protocol, update=update)
            held["update_s"] = 0.0
            train = held["f"]._train

            def timed(train: Any = train) -> None:
                t0 = best_time(train, 1)
                held["update_s"] += t0.cpu

            held["f"]._train = timed

        def learn(held: dict[str, Any] = held, budget: int = budget) -> None:
            held["f"].learn(budget)

        first = best_time(learn, 1, setup=lambda: build("compiled")).cpu  # cold: compiles into the empty cache
        task.advance()
        torch._dynamo.reset()
        compiled._compiled.cache_clear()
        cached = best_time(learn, 1, setup=lambda: build("compiled")).cpu  # traced again, kernels from the disk cache
        task.advance()
        steady = best_time(learn, 1, setup=lambda: build("compiled"))  # graphs in memory: the sweep's other fleets
        compiled_update = held["update_s"]
        task.advance()
        eager = best_time(learn, 1, setup=lambda: build("eager"))
        eager_update = held["update_s"]
        task.advance()
        if name == "ppo":
            rollout = held["f"].rollout
            rng = np.random.default_rng(0)
            shares = [_distinct_share(rollout.obs[r].numpy(), int(spec.hparams["batch_size"]), rng) for r in range(k)]
        per_run = 1e6 / (k * budget)
        ratio = eager.cpu / steady.cpu
        ratios.append(ratio)
        label = spec.label if protocol == "paper" else f"{spec.label} ({protocol} protocol)"
        rows.append([
            label, f"{budget:,}", f"{eager.cpu * per_run:.1f}", f"{steady.cpu * per_run:.1f}", f"{ratio:.2f}x",
            f"{eager_update:.2f}", f"{compiled_update:.2f}", f"{eager_update / compiled_update:.2f}x",
            *((f"{first - steady.cpu:.1f}", f"{cached - steady.cpu:.1f}") if STEP[name] not in seen
              else (f"(the row above's {STEP[name]})", f"{cached - steady.cpu:.1f}")),
        ])
        seen.add(STEP[name])
    task.done()
    met = sum(r >= TARGET for r in ratios)
    notes = [
        (f"Target: core time per learner down {TARGET:.0f}x on the compiled engine: met by {met} of {len(ratios)} "
         f"(whole-training speed-ups {', '.join(f'{r:.2f}x' for r in ratios)}). Measured on one fleet of K={k} of "
         f"one scenario, not on whole Table 1 rows"
         + (": a quick run, whose fleets of 2 pay more Python per run than a sweep's fleets of 15-36, so these "
            "ratios are not a sweep's." if ctx.quick else ".")),
    ]
    if shares:
        notes.append(
            f"Repeated states in PPO's minibatches: a minibatch of {spec_batch()} transitions holds on average "
            f"{100 * float(np.mean(shares)):.0f}% distinct observations (runs' range {100 * min(shares):.0f}-"
            f"{100 * max(shares):.0f}%); a forward pass on those only would save at most that share's complement of "
            "its rows, but needs a data-dependent shape that the compiled steps refuse (not built)."
        )
    return Section(
        intro=f"""
{SCENARIO}'s variants with the DualProcess chain, K={k} runs per fleet, paper hyper-parameters, torch on one thread,
*CPU* seconds of this process (another engineer's job shares the machine). Each learner is trained four times in
one process on the same budget: compiled with an empty compile cache (first), compiled again after
`torch._dynamo.reset()` (kernels from the disk cache: what every later process of a sweep pays), compiled with the
graphs in memory (steady: what every later fleet of a process pays), and eager (`update=eager`, the engine that
reruns the releases bit for bit). "core-s / run / 1M" is the whole training (rollouts and updates) per run per
million env steps; "update s" the CPU seconds inside the updates only; compile overheads are the first and cached
trainings' extra CPU seconds over the steady one (a learner whose step function an earlier row compiled reuses
that graph: no first compile of its own). The compiled engine compiles PPO's and PPO-Lag's minibatch
steps and CPO's critic steps (`morality_gym/baselines/fleet/compiled.py`); CPO's actor step stays eager.
""",
        headers=["learner", "steps per run", "eager core-s / run / 1M", "compiled core-s / run / 1M", "speed-up",
                 "eager update s", "compiled update s", "update speed-up", "compile s (first)", "compile s (cached)"],
        rows=rows,
        notes=notes,
        compare=["eager core-s / run / 1M", "compiled core-s / run / 1M"],
    )


def spec_batch() -> int:
    """PPO's minibatch size (the algo file's)."""
    return int(learner_spec("ppo").hparams["batch_size"])
