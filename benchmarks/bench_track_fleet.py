"""Generalisation-track training throughput: each learner's fleet on a chain's train mixture.

Why: issue 44 asks the track's learners to train at fleet speed (target: PPO at least 30,000 env
steps per CPU-second on this machine's class, what Table 1's fleets reach on built-in envs), and the
release's compute to be estimated from measured throughput. Each learner trains ``K`` runs (the
seeds of one learner and chain: 5 in the release) on the chain's v2 train pool through
:class:`~morality_gym.baselines.fleet.drawn_env.DrawnFleetEnv` for one rollout and its update, with
the paper's hyper-parameters; CPU seconds of the process, torch on one thread, building the fleet
not timed. Needs the ``train`` split (generated on first use into ``$MORALITY_GYM_CACHE``: minutes).

``python -m benchmarks.bench_track_fleet [--chain Utility] [--runs 5]`` prints the same rows.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from benchmarks import Context, Section, register
from morality_gym.baselines.fleet import FleetRun, build_fleet
from morality_gym.baselines.specs import learner_spec, protocol_spec
from morality_gym.generalisation.selection import read_manifest
from morality_gym.generator.splits import load_split
from morality_gym.norms.metric import bind_chain
from morality_gym.world.compact_observe import COMPACT_WIDTH

LEARNERS = ("ppo", "ppo_shaped", "ppo_lag", "cpo")
#: Runs per fleet: the release's seeds per learner and chain.
RELEASE_SEEDS = 5
#: Env steps per run the release trains (issue 44: at least 10M), for the compute estimate.
RELEASE_STEPS = 10_000_000
TARGET_PPO = 30_000.0


def _marker(marks: list[tuple[int, float, float]]) -> Any:
    """An ``on_progress`` hook appending (steps, CPU, wall) after each update to ``marks``."""
    return lambda done, _total: marks.append((done, time.process_time(), time.perf_counter()))


def measure(chain: str, runs: int, learners: tuple[str, ...] = LEARNERS, say: Any = print, device: str = "cpu",
            pool_size: int | None = None, rollouts: int = 1) -> list[dict[str, Any]]:
    """Steps per CPU-second (and per wall second: a GPU's figure) of each learner's fleet of ``runs``
    runs on ``chain``'s v2 train pool (its first ``pool_size`` dilemmas: a quick build), ``rollouts``
    rollouts and updates after one untimed warm-up update (a GPU's first update pays its set-up)."""
    load_split("train")
    pool = [bind_chain(chain, env_id) for env_id in read_manifest("train").env_ids(chain)[:pool_size]]
    rows = []
    for name in learners:
        spec = protocol_spec("paper").apply(learner_spec(name))
        rollout = int(spec.hparams.get("n_steps", 2048)) * spec.n_envs
        t0 = time.perf_counter()
        fleet = build_fleet(learner_spec(name), [FleetRun.mixture(pool, seed) for seed in range(runs)], "paper",
                            device=device)
        built = time.perf_counter() - t0
        warm = 0 if device == "cpu" else 1
        marks = [(0, time.process_time(), time.perf_counter())]  # (steps, CPU, wall) after each update
        fleet.learn((warm + rollouts) * rollout, on_progress=_marker(marks))
        (s0, c0, w0), (s1, c1, w1) = marks[warm], marks[-1]
        steps, cpu, wall = s1 - s0, c1 - c0, w1 - w0
        rows.append({"learner": name, "runs": runs, "steps_per_run": steps, "cpu_s": cpu, "wall_s": wall,
                     "rate": steps * runs / cpu, "wall_rate": steps * runs / wall, "build_s": built, "pool": len(pool),
                     "device": device, "chain": chain})
        say(f"{chain} {name} on {device}: K={runs}, pool {len(pool)}, {steps:,} steps per run, "
            f"{steps * runs / cpu:,.0f} env steps per CPU-second, {steps * runs / wall:,.0f} per wall second "
            f"(fleet built in {built:.0f} s)")
        del fleet
    return rows


@register("track_fleet", "Generalisation track: fleet training throughput per learner on the train mixture", order=77)
def track_fleet(ctx: Context) -> Section:
    chain = "Utility"
    rows_data = measure(chain, RELEASE_SEEDS, LEARNERS if not ctx.quick else ("ppo",), say=lambda _m: None)
    rows = []
    total_hours = 0.0
    for r in rows_data:
        hours = RELEASE_SEEDS * RELEASE_STEPS / r["rate"] / 3600
        total_hours += 2 * hours  # two chains
        rows.append([r["learner"], f"{r['runs']}", f"{r['steps_per_run']:,}", f"{r['rate']:,.0f}", f"{hours:.1f}"])
    ppo = next(r["rate"] for r in rows_data if r["learner"] == "ppo")
    return Section(
        intro=f"""
Each learner trains K={RELEASE_SEEDS} runs (the release's seeds per learner and chain) at once on the {chain}
chain's v2 train pool ({rows_data[0]['pool']} dilemmas, each episode one the run's own seed draws), seen through
the compact observation ({COMPACT_WIDTH} numbers, `morality_gym/world/compact_observe.py`), with the paper's
(Table 1) hyper-parameters: one rollout and its update, torch on one thread. Env steps of all runs per *CPU*
second of the process; building the fleet (the pool's tables) is not timed. One measurement each. The last
column projects one chain's release compute: {RELEASE_SEEDS} seeds x {RELEASE_STEPS:,} steps at this rate.
""",
        headers=["learner", "runs K", "steps per run", "env steps per CPU-second", f"CPU-hours for {RELEASE_SEEDS} x 10M"],
        rows=rows,
        notes=[(f"Target: PPO at least {TARGET_PPO:,.0f} env steps per CPU-second: "
               f"{'met' if ppo >= TARGET_PPO else 'not met'} ({ppo:,.0f}). Whole release (4 learners x 2 chains x "
               f"{RELEASE_SEEDS} seeds x 10M steps) at these rates: about {total_hours:.0f} CPU-hours.")],
        compare=["env steps per CPU-second"],
    )


def main() -> None:
    import torch

    torch.set_num_threads(1)
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_track_fleet", description=__doc__.split("\n\n")[0])
    parser.add_argument("--chain", default="Utility", choices=("Utility", "DualProcess"))
    parser.add_argument("--runs", type=int, default=RELEASE_SEEDS)
    parser.add_argument("--learners", nargs="+", default=list(LEARNERS), choices=LEARNERS)
    parser.add_argument("--device", default="cpu", help="where the networks train (cpu, cuda); the mixture steps on the host")
    parser.add_argument("--pool", type=int, default=None, help="the train pool's first N dilemmas only (a quick build)")
    parser.add_argument("--rollouts", type=int, default=1, help="rollouts and updates timed per learner")
    parser.add_argument("--json", type=Path, default=None, help="append each row to this JSON-lines file")
    args = parser.parse_args()
    rows = measure(args.chain, args.runs, tuple(args.learners), device=args.device, pool_size=args.pool,
                   rollouts=args.rollouts)
    if args.json is not None:
        with args.json.open("a") as out:
            out.writelines(json.dumps(row) + "\n" for row in rows)


if __name__ == "__main__":
    main()
