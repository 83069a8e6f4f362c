"""Training throughput of the fleet engine: K runs of one learner in one process vs one run at a time."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

import morality_gym
from benchmarks import Context, Section, best_time, register
from morality_gym.baselines.fleet import FleetRun, build_fleet
from morality_gym.baselines.learners import build_learner
from morality_gym.baselines.specs import learner_spec

ENV_ID = "PushOrSwitch-Human-v1"
#: (learner, protocol, rollouts per measurement): enough rollouts that a figure is not one short
#: update; PPO's rollouts are 16,384 steps, the constrained learners' 2,048 (PPO-Lag under the
#: corrected protocol runs up to 40 passes per rollout, so one is plenty).
RUNS = (
    ("ppo", "paper", 1),
    ("ppo_shaped", "paper", 1),
    ("ppo_lag", "paper", 4),
    ("cpo", "paper", 4),
    ("ppo_lag", "corrected", 1),
    ("cpo", "corrected", 4),
)
TARGET = 10.0


def _target_note(ratios: list[tuple[int, float]], sizes: tuple[int, ...]) -> str:
    """Whether the largest fleet met :data:`TARGET`, with every learner's speed-up at both sizes."""
    top = max(sizes)
    at_top = [r for k, r in ratios if k == top]
    met = sum(r >= TARGET for r in at_top)
    at_12 = [r for k, r in ratios if k == min(sizes)]
    return (
        f"Target: the fleet at K={top} at least {TARGET:.0f}x the single runs' steps/s per core: met by "
        f"{met} of {len(at_top)} learners (speed-ups at K={top}: {', '.join(f'{r:.1f}x' for r in at_top)}; "
        f"at K={min(sizes)}: {', '.join(f'{r:.1f}x' for r in at_12)})."
    )


def _single_cpu(spec: Any, bound: Any, protocol: str, budget: int, seeds: range, task: Any) -> list[float]:
    """CPU seconds of one single run per seed the fleets train: how much work an update does can
    depend on the seed (PPO-Lag's KL early stop under the corrected protocol ends after 1 to 40
    passes), so each fleet is compared with the single runs of exactly its own seeds."""
    held: dict[str, Any] = {}
    single_cpu: list[float] = []
    for seed in seeds:

        def build_single(held: dict[str, Any] = held, spec: Any = spec, protocol: str = protocol, seed: int = seed) -> None:
            held["l"] = build_learner(spec, bound, protocol, seed=seed)

        def learn_single(held: dict[str, Any] = held, budget: int = budget) -> None:
            held["l"].learn(budget, eval_every=0)

        single_cpu.append(best_time(learn_single, 1, setup=build_single).cpu)
        task.advance()
    return single_cpu


@register("fleet", "Fleet engine: training steps per second per core, single run vs K runs at once", order=75)
def fleet_speed(ctx: Context) -> Section:
    torch.set_num_threads(1)
    sizes = (2, 4) if ctx.quick else (12, 36)
    seeds = range(max(sizes))
    bound = morality_gym.bind_chain("DualProcess", ENV_ID)
    task = ctx.task("fleet", len(RUNS) * (len(seeds) + len(sizes)))
    rows, ratios = [], []
    for name, protocol, rollouts in RUNS:
        spec = learner_spec(name)
        budget = spec.hparams["n_steps"] * spec.n_envs * rollouts
        held: dict[str, Any] = {}
        single_cpu = _single_cpu(spec, bound, protocol, budget, seeds, task)
        label = spec.label if protocol == "paper" else f"{spec.label} ({protocol} protocol)"
        cells = [label, f"{budget:,}"]
        for k in sizes:

            def build(held: dict[str, Any] = held, spec: Any = spec, k: int = k, protocol: str = protocol) -> None:
                held["f"] = build_fleet(spec, [FleetRun(bound, seed) for seed in range(k)], protocol)

            def learn_fleet(held: dict[str, Any] = held, budget: int = budget) -> None:
                held["f"].learn(budget)

            timing = best_time(learn_fleet, 1, setup=build)
            single_rate = k * budget / sum(single_cpu[:k])
            fleet_rate = k * budget / timing.cpu
            cells += [f"{single_rate:,.0f}", f"{fleet_rate:,.0f}", f"{fleet_rate / single_rate:.1f}x"]
            ratios.append((k, fleet_rate / single_rate))
            task.advance()
        rows.append(cells)
    task.done()
    headers = ["learner", "steps per run"]
    for k in sizes:
        headers += [f"single runs, seeds 0-{k - 1}, steps/s", f"fleet K={k} steps/s", f"K={k} speed-up"]
    return Section(
        intro=f"""
Training on `{ENV_ID}` (DualProcess chain) with the paper's hyper-parameters (8 envs per run), torch on one
thread. "single runs" is `build_learner(spec, bound, protocol, seed=s).learn(budget)` for each seed the fleet
trains, one after another; "fleet K=n" is `build_fleet(spec, [FleetRun(bound, s) for s in range(n)],
protocol).learn(budget)`, which trains the same n runs at once, each reproducing its single run to float
tolerance (tests/test_fleet.py). Steps per second per core are environment steps of all runs divided by the
*CPU* seconds of the process (CPU time is the steadier measure on a shared machine), including rollouts,
updates and the diagnostics rows; building the learners (a fleet builds one single-run learner per run for
its initial weights) is not timed. Each figure is one measurement. What the fleet saves: the per-run Python and
kernel-launch overhead (one batched product per layer for all runs), autograd (the gradients are written out,
`morality_gym/baselines/fleet/nets.py`), PyTorch's slow `tanh` and a narrow `log_softmax`, and for CPO and
PPO-Lag's KL test most of the whole-rollout arithmetic (it runs on each rollout's distinct observations,
`morality_gym/baselines/fleet/dedup.py`). What it cannot save is each run's own matrix products, which bound the
gain of the minibatch learners near 10x.
""",
        headers=headers,
        rows=rows,
        notes=[_target_note(ratios, sizes)],
        compare=[h for h in headers if h.endswith("steps/s")],
    )


