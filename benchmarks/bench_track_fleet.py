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
from itertools import pairwise
from pathlib import Path
from typing import Any

import torch

from benchmarks import Context, Section, register
from morality_gym.baselines.fleet import FleetRun, build_fleet
from morality_gym.baselines.specs import learner_spec, protocol_spec
from morality_gym.generalisation.selection import read_manifest
from morality_gym.generalisation.sets import table_cache_dir
from morality_gym.generator.splits import load_split
from morality_gym.norms.metric import bind_chain
from morality_gym.world.compact_observe import COMPACT_WIDTH

LEARNERS = ("ppo", "ppo_shaped", "ppo_lag", "cpo")
#: Runs per fleet: the release's seeds per learner and chain.
RELEASE_SEEDS = 5
#: Env steps per run the release trains (issue 44: at least 10M), for the compute estimate.
RELEASE_STEPS = 10_000_000
TARGET_PPO = 30_000.0


#: The phases of a fleet's learn timed apart (CPU seconds of this process): the update, and in the
#: rollout the policy's forward pass and sampling, and the mixture's step (drawing, stepping,
#: cost and reward); the rest of the rollout is its buffers, bootstrap and GAE.
PHASES = ("update", "rollout", "policy", "env_step")


def _timed_phases(fleet: Any) -> dict[str, float]:
    """Wrap the fleet's phases (:data:`PHASES`) with CPU timers; returns the totals, filled as it learns."""
    totals = dict.fromkeys(PHASES, 0.0)

    def wrap(obj: Any, name: str, phase: str) -> None:
        inner = getattr(obj, name)

        def timed(*args: Any, **kwargs: Any) -> Any:
            c0 = time.process_time()
            try:
                return inner(*args, **kwargs)
            finally:
                totals[phase] += time.process_time() - c0

        setattr(obj, name, timed)

    wrap(fleet, "_train", "update")
    wrap(fleet.collector, "collect", "rollout")
    wrap(fleet.collector, "_policy_step", "policy")
    wrap(fleet.collector.env, "step", "env_step")
    return totals


def _marker(marks: list[tuple[int, float, float]]) -> Any:
    """An ``on_progress`` hook appending (steps, CPU, wall) after each update to ``marks``."""
    return lambda done, _total: marks.append((done, time.process_time(), time.perf_counter()))


def measure(chain: str, runs: int, learners: tuple[str, ...] = LEARNERS, say: Any = print,
            table_cache: Path | None = None, device: str = "cpu", pool_size: int | None = None,
            rollouts: int = 1) -> list[dict[str, Any]]:
    """Steps per CPU-second (and per wall second: a GPU's figure) of each learner's fleet of ``runs``
    runs on ``chain``'s v2 train pool (its first ``pool_size`` dilemmas: a quick build), with each
    phase's CPU seconds (:data:`PHASES`), over ``rollouts`` rollouts and updates; on a GPU after one
    untimed warm-up update (its first update pays its set-up). The pool's tables are read from
    ``table_cache`` (default: the track's, :func:`morality_gym.generalisation.sets.table_cache_dir`)."""
    load_split("train")
    pool = [bind_chain(chain, env_id) for env_id in read_manifest("train").env_ids(chain)[:pool_size]]
    cache = table_cache_dir() if table_cache is None else table_cache
    rows = []
    for name in learners:
        spec = protocol_spec("paper").apply(learner_spec(name))
        rollout = int(spec.hparams.get("n_steps", 2048)) * spec.n_envs
        t0, b0 = time.perf_counter(), time.process_time()
        fleet = build_fleet(learner_spec(name), [FleetRun.mixture(pool, seed) for seed in range(runs)], "paper",
                            device=device, table_cache=cache)
        built, built_cpu = time.perf_counter() - t0, time.process_time() - b0
        phases = _timed_phases(fleet)
        warm = 0 if device == "cpu" else 1
        marks = [(0, time.process_time(), time.perf_counter())]  # (steps, CPU, wall) after each update
        fleet.learn((warm + rollouts) * rollout, on_progress=_marker(marks))
        (s0, c0, w0), (s1, c1, w1) = marks[warm], marks[-1]
        steps, cpu, wall = s1 - s0, c1 - c0, w1 - w0
        rows.append({"learner": name, "runs": runs, "steps_per_run": steps, "cpu_s": cpu, "wall_s": wall,
                     "rate": steps * runs / cpu, "wall_rate": steps * runs / wall, "build_s": built,
                     "build_cpu_s": built_cpu, "pool": len(pool), "device": device, "chain": chain,
                     **{f"{phase}_s": phases[phase] for phase in PHASES}})
        say(f"{chain} {name} on {device}: K={runs}, pool {len(pool)}, {steps:,} steps per run, "
            f"{steps * runs / cpu:,.0f} env steps per CPU-second, {steps * runs / wall:,.0f} per wall second "
            f"(update {phases['update']:.1f} s, rollout {phases['rollout']:.1f} s of all updates' CPU; "
            f"fleet built in {built:.0f} s)")
        del fleet
    return rows


#: Larger PPO fleets measured beside the release's K: a run's bits do not depend on the runs that share
#: its fleet (tests/test_track_fleet.py), so training more seeds (or both chains' seeds) in one fleet is
#: the one speed-up that changes no bit of any run.
LARGER_K = (10, 20)


