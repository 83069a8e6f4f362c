"""The sweep's unit of work: a *job* of one run (single engine) or of many runs trained as a fleet.

With ``engine=fleet`` (the default) the plan's runs are grouped into fleets: runs whose resolved
configurations differ only in env id (variant), chain and seed, on one scenario (on accelerators:
of any scenario of the same budget), of a learner the fleet engine reproduces
(:func:`morality_gym.baselines.fleet.fleet_class`), are trained together by
:mod:`morality_gym.baselines.fleet`, at most ``fleet_size`` at a time.
Everything else (Random, the oracle, a user's learner, a group of one) stays a single-run job.

Why per-run files stay exactly as before: a fleet only *trains*; every run is then evaluated,
saved, rendered and written by :func:`runners.execute.run.record_outcome`, the same function the single
engine uses, one run after the other, each Parquet row last. A fleet killed while training loses
the runs it had not finished; those, and only those, are planned again by the next sweep. Its
training is not lost with them: a fleet checkpoints its training in the results directory
(``checkpoint_every_s``, :mod:`runners.record.fleet_checkpoints`), the next sweep forms the same fleet
again (:func:`make_jobs`) and it resumes from the checkpoint, ending bit for bit where it would
have. Runs already finished by another process are skipped, and runs another process holds are
reported ``busy`` and retried, as single runs are.

The run id does not include the engine: the fleet reproduces each run's arithmetic to float
tolerance, not bit for bit (batched products may sum in another order), so a fleet run and a
single run of one id are two trainings of the same configuration, as two machines' would be. The
row's ``engine`` column (``single`` / ``fleet:K``) says which trained it.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

from morality_gym.baselines.device import CPU, Device
from morality_gym.baselines.specs import SpecError
from morality_gym.baselines.stopped import TrainingStopped
from morality_gym.results.recording import RunClock, RunLock, finished_status, git_commit
from morality_gym.results.run_config import RunConfig
from runners.compose.schema import ENGINES
from runners.execute import stopping
from runners.execute.run import execute_locked, limit_threads, record_outcome, training_code
from runners.plan.estimate import DeviceRate, DeviceWork, device_price, fleet_seconds
from runners.plan.runs import PlannedRun
from runners.record.fleet_checkpoints import fleet_to_train, remove_fleet, write_fleet_runs

#: Keys of a run config that may differ between the runs of one fleet (the rest must be equal).
FLEET_FREE_KEYS = ("env_id", "variant", "chain", "seed")
#: ... and with ``mix_scenarios``: a fleet pads observations of different widths (scenarios) to
#: one, each run's numbers unchanged bit for bit (tests/test_fleet_mixed.py).
MIXED_FREE_KEYS = (*FLEET_FREE_KEYS, "scenario")

Summary = dict[str, Any]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Job:
    """Runs executed together by one worker (one local process or one SLURM array task)."""

    runs: tuple[PlannedRun, ...]
    engine: str  # "single" (one run) | "fleet"
    est_seconds: float  # alone on the machine (and on the device): what longest-first orders by (runners.plan.estimate)
    device: DeviceWork | None = None  # a fleet training on an accelerator that other workers share

    @property
    def items(self) -> list[tuple[str, RunConfig]]:
        """``(run_id, config)`` of each run: what a worker receives (the resolved run, as it is)."""
        return [(r.run_id, r.config) for r in self.runs]


@cache
def fleet_trains(target: str) -> bool:
    """True if the fleet engine reproduces the learner class at ``target``."""
    # torch waits: importing runners.execute.jobs must not load it
    from morality_gym.baselines.fleet import fleet_class

    try:
        fleet_class(target)
    except (SpecError, ImportError, ValueError):
        return False
    return True


def _group_key(config: RunConfig, free: Sequence[str] = FLEET_FREE_KEYS) -> str:
    return json.dumps({k: v for k, v in config.to_json().items() if k not in free}, sort_keys=True)


def _split(runs: list[PlannedRun], parts: int) -> list[list[PlannedRun]]:
    """``runs`` in ``parts`` contiguous chunks whose sizes differ by at most one."""
    size, extra = divmod(len(runs), parts)
    out, start = [], 0
    for i in range(parts):
        end = start + size + (i < extra)
        out.append(runs[start:end])
        start = end
    return out


def make_jobs(
    runs: Sequence[PlannedRun],
    engine: str = "fleet",
    fleet_size: int = 36,
    workers: int = 1,
    speedups: Mapping[str, float] | None = None,
    checkpointed: Iterable[Sequence[str]] = (),
    mix_scenarios: bool = False,
    device_rates: Mapping[str, DeviceRate] | None = None,
) -> list[Job]:
    """The plan's runs as jobs, in plan order of each job's first run.

    ``mix_scenarios``: fleets may hold runs of different scenarios (of one budget). The sweep asks
    for it on accelerators, where a fleet's rate grows with its size (a process of 36 runs is
    bound by launching small kernels); on the CPU, where it does not, fleets keep to one scenario.

    Under ``fleet`` each group of fleet-compatible runs is cut into ``ceil(n / fleet_size)``
    balanced fleets; while there are fewer jobs than ``workers``, the largest fleet is cut again
    (down to fleets of 2), so that no worker idles while one trains everything. ``speedups`` maps
    an algo name to its measured fleet speed-up (``planning.fleet_speedup``) for the estimate
    (:func:`runners.plan.estimate.fleet_seconds`).

    ``checkpointed``: the run ids of fleets that have a training checkpoint
    (:func:`runners.record.fleet_checkpoints.checkpointed_fleets`). A fleet whose runs are all among one
    group's runs is formed again first, exactly (whatever ``fleet_size`` and ``workers`` say), so
    that it resumes its training instead of starting over; the rest of the group is cut as above.

    ``device_rates``: an algo name's measured fleet rate on the sweep's device
    (``planning.devices``); its fleets are priced at it (:func:`runners.plan.estimate.device_price`)
    instead of at the CPU rate and fleet speed-up.
    """
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    if fleet_size < 1:
        raise ValueError(f"fleet_size must be >= 1, got {fleet_size}")
    if engine == "single":
        return [_single(r) for r in runs]
    groups, order = _group(runs, MIXED_FREE_KEYS if mix_scenarios else FLEET_FREE_KEYS)
    kept = _take_checkpointed(groups, checkpointed)
    singles = sum(isinstance(item, PlannedRun) for item in order) + sum(len(fleets) for fleets in kept.values())
    parts = _parts({key: g for key, g in groups.items() if g}, fleet_size, workers, singles=singles)
    jobs = [job for item in order for job in _jobs_of(item, groups, kept, parts, speedups or {})]
    return [_priced_on_device(job, device_rates) for job in jobs] if device_rates else jobs


def _jobs_of(item: str | PlannedRun, groups: Mapping[str, list[PlannedRun]], kept: Mapping[str, list[list[PlannedRun]]],
             parts: Mapping[str, int], speedups: Mapping[str, float]) -> list[Job]:
    """The jobs of one item of the plan's order: a run alone, or a group's checkpointed fleets
    (formed again as they were) and then the rest of the group cut into ``parts[item]`` fleets."""
    if isinstance(item, PlannedRun):
        return [_single(item)]
    jobs = [_fleet_job(chunk, speedups) for chunk in kept.get(item, [])]
    if groups[item]:
        jobs += [_fleet_job(chunk, speedups) for chunk in _split(groups[item], parts[item])]
    return jobs


def _priced_on_device(job: Job, rates: Mapping[str, DeviceRate]) -> Job:
    """A fleet of a learner with a device rate, priced at it (:func:`runners.plan.estimate.device_price`);
    other jobs keep their price."""
    rate = rates.get(job.runs[0].config.algo.name)
    if job.engine != "fleet" or rate is None:
        return job
    return Job(job.runs, job.engine, *device_price(job.runs, rate))


def _take_checkpointed(groups: dict[str, list[PlannedRun]], checkpointed: Iterable[Sequence[str]]) -> dict[str, list[list[PlannedRun]]]:
    """Move each checkpointed fleet whose runs are all in one group (still to do) out of that
    group; returns the fleets per group key, their runs in plan order. Largest fleets first; a
    fleet that shares a run with one taken before it is left (its checkpoint cannot be used)."""
    kept: dict[str, list[list[PlannedRun]]] = {}
    for ids in sorted({tuple(sorted(c)) for c in checkpointed}, key=lambda c: (-len(c), c)):
        wanted = set(ids)
        if len(wanted) < 2:
            continue
        for key, group in groups.items():
            chosen = [r for r in group if r.run_id in wanted]
            if len(chosen) == len(wanted):
                kept.setdefault(key, []).append(chosen)
                groups[key] = [r for r in group if r.run_id not in wanted]
                break
    return kept


def _single(run: PlannedRun) -> Job:
    return Job((run,), "single", run.est_seconds)


def _group(runs: Sequence[PlannedRun], free: Sequence[str] = FLEET_FREE_KEYS) -> tuple[dict[str, list[PlannedRun]], list[str | PlannedRun]]:
    """The fleet-compatible runs grouped by :func:`_group_key`, and the plan's order of its items:
    a run that trains alone (no budget, or a learner the fleet engine does not reproduce), or the
    key of a group at the place of the group's first run."""
    groups: dict[str, list[PlannedRun]] = {}
    order: list[str | PlannedRun] = []
    for run in runs:
        c = run.config
        if c.budget <= 0 or not fleet_trains(c.algo.target):
            order.append(run)
            continue
        key = _group_key(c, free)
        if key not in groups:
            groups[key] = []
            order.append(key)
        groups[key].append(run)
    return groups, order