@register("fleet_cost", "Fleet engine: the step-wise cost of 36 runs in one pass vs a loop over their groups", order=76)
def fleet_cost(ctx: Context) -> Section:
    """Why: a fleet's runs follow different (env id, chain) pairs; the cost was computed by one
    VectorCost per pair in a Python loop at every step. StackedCost does all copies in one pass with
    the same bits. Measured: the fleet simulator's step with its cost (random actions), and a short
    PPO-Lag and PPO training of the fleet, each with the loop and with the stacked cost."""
    torch.set_num_threads(1)
    ids = morality_gym.env_ids("PushOrSwitch")
    runs = [FleetRun(morality_gym.bind_chain(c, i), 41) for c in ("DualProcess", "Utility", "Outcome") for i in ids][:36]
    steps = 50 if ctx.quick else 500
    rows = []
    held: dict[str, Any] = {}
    task = ctx.task("fleet_cost", 6)
    for what, algo, budget in (("simulator + cost, 8 envs x 36 runs", None, steps),
                               ("PPO-Lag training", "ppo_lag", 2048 * (2 if ctx.quick else 8)),
                               ("PPO training", "ppo", 16384 * (1 if ctx.quick else 2))):
        cells = [what]
        for stacked in (False, True):

            def build(held: dict[str, Any] = held, stacked: bool = stacked, algo: str | None = algo) -> None:
                held["f"] = build_fleet(learner_spec(algo or "ppo_lag"), runs, "paper")
                if not stacked:
                    held["f"].collector.env._stacked = None  # the per-group loop, as before StackedCost
                held["f"].collector.env.reset()

            def work(held: dict[str, Any] = held, algo: str | None = algo, budget: int = budget) -> None:
                fleet = held["f"]
                if algo is None:
                    rng = np.random.default_rng(0)
                    for _ in range(budget):
                        fleet.collector.env.step(torch.from_numpy(rng.integers(0, 6, size=fleet.n_runs * fleet.n_envs)))
                else:
                    fleet.learn(budget)

            timing = best_time(work, 1 if algo else ctx.repeats, setup=build)
            cells.append(f"{timing.cpu:.2f}")
            task.advance()
        cells.append(f"{float(cells[1]) / float(cells[2]):.2f}x")
        rows.append(cells)
    task.done()
    return Section(
        intro=f"""
PushOrSwitch, 36 runs (12 variants x DualProcess, Utility, Outcome: 36 (env id, chain) groups), 8 envs each, paper
protocol, one thread; CPU seconds (best of the repeats for the simulator, one run for training). The first row steps the
fleet's simulator {steps} times with random actions and computes the cost; the others train the fleet
({'a short' if ctx.quick else '8 rollouts of PPO-Lag, 2 of PPO'} budget).
""",
        headers=["what", "loop over groups (s CPU)", "stacked (s CPU)", "speed-up"],
        rows=rows,
    )
