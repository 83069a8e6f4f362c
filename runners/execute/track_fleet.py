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
Progress: one line at most every :data:`PROGRESS_EVERY_S` seconds. SIGTERM (a machine or session
that stops, ``kill``) ends a fleet at its next update boundary with its state written
(:mod:`runners.execute.stopping`), so a resume loses nothing, rather than up to 5 minutes of every run.

A session's fleet reads its pool's simulator tables from ``$MORALITY_GYM_CACHE/tables``
(:func:`~morality_gym.generalisation.sets.table_cache_dir`, :mod:`morality_gym.envs.table_cache`) instead of enumerating the pool's
graphs again: the Utility train pool's fleet starts in about 15 s instead of minutes. The first
session writes them; what is read is verified, and the tables are the same bits (tested).

Learning curves (issue 44 item 4: a budget is chosen where the curve on seen dilemmas flattens, so
the release's own runs must show it): every ``curve_every`` env steps per run (at the first update
boundary at or after each multiple, at step 0 and at the end) every run's current policy is scored
exactly on the track's ``seen`` set, and ``DIR/curves/<run prefix>-<learner>.csv`` is rewritten with
all points so far (:data:`CURVE_FIELDS`). The points ride in the fleet checkpoint, so a resumed fleet
continues its curve instead of losing or repeating points; scoring is exact and reads no random
stream, so a run's bits do not depend on whether its curve is recorded (tested).
"""

from __future__ import annotations

import csv
import io
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from morality_gym.baselines.device import CPU, Device
from morality_gym.baselines.fleet import FleetCheckpoint, FleetRun, build_fleet
from morality_gym.baselines.specs import learner_spec
from morality_gym.clitools import write_atomically
from morality_gym.constants import MAX_STEPS
from morality_gym.generalisation.scoring import score_set
from morality_gym.generalisation.sets import EvalSet
from morality_gym.norms.metric import bind_chain
from morality_gym.world.compact_observe import COMPACT_WIDTH
from runners.execute import stopping

CHECKPOINT_EVERY_S = 300.0
PROGRESS_EVERY_S = 30.0
#: Env steps per run between two points of a learning curve: 20 points over the release's 10M
#: budget; each point costs an exact scoring of the seen set per run (a few seconds each).
CURVE_EVERY = 500_000
CURVE_FIELDS = ("learner", "chain", "seed", "steps", "mean_range_score", "cpu_seconds")


@dataclass
class CurveRecorder:
    """A fleet's learning curves on the seen set, kept across checkpoints (module docstring).

    ``cpu_seconds`` is the process time spent on this fleet (training and scoring) up to the point,
    summed over resumed sessions, so the curve also says what each step of budget cost."""

    path: Path
    learner: str
    chain: str
    seeds: Sequence[int]
    seen: EvalSet
    every: int = CURVE_EVERY
    rows: list[dict[str, Any]] = field(default_factory=list)
    _next: int = field(default=0, init=False)
    _cpu_before: float = field(default=0.0, init=False)  # CPU-s of earlier sessions
    _cpu_start: float = field(default_factory=time.process_time, init=False)

    def __post_init__(self) -> None:
        if self.every <= 0:
            raise ValueError(f"curve_every must be positive, got {self.every}")

    def cpu_seconds(self) -> float:
        return self._cpu_before + time.process_time() - self._cpu_start

    def due(self, steps: int) -> bool:
        return steps >= self._next

    def record(self, fleet: Any, steps: int) -> None:
        """Score every run's current policy on the seen set and rewrite the CSV."""
        for k, (seed, trained) in enumerate(zip(self.seeds, fleet.learners())):
            fleet.nets.export_run(k, trained.model.policy)
            scores = [row["range_score"] for row in score_set(trained.model, self.seen)]
            self.rows = [r for r in self.rows if (r["seed"], r["steps"]) != (int(seed), steps)]
            self.rows.append({"learner": self.learner, "chain": self.chain, "seed": int(seed), "steps": int(steps),
                              "mean_range_score": round(sum(scores) / len(scores), 4),
                              "cpu_seconds": round(self.cpu_seconds(), 1)})
        while self._next <= steps:
            self._next += self.every
        self.write()

    def write(self) -> None:
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=CURVE_FIELDS, lineterminator="\n")
        writer.writeheader()
        writer.writerows(sorted(self.rows, key=lambda r: (r["seed"], r["steps"])))
        write_atomically(self.path, lambda fh: fh.write(text.getvalue().encode()))

    def state(self) -> dict[str, Any]:
        """What the fleet checkpoint keeps of the curve."""
        return {"rows": self.rows, "next": self._next, "cpu_seconds": self.cpu_seconds()}

    def resume(self, steps: int, extra: Any) -> None:
        """Take the curve back from a restored checkpoint (points after ``steps`` are dropped: they
        are retaken, identically, when training reaches them again)."""
        state = (extra or {}).get("curve") if isinstance(extra, dict) else None
        if not isinstance(state, dict):
            return
        self.rows = [dict(r) for r in state.get("rows", []) if int(r["steps"]) <= steps]
        self._next = int(state.get("next", 0))
        self._cpu_before = float(state.get("cpu_seconds", 0.0))
        self._cpu_start = time.process_time()
        self.write()  # the file held only the step-0 point retaken before the restore