def update_flops(width: int, arch: tuple[int, ...], epochs: int) -> float:
    """Multiply-adds x 2 of PPO's update per env step: ``epochs`` passes over every transition, each a
    forward and a backward pass (about twice the forward's products, less the first layer's input
    gradient, which no one needs) through the actor (6 outputs) and the critic (1)."""
    total = 0.0
    for out in (6, 1):
        dims = (width, *arch, out)
        forward = sum(2 * a * b for a, b in pairwise(dims))
        total += 3 * forward - 2 * width * arch[0]
    return epochs * total


@register("track_fleet", "Generalisation track: fleet training throughput per learner on the train mixture", order=77)
def track_fleet(ctx: Context) -> Section:
    chain = "Utility"
    rows_data = measure(chain, RELEASE_SEEDS, LEARNERS if not ctx.quick else ("ppo",), say=lambda _m: None)
    larger = [] if ctx.quick else [r for k in LARGER_K for r in measure(chain, k, ("ppo",), say=lambda _m: None)]
    rows = []
    total_hours = 0.0
    for r in rows_data + larger:
        hours = RELEASE_SEEDS * RELEASE_STEPS / r["rate"] / 3600
        if r["runs"] == RELEASE_SEEDS:
            total_hours += 2 * hours  # two chains
        rows.append([r["learner"], f"{r['runs']}", f"{r['steps_per_run']:,}", f"{r['rate']:,.0f}",
                     f"{r['update_s']:.2f} ({100 * r['update_s'] / r['cpu_s']:.0f} %)",
                     f"{r['rollout_s']:.2f} ({r['policy_s']:.2f} / {r['env_step_s']:.2f})",
                     f"{r['build_s']:.1f} / {r['build_cpu_s']:.1f}", f"{hours:.1f}"])
    ppo = next(r for r in rows_data if r["learner"] == "ppo")
    spec = protocol_spec("paper").apply(learner_spec("ppo"))
    epochs, arch = int(spec.hparams.get("n_epochs", 10)), tuple(spec.net_arch)
    flops = {w: update_flops(w, arch, epochs) for w in (COMPACT_WIDTH, 32)}
    ceiling = ppo["steps_per_run"] * ppo["runs"] / ppo["update_s"]
    notes = [(f"Target: PPO at least {TARGET_PPO:,.0f} env steps per CPU-second at the release's K={RELEASE_SEEDS}: "
              f"{'met' if ppo['rate'] >= TARGET_PPO else 'not met'} ({ppo['rate']:,.0f}). Whole release (4 learners x 2 "
              f"chains x {RELEASE_SEEDS} seeds x 10M steps) at these rates: about {total_hours:.0f} CPU-hours."),
             (f"What limits PPO: its update, {100 * ppo['update_s'] / ppo['cpu_s']:.0f} % of the CPU time; with a free "
              f"rollout it would still train at most {ceiling:,.0f} env steps per CPU-second. The update's products alone "
              f"are {flops[COMPACT_WIDTH] / 1e6:.2f} MFLOP per env step (the paper's {epochs} epochs through the "
              f"{COMPACT_WIDTH}-{'-'.join(map(str, arch))} actor and critic), the rest is per-minibatch work (Adam, "
              "gradient clipping, the loss) that a fleet of K runs pays once for all K, hence the larger fleets' rates. "
              "The update lives in `morality_gym/baselines/fleet/{ppo,nets,optim}.py`."),
             (f"Without changing a run's arithmetic PPO gets faster only in larger fleets (more seeds, or both chains' "
              f"seeds, in one fleet: the rows K={', '.join(map(str, LARGER_K))}). Changes of arithmetic that would: the "
              f"compiled update (`update=compiled`, other float rounding), a narrower compact observation (width 32: "
              f"{flops[32] / 1e6:.2f} MFLOP per env step, new observations, so new runs), fewer epochs (new "
              "hyper-parameters).")]
    if ctx.quick:
        notes = notes[:1]
    return Section(
        intro=f"""
Each learner trains K={RELEASE_SEEDS} runs (the release's seeds per learner and chain) at once on the {chain}
chain's v2 train pool ({rows_data[0]['pool']} dilemmas, each episode one the run's own seed draws), seen through
the compact observation ({COMPACT_WIDTH} numbers, `morality_gym/world/compact_observe.py`), with the paper's
(Table 1) hyper-parameters: one rollout and its update, torch on one thread. Env steps of all runs per *CPU*
second of the process, and where they went: the update, and the rollout (of which the policy's forward pass
with the sampling, and the mixture's step: drawing, stepping, cost, reward), CPU seconds. The fleet is built
from the pool's cached tables (`morality_gym/envs/table_cache.py`, written by an earlier build), wall / CPU
seconds, not in the rate. One measurement each. The last column projects one chain's release compute:
{RELEASE_SEEDS} seeds x {RELEASE_STEPS:,} steps at this rate.
""",
        headers=["learner", "runs K", "steps per run", "env steps per CPU-second", "update CPU s (share)",
                 "rollout CPU s (policy / env step)", "fleet build s, cached tables (wall / CPU)",
                 f"CPU-hours for {RELEASE_SEEDS} x 10M"],
        rows=rows,
        notes=notes,
        compare=["env steps per CPU-second"],
    )


def main() -> None:
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
