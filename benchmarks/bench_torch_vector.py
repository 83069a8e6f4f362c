"""Throughput of the public device vector env (:class:`morality_gym.TorchTrolleyVectorEnv`) and of the
example algorithm that trains on it (``examples/ppo_lag_torch``), beside the host simulator and the fleet."""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

import morality_gym
from benchmarks import Context, Section, best_time, register
from leaderboard.submit import select_cells
from morality_gym.baselines.fleet import FleetRun, build_fleet
from morality_gym.baselines.specs import learner_spec
from morality_gym.envs.batched import BatchedTrolleyEnv
from morality_gym.envs.registry import scenario_named
from morality_gym.norms.cost import VectorCost

ENV_ID = "PushOrSwitch-Human-v1"
CHAIN = "DualProcess"
SIZES = (256, 1_024, 4_096, 16_384, 65_536)
POOL = 64  # rows of pre-generated actions, reused cyclically
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "ppo_lag_torch" / "ppo_lag.py"


def _steps_for(copies: int, quick: bool) -> int:
    """Steps per measurement: about 4M env steps (0.4M quick), at least 20 steps."""
    return max(20, (400_000 if quick else 4_000_000) // copies)


def _host_work(copies: int, steps: int, cost: bool) -> tuple[Callable[[], object], Callable[[], object]]:
    """(setup, work) stepping the numpy simulator, optionally with the host cost of every copy."""
    held: dict[str, Any] = {}
    pool = np.random.default_rng(0).integers(0, 6, size=(POOL, copies))

    def setup() -> None:
        held["env"] = BatchedTrolleyEnv(ENV_ID, copies, autoreset="same_step")
        held["cost"] = VectorCost(morality_gym.bind_chain(CHAIN, ENV_ID), copies)
        held["env"].reset()

    def work() -> None:
        env, vc = held["env"], held["cost"]
        for i in range(steps):
            res = env.step(pool[i % POOL])
            if cost:
                vc(res.events, env.utility(res.transition), res.terminated | res.truncated)

    return setup, work


def _device_work(copies: int, steps: int, cost: bool, device: str) -> tuple[Callable[[], object], Callable[[], object]]:
    """(setup, work) stepping :class:`TorchTrolleyVectorEnv` (actions unchecked, as a tuned loop runs it),
    optionally wrapped with :class:`TorchCostWrapper`; a CUDA measurement ends with a synchronize."""
    held: dict[str, Any] = {}

    def setup() -> None:
        env: Any = morality_gym.TorchTrolleyVectorEnv(ENV_ID, copies, device=device, check_actions=False)
        if cost:
            env = morality_gym.TorchCostWrapper(env, CHAIN)
        gen = th.Generator(device="cpu").manual_seed(0)
        held["pool"] = th.randint(0, 6, (POOL, copies), generator=gen, device="cpu").to(device)
        held["env"] = env
        env.reset()

    def work() -> None:
        env, pool = held["env"], held["pool"]
        for i in range(steps):
            env.step(pool[i % POOL])
        if device.startswith("cuda"):
            th.cuda.synchronize()

    return setup, work


def _rate(setup: Callable[[], object], work: Callable[[], object], env_steps: int, repeats: int, wall: bool) -> float:
    timing = best_time(work, repeats, setup=setup)
    return env_steps / (timing.wall if wall else timing.cpu)


@register("torch_vector", "Device vector env: env steps per second at 256 to 65,536 copies, cpu and cuda", order=77)
def torch_vector_speed(ctx: Context) -> Section:
    th.set_num_threads(1)
    gpu = th.cuda.is_available()
    sizes = SIZES[:2] if ctx.quick else SIZES
    task = ctx.task("torch_vector", len(sizes) * 6)
    rows = []
    for copies in sizes:
        steps = _steps_for(copies, ctx.quick)
        cells = [f"{copies:,}", f"{steps:,}"]
        for cost in (False, True):
            cells.append(f"{_rate(*_host_work(copies, steps, cost), copies * steps, ctx.repeats, wall=False):,.0f}")
            task.advance()
        for device in ("cpu", "cuda"):
            for cost in (False, True):
                if device == "cuda" and not gpu:
                    cells.append("skipped (no GPU)")
                else:
                    cells.append(f"{_rate(*_device_work(copies, steps, cost, device), copies * steps, ctx.repeats, wall=device == 'cuda'):,.0f}")
                task.advance()
        rows.append(cells)
    task.done()
    card = th.cuda.get_device_name(0) if gpu else "none (torch sees no GPU)"
    return Section(
        intro=f"""
Copies of `{ENV_ID}` stepped with uniform-random actions (a pool of {POOL} rows drawn before timing, reused
cyclically), same-step auto-reset, `max_steps` 200; "env steps/s" counts every copy's step. "host numpy" is
`BatchedTrolleyEnv.step` (the simulator behind `TrolleyVectorEnv`); "device" is
`morality_gym.TorchTrolleyVectorEnv(..., check_actions=False)`, its tensors on the named device; "+ cost" adds the
step-wise cost of the {CHAIN} chain (`VectorCost` on the host, `TorchCostWrapper` on the device). Host and cpu
rates are per CPU-second of the process (one thread); cuda rates are wall-clock, ending with a synchronize.
Best of {ctx.repeats} runs. GPU: {card}.
""",
        headers=["copies", "steps per run", "host numpy", "host numpy + cost", "device cpu", "device cpu + cost",
                 "device cuda", "device cuda + cost"],
        rows=rows,
        compare=["host numpy", "device cpu", "device cuda"],
    )


def _load_example() -> Any:
    """The example script as a module (it is a file to copy, not part of a package)."""
    spec = importlib.util.spec_from_file_location("ppo_lag_torch_example", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@register("torch_vector_example", "The example PPO-Lagrangian on the device vector env vs the fleet's PPO-Lag, cpu", order=78)
def example_speed(ctx: Context) -> Section:
    """Why: the issue asks the example algorithm on the vector env to be at least as fast per run as the
    fleet's PPO-Lag. Both train the 12 SwitchStandard variants under Utility (seeds 41.. for K > 12)."""
    th.set_num_threads(1)
    example = _load_example()
    cell = select_cells(["Utility"], ["SwitchStandard"], [])[0]
    env_ids = [scenario_named(cell.scenario).env_id(v) for v in cell.variants]
    sizes = (12,) if ctx.quick else (12, 36)
    budget = 2_048 * (1 if ctx.quick else 4)
    rows = []
    task = ctx.task("torch_vector_example", len(sizes) * 3)
    for k in sizes:
        runs = [(cell, env_ids[i % len(env_ids)], 41 + i // len(env_ids)) for i in range(k)]
        args = example.parse_args(["--total-steps", str(budget), "--log-every", "1000000"])
        timing = best_time(lambda args=args, runs=runs: example.train(args, runs), 1)
        rows.append([f"example PPO-Lag (`examples/ppo_lag_torch`), {args.update_epochs} epochs x {args.num_minibatches} minibatches",
                     str(k), f"{budget:,}", f"{k * budget / timing.cpu:,.0f}", f"{budget / timing.cpu:,.0f}"])
        task.advance()
        for protocol, rollouts in (("paper", budget // 2_048), ("corrected", 1)):
            fleet_budget = 2_048 * rollouts
            fleet_runs = [FleetRun(morality_gym.bind_chain("Utility", e), s) for _, e, s in runs]
            held: dict[str, Any] = {}

            def build(held: dict[str, Any] = held, fleet_runs: list[Any] = fleet_runs, protocol: str = protocol) -> None:
                held["f"] = build_fleet(learner_spec("ppo_lag"), fleet_runs, protocol)

            timing = best_time(lambda held=held, b=fleet_budget: held["f"].learn(b), 1, setup=build)
            rows.append([f"fleet PPO-Lag, {protocol} protocol", str(k), f"{fleet_budget:,}", f"{k * fleet_budget / timing.cpu:,.0f}",
                         f"{fleet_budget / timing.cpu:,.0f}"])
            task.advance()
    task.done()
    return Section(
        intro="""
Training the K runs of Utility on SwitchStandard's 12 variants (K = 36: three seeds) in one process, torch on one
thread, CPU seconds of the process (building the fleet's learners untimed; the example's figure includes building its env
and networks). The example (`python examples/ppo_lag_torch/ppo_lag.py`, its defaults: 16 copies x 128
steps per run per update, 4 epochs of 4 minibatches) runs several passes over each rollout; the fleet's PPO-Lag has the
paper's hyper-parameters (8 envs x 256 steps, minibatch 64, up to 40 passes cut by the KL early stop: about one pass
under the paper protocol, up to 40 under the corrected one). One measurement each.
""",
        headers=["learner", "runs K", "steps per run", "env steps/s (all runs)", "env steps/s per run"],
        rows=rows,
        compare=["env steps/s (all runs)"],
    )
