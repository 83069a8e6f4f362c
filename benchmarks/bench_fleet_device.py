"""The fleet engine per device: env steps/s per learner at K = 21, 84, 336 and 1,512 runs, the
simulators alone, and the paper Table 1 projected from those rates.

Why: the paper-budget Table 1 is 1.378 billion env steps; whether it fits a coffee break on one GPU
or a night on a workstation is a matter of these rates, so they are measured, per device, by the
same code a sweep runs (``build_fleet(...).learn``). The CUDA rows run wherever torch sees a GPU
(``benchmarks/gpu_check.sh`` runs this section on a GPU machine) and are marked skipped elsewhere.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

import torch

import morality_gym
from benchmarks import Context, Section, register
from morality_gym.baselines.fleet import FleetRun, build_fleet
from morality_gym.baselines.fleet.env import fleet_env
from morality_gym.baselines.specs import learner_spec
from morality_gym.paper import table1
from morality_gym.results.presets import load_preset

SCENARIO, CHAIN = "Switch5", "Utility"
#: (learner, protocol): the paper-protocol learners of Table 1, and PPO-Lag's dearer corrected protocol.
LEARNERS = (("ppo", "paper"), ("ppo_shaped", "paper"), ("ppo_lag", "paper"), ("cpo", "paper"), ("ppo_lag", "corrected"))
SIZES = (21, 84, 336, 1512)
#: The largest fleet measured on the CPU: K=336 of PPO is 5.5M env steps a rollout, minutes on one core.
CPU_MAX = 84
#: A lent GPU's minutes are few: ``MORALITY_GYM_BENCH_DEVICES=cuda`` and ``MORALITY_GYM_BENCH_SIZES=336,1512``
#: measure only those rows there (benchmarks/gpu_check.sh); the other cells read "not run".
DEVICES_ENV, SIZES_ENV = "MORALITY_GYM_BENCH_DEVICES", "MORALITY_GYM_BENCH_SIZES"


def _chosen_sizes(quick: bool) -> tuple[int, ...]:
    if os.environ.get(SIZES_ENV):
        return tuple(int(k) for k in os.environ[SIZES_ENV].split(","))
    return (21,) if quick else SIZES


def _sync(device: str) -> None:
    if device == "cuda":
        torch.cuda.synchronize()


def _timed(work: Callable[[], Any], device: str) -> tuple[float, float]:
    """(wall, CPU) seconds of ``work()``, the device's queue drained before and after."""
    _sync(device)
    wall, cpu = time.perf_counter(), time.process_time()
    work()
    _sync(device)
    return time.perf_counter() - wall, time.process_time() - cpu