def _parts(groups: Mapping[str, list[PlannedRun]], fleet_size: int, workers: int, singles: int) -> dict[str, int]:
    """Into how many fleets each group is cut: ``ceil(n / fleet_size)``, then, while there are
    fewer jobs than ``workers``, one more for the group of the widest fleets (down to fleets of 2)."""
    parts = {key: max(1, math.ceil(len(g) / fleet_size)) for key, g in groups.items()}
    while singles + sum(parts.values()) < workers:
        splittable = [k for k, g in groups.items() if len(g) // (parts[k] + 1) >= 2]
        if not splittable:
            break
        widest = max(splittable, key=lambda k: len(groups[k]) / parts[k])
        parts[widest] += 1
    return parts


def _fleet_job(chunk: list[PlannedRun], speedups: Mapping[str, float]) -> Job:
    """One chunk of a group as a job: a fleet, or a single run when the chunk holds one."""
    if len(chunk) == 1:
        return _single(chunk[0])
    return Job(tuple(chunk), "fleet", fleet_seconds(chunk, float(speedups.get(chunk[0].config.algo.name, 1.0))))


# ---------------------------------------------------------------------------------------------- workers
def execute_job(
    items: Sequence[tuple[str, RunConfig]],
    results_dir: str | Path,
    gif: bool = True,
    engine: str = "single",
    device: Device = CPU,
    progress: Callable[[int, int], None] | None = None,
    checkpoint_every_s: float = 0.0,
) -> Iterator[Summary]:
    """Execute a job's runs, yielding each run's summary as soon as its result is written.

    Each run is locked first (a run another live process holds is yielded as ``busy``; one already
    finished ``ok`` as skipped); the rest are trained together when ``engine == "fleet"`` and more
    than one remains, else one by one. A fleet's networks and updates run on ``device``, it
    calls ``progress(steps, total)`` as it trains, and, with ``checkpoint_every_s > 0``, it
    checkpoints its training at most that often (and resumes from a checkpoint it finds).
    """
    git_commit()  # fixed before training: a SLURM task's job may outlast a commit (morality_gym.results.recording.git_commit)
    training_code()  # likewise: what a fleet checkpoint is keyed by
    results_dir = Path(results_dir)
    locks: list[RunLock] = []
    mine: list[tuple[str, RunConfig]] = []
    try:
        for run_id, config in items:
            lock = RunLock(results_dir, run_id)
            if not lock.acquire():
                yield {"run_id": run_id, "status": "busy"}
                continue
            locks.append(lock)
            if finished_status(results_dir, run_id) == "ok":
                yield {"run_id": run_id, "status": "ok", "skipped": True}
                continue
            mine.append((run_id, config))
        if engine == "fleet" and len(mine) > 1:
            yield from _train_fleet(mine, results_dir, gif, device, progress, checkpoint_every_s)
        else:
            for run_id, config in mine:
                yield execute_locked(config, run_id, results_dir, gif)
    finally:
        for lock in locks:
            lock.release()


def execute_job_all(
    items: Sequence[tuple[str, RunConfig]], results_dir: str, gif: bool = True, engine: str = "single", device: Device = CPU,
    checkpoint_every_s: float = 0.0,
) -> list[Summary]:
    """:func:`execute_job` as one list (what a SLURM array task returns to the parent).

    A SLURM task stops on SIGTERM or submitit's SIGUSR2 (time limit, preemption) as
    :mod:`runners.execute.stopping` says: a fleet writes its checkpoint; the runs not recorded are returned
    as ``interrupted`` (not failed), so the next sweep does them and the fleet resumes."""
    stopping.install()  # after submitit's own handlers (which ignore SIGTERM): ours win
    summaries: list[Summary] = []
    try:
        for summary in execute_job(items, results_dir, gif, engine, device, checkpoint_every_s=checkpoint_every_s):
            with stopping.signals_held():
                summaries.append(summary)
    except TrainingStopped as exc:
        done = {s["run_id"] for s in summaries}
        summaries += [interrupted(run_id, str(exc)) for run_id, _ in items if run_id not in done]
    return summaries


def interrupted(run_id: str, why: str) -> Summary:
    """The summary of a run that a stop signal kept from being recorded (done again by the next sweep)."""
    return {"run_id": run_id, "status": "interrupted", "error": why}


def _train_fleet(
    mine: list[tuple[str, RunConfig]],
    results_dir: Path,
    gif: bool,
    device: Device = CPU,
    progress: Callable[[int, int], None] | None = None,
    checkpoint_every_s: float = 0.0,
) -> Iterator[Summary]:
    """Train the locked runs ``mine`` as one fleet, then record them one after the other.

    With ``checkpoint_every_s > 0`` the training is checkpointed in the results directory
    (:class:`FleetTraining`), and the checkpoint is deleted once every run is recorded. A fleet
    killed while it recorded its runs is built again with all of its runs, to restore its
    checkpoint (:func:`runners.record.fleet_checkpoints.fleet_to_train`); only ``mine`` are recorded."""
    # torch waits: importing runners.execute.jobs must not load it
    from morality_gym.baselines.fleet import FleetRun, make_fleet

    limit_threads()
    clock = RunClock.start()
    ours = {run_id for run_id, _ in mine}
    trained = fleet_to_train(results_dir, mine) if checkpoint_every_s > 0 else mine
    engine = f"fleet:{len(trained)}"
    first = mine[0][1]
    try:
        device.usable()  # checked once on this machine, or here on a SLURM node (morality_gym.baselines.device)
    except SpecError as exc:  # e.g. a SLURM node without the GPU the submitting host had: a failure, not a silent CPU run
        yield from _all_failed(mine, results_dir, gif, clock, engine, exc)
        return
    try:
        spec, protocol = first.algo, first.protocol  # resolved: the fleet applies nothing again
        fleet = make_fleet(spec, [FleetRun(c.bound_chain(), c.seed) for _, c in trained], protocol, max_steps=first.max_steps,
                           device=device.name)
    except SpecError:
        # A setting the fleet does not reproduce (e.g. a learner option it has no batched form
        # of): the runs are trained one by one, as the single engine would.
        for run_id, config in mine:
            yield execute_locked(config, run_id, results_dir, gif)
        return
    except Exception as exc:  # noqa: BLE001 - recorded for every run of the fleet
        yield from _all_failed(mine, results_dir, gif, clock, engine, exc)
        return
    training = FleetTraining(trained, clock)
    checkpoint = training.checkpoint(results_dir, spec, protocol, device, checkpoint_every_s) if checkpoint_every_s > 0 else None
    try:
        with stopping.stop_at_update(checkpoint):  # a SIGTERM checkpoints at the next update, then stops
            fleet.learn(
                first.budget,
                eval_every=first.learn_eval_every,
                eval_episodes=first.learn_eval_episodes,
                on_eval=lambda k, row: training.learn_rows[k].append(row),
                on_progress=progress,
                checkpoint=checkpoint,
            )
    except Exception as exc:  # noqa: BLE001 - TrainingStopped is no Exception: it passes, the runs are not failed
        yield from _all_failed(mine, results_dir, gif, training.clock, engine, exc)
        return
    yield from _record_trained(fleet, training, ours, results_dir, gif, engine)
    if checkpoint is not None:
        remove_fleet(checkpoint.path)


def _all_failed(mine: Sequence[tuple[str, RunConfig]], results_dir: Path, gif: bool, clock: RunClock, engine: str,
                error: BaseException) -> Iterator[Summary]:
    """Every run of ``mine`` recorded as failed with ``error`` (the fleet could not train them)."""
    for run_id, config in mine:
        yield record_outcome(config, run_id, results_dir, gif, None, [], clock, engine=engine, error=error)


def _record_trained(fleet: Any, training: FleetTraining, ours: set[str], results_dir: Path, gif: bool,
                    engine: str) -> Iterator[Summary]:
    """Record each of ``ours`` among the fleet's trained runs, one after the other.

    Each run's wall and CPU time is its share of the fleet's training (before a resume too) plus
    its own evaluation and writes, so that summing them over runs still gives what the fleet spent."""
    # torch waits: importing runners.execute.jobs must not load it
    from morality_gym.baselines.fleet.state import NonFiniteTraining

    trained = training.runs
    wall, cpu = training.clock.elapsed()  # since the fleet began, before a resume too
    for k, learner in enumerate(fleet.learners()):
        run_id, config = trained[k]
        if run_id not in ours:  # recorded before a kill
            continue
        own = RunClock.already_spent(training.clock.started, wall / len(trained), cpu / len(trained))
        if k in fleet.failed:  # went non-finite: this run fails with its own error, the others are recorded
            yield record_outcome(config, run_id, results_dir, gif, None, [], own, engine=engine,
                                 error=NonFiniteTraining(fleet.failed[k]))
            continue
        yield record_outcome(config, run_id, results_dir, gif, learner, training.learn_rows[k], own, engine=engine)


class FleetTraining:
    """What the sweep keeps of a fleet's training besides the fleet: each run's learn-time
    evaluation rows and the time spent, which a checkpoint carries across a kill (its ``extra``
    data), so that a resumed fleet records every row and the whole time it trained."""

    def __init__(self, runs: Sequence[tuple[str, RunConfig]], clock: RunClock) -> None:
        self.runs = list(runs)
        self.run_ids = [run_id for run_id, _ in runs]
        self.clock = clock
        self.learn_rows: list[list[dict[str, Any]]] = [[] for _ in runs]

    def checkpoint(self, results_dir: Path, spec: Any, protocol: Any, device: Device, every_s: float) -> Any:
        """The fleet's checkpoint in ``results_dir`` (:mod:`runners.record.fleet_checkpoints`), keyed by
        the runs, the learner, protocol and device, and the fingerprint of the training code
        (:func:`runners.execute.run.training_code`; None,
        with a warning, when the directory cannot be written)."""
        # torch waits: importing runners.execute.jobs must not load it
        from morality_gym.baselines.fleet import FleetCheckpoint

        key = {"runs": sorted(self.run_ids), "learner": spec.name, "protocol": protocol.name, "device": device.name,
               "fleet_size": len(self.run_ids), "code": training_code()}
        try:
            path = write_fleet_runs(results_dir, self.runs)
        except OSError as exc:  # e.g. a full disk: train without checkpoints rather than not at all
            log.warning("fleet of %d runs trains without checkpoints: %s", len(self.runs), exc)
            return None
        return FleetCheckpoint(path, every_s=every_s, key=key, extra=self._extra, on_resume=self._resume)

    def _extra(self) -> dict[str, Any]:
        wall, cpu = self.clock.elapsed()
        return {"learn_rows": self.learn_rows, "started": self.clock.started, "wall_s": wall, "cpu_s": cpu}

    def _resume(self, steps: int, extra: Any) -> None:
        """Take back the rows and the time of the training before the checkpoint."""
        self.learn_rows = [list(rows) for rows in extra["learn_rows"]]
        self.clock = RunClock.already_spent(str(extra["started"]), float(extra["wall_s"]), float(extra["cpu_s"]))

