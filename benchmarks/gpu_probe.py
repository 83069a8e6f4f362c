"""Where a fleet's time goes on a GPU: rollout vs update per learner, and what N processes sharing one GPU add up to.

Why a probe beside the ``fleet_device`` benchmark: that section gives one rate per fleet; deciding
what to batch next (issue 31 item 4) needs the split between collecting a rollout and updating on
it, and deciding how many workers a GPU sweep should run (item 5) needs the aggregate rate of
several processes on one card. Prints one table; ``--json PATH`` keeps the numbers.

    python -m benchmarks.gpu_probe --sizes 336 --learners ppo cpo        # phases
    python -m benchmarks.gpu_probe --procs 8 --learners ppo --sizes 336  # 8 processes at once
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import time
from typing import Any

import torch as th

import morality_gym
from morality_gym.baselines.fleet import FleetRun, build_fleet
from morality_gym.baselines.specs import learner_spec

SCENARIO, CHAIN = "Switch5", "Utility"
LEARNERS = {"ppo": ("ppo", "paper"), "ppo_shaped": ("ppo_shaped", "paper"), "ppo_lag": ("ppo_lag", "paper"),
            "cpo": ("cpo", "paper"), "ppo_lag_corrected": ("ppo_lag", "corrected"), "cpo_corrected": ("cpo", "corrected")}


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        th.cuda.synchronize()


def _fleet(key: str, k: int, device: str, update: str = "eager") -> Any:
    name, protocol = LEARNERS[key]
    ids = morality_gym.env_ids(SCENARIO)
    runs = [FleetRun(morality_gym.bind_chain(CHAIN, ids[i % len(ids)]), 41 + i // len(ids)) for i in range(k)]
    return build_fleet(learner_spec(name), runs, protocol, device=device, update=update)


def phases(key: str, k: int, device: str, updates: int = 2, update: str = "eager") -> dict[str, Any]:
    """Seconds spent collecting rollouts and updating over ``updates`` updates, after one warm-up
    update (which pays the compiled engine's compile: ``warmup_s``)."""
    fleet = _fleet(key, k, device, update)
    spec = fleet.spec
    rollout = int(spec.hparams["n_steps"]) * spec.n_envs
    spent = {"rollout": 0.0, "update": 0.0}

    def timed(phase: str, fn: Any) -> Any:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            _sync(device)
            t = time.perf_counter()
            out = fn(*args, **kwargs)
            _sync(device)
            spent[phase] += time.perf_counter() - t
            return out

        return wrapper

    t = time.perf_counter()
    fleet.learn(rollout)  # warm-up: kernels, allocator, caches, compiled graphs
    warmup = time.perf_counter() - t
    fleet = _fleet(key, k, device, update)
    fleet.collector.collect = timed("rollout", fleet.collector.collect)
    fleet._train = timed("update", fleet._train)
    _sync(device)
    t = time.perf_counter()
    fleet.learn(rollout * updates)
    _sync(device)
    wall = time.perf_counter() - t
    steps = k * rollout * updates
    return {"learner": key, "update": update, "K": k, "steps": steps, "wall_s": wall, "rollout_s": spent["rollout"],
            "update_s": spent["update"], "steps_per_s": steps / wall, "warmup_s": warmup}


def _worker(args: tuple[str, int, str, int, Any, Any, str]) -> float:
    key, k, device, updates, barrier, out, update = args
    th.set_num_threads(1)
    fleet = _fleet(key, k, device, update)
    rollout = int(fleet.spec.hparams["n_steps"]) * fleet.spec.n_envs
    fleet.learn(rollout)  # warm-up
    fleet = _fleet(key, k, device, update)
    barrier.wait()
    _sync(device)
    t = time.perf_counter()
    fleet.learn(rollout * updates)
    _sync(device)
    out.put((k * rollout * updates, time.perf_counter() - t))
    return 0.0


def aggregate(key: str, k: int, device: str, procs: int, updates: int = 2, update: str = "eager") -> dict[str, Any]:
    """Env steps/s of ``procs`` processes each training a fleet of ``k`` at the same time (timed from a common start)."""
    ctx = mp.get_context("spawn")
    barrier, out = ctx.Barrier(procs), ctx.Queue()
    workers = [ctx.Process(target=_worker, args=((key, k, device, updates, barrier, out, update),)) for _ in range(procs)]
    for w in workers:
        w.start()
    results = [out.get() for _ in workers]
    for w in workers:
        w.join()
    steps = sum(s for s, _ in results)
    slowest = max(t for _, t in results)
    return {"learner": key, "update": update, "K": k, "procs": procs, "steps": steps, "wall_s": slowest,
            "steps_per_s": steps / slowest}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--learners", nargs="+", default=["ppo", "cpo"], choices=sorted(LEARNERS))
    parser.add_argument("--sizes", nargs="+", type=int, default=[336])
    parser.add_argument("--device", default="cuda" if th.cuda.is_available() else "cpu")
    parser.add_argument("--procs", type=int, default=0, help="N > 0: N processes at once instead of the phase split")
    parser.add_argument("--updates", type=int, default=2)
    parser.add_argument("--json", default="")
    parser.add_argument("--update", default="eager", choices=["eager", "compiled"], help="the fleets' update engine")
    a = parser.parse_args(argv)
    th.set_num_threads(1)
    rows = []
    for key in a.learners:
        for k in a.sizes:
            row = (aggregate(key, k, a.device, a.procs, a.updates, a.update) if a.procs
                   else phases(key, k, a.device, a.updates, a.update))
            rows.append(row)
            print("  ".join(f"{n}={v:,.2f}" if isinstance(v, float) else f"{n}={v}" for n, v in row.items()), flush=True)
    if a.json:
        with open(a.json, "a") as fh:
            for row in rows:
                fh.write(json.dumps({**row, "device": a.device}) + "\n")


if __name__ == "__main__":
    main()
