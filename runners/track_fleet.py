"""A chain's track trains its learners as fleets: all seeds of a learner in one process.

``python -m runners.track --chain Utility`` trains every learner (PPO on the paper's reward, PPO
Shaped on the chain's shaping, PPO-Lag and CPO on its step-wise cost) with its Table 1
hyper-parameters (the paper protocol) as one fleet per learner
(:mod:`morality_gym.baselines.fleet`): each run's copies play the chain's train dilemmas, every
episode one its own seed draws, seen through the compact observation
(:mod:`morality_gym.baselines.fleet.drawn_env`). A run's numbers do not depend on which other seeds
share its fleet (tested), so a rerun trains only the seeds whose ``result.json`` is missing.

The fleet checkpoints to ``DIR/fleets/<run prefix>-<learner>.pt`` (at most every
:data:`CHECKPOINT_EVERY_S` seconds and when training ends) and a rerun of the same command resumes
from it bit for bit; a file of another command (seeds, budget, pool) is discarded with one warning.
Progress: one line at most every :data:`PROGRESS_EVERY_S` seconds.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from morality_gym.baselines.fleet import FleetCheckpoint, FleetRun, build_fleet
from morality_gym.baselines.specs import learner_spec
from morality_gym.constants import MAX_STEPS
from morality_gym.norms.metric import bind_chain
from morality_gym.world.compact_observe import COMPACT_WIDTH

CHECKPOINT_EVERY_S = 300.0
PROGRESS_EVERY_S = 30.0


def fleet_key(learner: str, seeds: Sequence[int], budget: int, train_ids: Sequence[str], chain: str,
              train_digest: str) -> dict[str, Any]:
    """What a fleet checkpoint of the track is for (another command's file is discarded)."""
    return {"track": "generalisation", "learner": learner, "seeds": [int(s) for s in seeds], "budget": int(budget),
            "chain": chain, "train_digest": train_digest, "pool": len(train_ids)}


def train_fleet(learner: str, seeds: Sequence[int], budget: int, train_ids: Sequence[str], chain: str,
                checkpoint: Path, key: dict[str, Any], say: Callable[[str], None] = print) -> dict[int, tuple[Any, dict[str, Any]]]:
    """Train ``learner`` on the chain's mixture for every seed in one fleet; returns each seed's
    trained SB3 learner and what its result records."""
    spec = learner_spec(learner)
    pool = [bind_chain(chain, env_id) for env_id in train_ids]
    t0 = time.perf_counter()
    fleet = build_fleet(spec, [FleetRun.mixture(pool, seed) for seed in seeds], protocol="paper", max_steps=MAX_STEPS)
    say(f"{chain} {learner}: fleet of {len(seeds)} runs on {len(pool)} dilemmas built in {time.perf_counter() - t0:.0f} s")
    last = [time.perf_counter(), 0]

    def progress(steps: int, total: int) -> None:
        now = time.perf_counter()
        if now - last[0] >= PROGRESS_EVERY_S or steps >= total:
            rate = (steps - last[1]) * len(seeds) / max(now - last[0], 1e-9)
            say(f"{chain} {learner}: {steps:,} of {total:,} steps per run ({100 * steps / total:.0f} %), "
                f"{rate:,.0f} env steps/s over the fleet")
            last[:] = [now, steps]

    t1 = time.perf_counter()
    fleet.learn(budget, on_progress=progress, checkpoint=FleetCheckpoint(checkpoint, every_s=CHECKPOINT_EVERY_S, key=key))
    seconds = time.perf_counter() - t1
    failed = fleet.failed
    out: dict[int, tuple[Any, dict[str, Any]]] = {}
    model = fleet.model
    hparams = {name: getattr(model, name) for name in ("n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda")
               if isinstance(getattr(model, name, None), (int, float))}
    for k, (seed, trained) in enumerate(zip(seeds, fleet.learners())):
        info = {"engine": "fleet", "fleet_runs": len(seeds), "fleet_seconds": round(seconds, 1),
                "hparams": {**dict(spec.hparams), **hparams}, "protocol": "paper", "n_envs": spec.n_envs,
                "net_arch": list(spec.net_arch), "activation": spec.activation,
                "policy": f"MlpPolicy on the compact observation ({COMPACT_WIDTH} numbers, morality_gym.world.compact_observe)",
                "trained_steps": int(trained.trained_steps), **({"failed": failed[k]} if k in failed else {})}
        out[int(seed)] = (trained, info)
    return out