def _fleet_rate(name: str, protocol: str, k: int, device: str) -> float:
    """Env steps/s of a fleet of ``k`` runs (Switch5's variants x seeds) over one rollout and update
    (two for the constrained learners, whose rollouts are short), after a warm-up rollout on a GPU."""
    ids = morality_gym.env_ids(SCENARIO)
    runs = [FleetRun(morality_gym.bind_chain(CHAIN, ids[i % len(ids)]), 41 + i // len(ids)) for i in range(k)]
    spec = learner_spec(name)
    rollout = int(spec.hparams["n_steps"]) * spec.n_envs
    per_run = rollout * (1 if name.startswith("ppo") and protocol == "paper" and "lag" not in name else 2)
    if device != "cpu":  # warm-up: the first kernels, the allocator, the caches
        build_fleet(spec, runs, protocol, device=device).learn(rollout)
    fleet = build_fleet(spec, runs, protocol, device=device)
    wall, cpu = _timed(lambda: fleet.learn(per_run), device)
    return k * per_run / (cpu if device == "cpu" else wall)


def _simulator_rate(simulator: str, k: int, device: str, steps: int) -> float:
    """Env steps/s of the fleet's simulator with its step-wise cost and reward, random actions."""
    ids = morality_gym.env_ids(SCENARIO)
    bounds = [morality_gym.bind_chain(CHAIN, ids[i % len(ids)]) for i in range(k)]
    spec = learner_spec("ppo_lag").reward_cost()
    env = fleet_env(simulator, bounds, 8, spec, 100, torch.device(device))  # type: ignore[arg-type]
    env.reset()
    gen = torch.Generator(device=device).manual_seed(0)
    actions = torch.randint(0, 6, (steps, k * 8), generator=gen, device=device)
    env.step(actions[0])

    def run() -> None:
        for a in actions:
            env.step(a)

    wall, cpu = _timed(run, device)
    return steps * k * 8 / (cpu if device == "cpu" else wall)


def table1_steps() -> dict[str, int]:
    """Env steps one learner trains for the paper Table 1 at the paper preset (its 126 (chain, env id) pairs x the preset's seeds)."""
    preset = load_preset("paper")
    total = sum(preset.budget_for(row.scenario) * len(morality_gym.env_ids(row.scenario)) * len(preset.seeds) for row in table1())
    return {name: total for name, _ in LEARNERS}


def _devices() -> list[str]:
    present = ["cpu", "cuda"] if torch.cuda.is_available() else ["cpu"]
    chosen = os.environ.get(DEVICES_ENV)
    return [d for d in present if d in chosen.split(",")] if chosen else present


def _absent(device: str) -> str:
    """The cell of a device not measured: no GPU here, or left out by :data:`DEVICES_ENV`."""
    return "skipped" if device == "cuda" and not torch.cuda.is_available() else "not run"


def _learner_rows(ctx: Context, rates: dict[tuple[str, str, str, int], float]) -> list[list[str]]:
    devices = _devices()
    sizes = _chosen_sizes(ctx.quick)
    task = ctx.task("fleet_device", len(LEARNERS) * len(sizes) * len(devices))
    rows = []
    for name, protocol in LEARNERS:
        label = learner_spec(name).label + ("" if protocol == "paper" else " (corrected)")
        for device in ("cpu", "cuda"):
            cells = [label, device]
            for k in SIZES:
                if device not in devices or k not in sizes or (device == "cpu" and k > CPU_MAX):
                    cells.append(_absent(device) if device not in devices else "-")
                    continue
                rates[(name, protocol, device, k)] = _fleet_rate(name, protocol, k, device)
                cells.append(f"{rates[(name, protocol, device, k)]:,.0f}")
                task.advance()
            rows.append(cells)
    task.done()
    return rows


def _simulator_rows(ctx: Context) -> list[list[str]]:
    steps = ctx.size(200, 20)
    rows = []
    for device in ("cpu", "cuda"):
        for simulator in ("host", "device"):
            cells = [f"simulator: {simulator}", device]
            for k in SIZES:
                if device not in _devices():
                    cells.append(_absent(device))
                    continue
                cells.append(f"{_simulator_rate(simulator, k, device, steps):,.0f}")
            rows.append(cells)
    return rows


def _projection(rates: dict[tuple[str, str, str, int], float]) -> list[str]:
    """The paper-protocol Table 1 projected per device from each learner's best measured fleet rate."""
    steps = table1_steps()
    notes = []
    for device in _devices():
        parts, total = [], 0.0
        for name, protocol in LEARNERS:
            measured = [r for (n, p, d, _), r in rates.items() if (n, p, d) == (name, protocol, device)]
            if protocol != "paper" or not measured:
                continue
            seconds = steps[name] / max(measured)
            total += seconds
            parts.append(f"{learner_spec(name).label} {seconds / 60:.0f} min")
        notes.append(
            f"Paper-protocol Table 1 on {device}, one process, each learner at its fastest measured K: "
            f"{total / 60:.0f} min ({', '.join(parts)}; {steps['ppo'] / 1e6:.0f}M env steps per learner; Random not counted)."
        )
    return notes


@register("fleet_device", "Fleet engine per device: env steps/s at K = 21 to 1,512 runs, and Table 1 projected", order=77)
def fleet_device(ctx: Context) -> Section:
    torch.set_num_threads(1)
    rates: dict[tuple[str, str, str, int], float] = {}
    rows = _learner_rows(ctx, rates) + _simulator_rows(ctx)
    return Section(
        intro=f"""
`build_fleet(spec, runs, protocol, device=...).learn(...)` on {SCENARIO} under {CHAIN} with the paper's hyper-parameters:
K runs (its variants x seeds), one rollout and update for PPO and PPO-Shaped, two for PPO-Lag and CPO (after a
warm-up rollout on a GPU). Env steps per second of all runs together: per *CPU* second on the CPU (torch on one thread,
steadier on a shared machine), per wall second on CUDA (the device's queue drained before and after). CPU fleets
above K={CPU_MAX} are not measured ("-": minutes per rollout on one core). The simulator rows step the fleet's
simulator with its step-wise cost and reward (`host`: numpy, `device`: torch on the device), 8 envs per run,
random actions. "skipped": torch sees no GPU here; `benchmarks/gpu_check.sh` runs this section on a GPU machine,
and `benchmarks/gpu_runs/` keeps what lent GPUs measured (card, commit, per-phase seconds, several processes at once).
""",
        headers=["learner", "device", *[f"K={k:,} steps/s" for k in SIZES]],
        rows=rows,
        notes=_projection(rates),
        compare=[f"K={k:,} steps/s" for k in SIZES],
    )


__all__ = ["fleet_device", "table1_steps"]