def fleet_key(learner: str, seeds: Sequence[int], budget: int, train_ids: Sequence[str], chain: str,
              train_digest: str, device: Device = CPU) -> dict[str, Any]:
    """What a fleet checkpoint of the track is for (another command's file is discarded). A fleet on
    a GPU rounds differently, so its checkpoint is not resumed on the CPU nor the reverse; the CPU's
    key carries no device, as before devices were asked for (its checkpoints stay resumable)."""
    return {"track": "generalisation", "learner": learner, "seeds": [int(s) for s in seeds], "budget": int(budget),
            "chain": chain, "train_digest": train_digest, "pool": len(train_ids),
            **({} if device.on_cpu else {"device": device.name})}


def train_fleet(learner: str, seeds: Sequence[int], budget: int, train_ids: Sequence[str], chain: str,
                checkpoint: Path, key: dict[str, Any], say: Callable[[str], None] = print,
                curve: CurveRecorder | None = None, device: Device = CPU,
                table_cache: Path | None = None) -> dict[int, tuple[Any, dict[str, Any]]]:
    """Train ``learner`` on the chain's mixture for every seed in one fleet; returns each seed's
    trained SB3 learner and what its result records. ``curve``: record its learning curves.
    ``device``: where the networks train (the mixture's tables stay on the host), as the command
    checked it once (:class:`~morality_gym.baselines.device.Device`). ``table_cache``:
    where the pool's tables are kept between sessions (:func:`~morality_gym.generalisation.sets.table_cache_dir`)."""
    spec = learner_spec(learner)
    pool = [bind_chain(chain, env_id) for env_id in train_ids]
    t0 = time.perf_counter()
    fleet = build_fleet(spec, [FleetRun.mixture(pool, seed) for seed in seeds], protocol="paper", max_steps=MAX_STEPS,
                        device=device, table_cache=table_cache)
    say(f"{chain} {learner}: fleet of {len(seeds)} runs on {len(pool)} dilemmas built in {time.perf_counter() - t0:.0f} s")
    last = [time.perf_counter(), 0]

    def progress(steps: int, total: int) -> None:
        if curve is not None and (curve.due(steps) or steps >= total):
            curve.record(fleet, steps)
        now = time.perf_counter()
        if now - last[0] >= PROGRESS_EVERY_S or steps >= total:
            rate = (steps - last[1]) * len(seeds) / max(now - last[0], 1e-9)
            say(f"{chain} {learner}: {steps:,} of {total:,} steps per run ({100 * steps / total:.0f} %), "
                f"{rate:,.0f} env steps/s over the fleet")
            last[:] = [now, steps]

    t1 = time.perf_counter()
    saved = FleetCheckpoint(checkpoint, every_s=CHECKPOINT_EVERY_S, key=key)
    if curve is not None:
        curve.record(fleet, 0)  # the untrained policies; a resumed fleet's stored curve replaces this
        saved.extra = lambda: {"curve": curve.state()}
        saved.on_resume = curve.resume
    with stopping.stop_at_update(saved):  # a SIGTERM (once installed) writes the state at the next update, then stops
        fleet.learn(budget, on_progress=progress, checkpoint=saved)
    seconds = time.perf_counter() - t1
    failed = fleet.failed
    out: dict[int, tuple[Any, dict[str, Any]]] = {}
    model = fleet.model
    hparams = {name: getattr(model, name) for name in ("n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda")
               if isinstance(getattr(model, name, None), (int, float))}
    for k, (seed, trained) in enumerate(zip(seeds, fleet.learners())):
        info = {"engine": "fleet", "fleet_runs": len(seeds), "fleet_seconds": round(seconds, 1),
                "hparams": {**dict(spec.hparams), **hparams}, "protocol": "paper", "n_envs": spec.n_envs,
                "device": device.name,
                "net_arch": list(spec.net_arch), "activation": spec.activation,
                "policy": f"MlpPolicy on the compact observation ({COMPACT_WIDTH} numbers, morality_gym.world.compact_observe)",
                "trained_steps": int(trained.trained_steps), **({"failed": failed[k]} if k in failed else {})}
        out[int(seed)] = (trained, info)
    return out
