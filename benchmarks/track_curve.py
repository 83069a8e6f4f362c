"""A pilot learning curve of the generalisation track: seen-dilemma score against env steps.

Why: issue 44 item 4 asks each learner to train until its curve on seen dilemmas flattens, and the
budget to be chosen from measured curves. This trains one learner's fleet (``--seeds``) on a
chain's v2 train mixture exactly as ``runners.track --chain`` does, and every ``--every`` steps per
run scores each run's current policy exactly (no sampling noise) on a fixed sample of the chain's
seen dilemmas (``--sample`` env ids of the v2 train pool, drawn with the track's seen seed), writing
one CSV row per (run, point): ``learner, chain, seed, steps, mean_range_score, cpu_seconds``.

    nice -n 19 python -m benchmarks.track_curve --learner ppo --chain Utility --seeds 1 --steps 2000000 \\
        --every 250000 --out results/track-pilot/ppo-Utility.csv

Points are taken at update boundaries (the first boundary at or after each multiple of ``--every``),
and at the end.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path
from typing import Any

import torch

from morality_gym.baselines.fleet import FleetRun, build_fleet
from morality_gym.baselines.specs import learner_spec
from morality_gym.generalisation.scoring import score_set
from morality_gym.generalisation.selection import read_manifest
from morality_gym.generalisation.sets import EvalSet, dilemma_values, seen_sample
from morality_gym.generator.splits import load_split
from morality_gym.norms.metric import bind_chain

FIELDS = ("learner", "chain", "seed", "steps", "mean_range_score", "cpu_seconds")


def seen_set(chain: str, size: int) -> tuple[list[str], EvalSet]:
    """The chain's v2 train pool and an exact-valued sample of it (the track's seen seed)."""
    load_split("train")
    pool = read_manifest("train").env_ids(chain)
    ids = seen_sample(pool, size)
    pairs = tuple(p for env_id in ids for p in dilemma_values(env_id, [chain]))
    return pool, EvalSet("seen", pairs, {"split": "train", "chain": chain, "sample": f"{len(ids)} of {len(pool)}"})


def curve(learner: str, chain: str, seeds: list[int], steps: int, every: int, sample: int, out: Path) -> None:
    torch.set_num_threads(1)
    pool, seen = seen_set(chain, sample)
    fleet = build_fleet(learner_spec(learner), [FleetRun.mixture([bind_chain(chain, e) for e in pool], s) for s in seeds],
                        "paper")
    out.parent.mkdir(parents=True, exist_ok=True)
    c0 = time.process_time()
    next_point = [0]
    recorded = [-1]  # the steps of the last point written
    with out.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=FIELDS)
        writer.writeheader()

        def point(done: int, _total: int, last: bool = False) -> None:
            if done < next_point[0] and not last:
                return
            cpu = time.process_time() - c0
            for k, (seed, trained) in enumerate(zip(seeds, fleet.learners())):
                fleet.nets.export_run(k, trained.model.policy)
                rows: list[dict[str, Any]] = score_set(trained.model, seen)
                score = sum(r["range_score"] for r in rows) / len(rows)
                writer.writerow({"learner": learner, "chain": chain, "seed": seed, "steps": done,
                                 "mean_range_score": round(score, 4), "cpu_seconds": round(cpu, 1)})
                print(f"{learner} {chain} seed {seed}: {done:,} steps, seen mean range score {score:.4f} "
                      f"({cpu:.0f} CPU-s)", flush=True)
            fh.flush()
            recorded[0] = done
            while next_point[0] <= done:
                next_point[0] += every

        point(0, steps)
        fleet.learn(steps, on_progress=point)
        if recorded[0] != fleet.num_timesteps:  # the end, unless it was a point already
            point(fleet.num_timesteps, steps, last=True)


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.track_curve", description=__doc__.split("\n\n")[0])
    parser.add_argument("--learner", default="ppo", choices=("ppo", "ppo_shaped", "ppo_lag", "cpo"))
    parser.add_argument("--chain", default="Utility", choices=("Utility", "DualProcess"))
    parser.add_argument("--seeds", nargs="+", type=int, default=[1])
    parser.add_argument("--steps", type=int, default=2_000_000)
    parser.add_argument("--every", type=int, default=250_000)
    parser.add_argument("--sample", type=int, default=30, help="seen env ids scored at every point")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    curve(args.learner, args.chain, args.seeds, args.steps, args.every, args.sample, args.out)


if __name__ == "__main__":
    main()
