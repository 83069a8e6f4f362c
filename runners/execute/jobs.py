"""A job executed in a worker: its runs locked, trained (one by one, or together as one fleet) and recorded.

The jobs are cut by :mod:`runners.plan.fleets`; this module trains them, so it imports the fleet
engine (torch) at its top, and only a worker process imports it (the sweep's own process, which
plans and waits, names it: :mod:`runners.launch.entry_points`).

Why per-run files stay exactly as before: a fleet only *trains*; every run is then evaluated,
saved, rendered and written by :func:`runners.execute.run.record_outcome`, the same function the single
engine uses, one run after the other, each Parquet row last. A fleet killed while training loses
the runs it had not finished; those, and only those, are planned again by the next sweep. Its
training is not lost with them: a fleet checkpoints its training in the results directory
(``checkpoint_every_s``, :mod:`runners.record.fleet_checkpoints`), the next sweep forms the same fleet
again (:func:`runners.plan.fleets.make_jobs`) and it resumes from the checkpoint, ending bit for bit where it would
have. Runs already finished by another process are skipped, and runs another process holds are
reported ``busy`` and retried, as single runs are.

The run id does not include the engine: the fleet reproduces each run's arithmetic to float
tolerance, not bit for bit (batched products may sum in another order), so a fleet run and a
single run of one id are two trainings of the same configuration, as two machines' would be. The
row's ``engine`` column (``single`` / ``fleet:K``) says which trained it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from morality_gym.baselines.device import CPU, Device
from morality_gym.baselines.fleet import FleetCheckpoint, FleetRun, make_fleet
from morality_gym.baselines.fleet.state import NonFiniteTraining
from morality_gym.baselines.specs import DEFAULT_UPDATE_ENGINE, SpecError
from morality_gym.baselines.stopped import TrainingStopped
from morality_gym.results.recording import RunClock, RunLock, finished_status, git_commit
from morality_gym.results.run_config import RunConfig
from runners.execute import stopping
from runners.execute.run import execute_locked, limit_threads, record_outcome, training_code
from runners.record.fleet_checkpoints import fleet_to_train, remove_fleet, write_fleet_runs

Summary = dict[str, Any]

log = logging.getLogger(__name__)


def execute_job(
    items: Sequence[tuple[str, RunConfig]],
    results_dir: str | Path,
    gif: bool = True,
    engine: str = "single",
    device: Device = CPU,
    progress: Callable[[int, int], None] | None = None,
    checkpoint_every_s: float = 0.0,
    update: str = DEFAULT_UPDATE_ENGINE,
) -> Iterator[Summary]:
    """Execute a job's runs, yielding each run's summary as soon as its result is written.

    Each run is locked first (a run another live process holds is yielded as ``busy``; one already
    finished ``ok`` as skipped); the rest are trained together when ``engine == "fleet"`` and more
    than one remains, else one by one. A fleet's networks and updates run on ``device``, with the
    update engine ``update`` (``eager`` reruns the releases bit for bit; docs/engines.md), it
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
            yield from _train_fleet(mine, results_dir, gif, device, progress, checkpoint_every_s, update)
        else:
            for run_id, config in mine:
                yield execute_locked(config, run_id, results_dir, gif)
    finally:
        for lock in locks:
            lock.release()


def execute_job_all(
    items: Sequence[tuple[str, RunConfig]], results_dir: str, gif: bool = True, engine: str = "single", device: Device = CPU,
    checkpoint_every_s: float = 0.0, update: str = DEFAULT_UPDATE_ENGINE,
) -> list[Summary]:
    """:func:`execute_job` as one list (what a SLURM array task returns to the parent).

    A SLURM task stops on SIGTERM or submitit's SIGUSR2 (time limit, preemption) as
    :mod:`runners.execute.stopping` says: a fleet writes its checkpoint; the runs not recorded are returned
    as ``interrupted`` (not failed), so the next sweep does them and the fleet resumes."""
    stopping.install()  # after submitit's own handlers (which ignore SIGTERM): ours win
    summaries: list[Summary] = []
    try:
        for summary in execute_job(items, results_dir, gif, engine, device, checkpoint_every_s=checkpoint_every_s,
                                   update=update):
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
    update: str = DEFAULT_UPDATE_ENGINE,
) -> Iterator[Summary]:
    """Train the locked runs ``mine`` as one fleet, then record them one after the other.

    With ``checkpoint_every_s > 0`` the training is checkpointed in the results directory
    (:class:`FleetTraining`), and the checkpoint is deleted once every run is recorded. A fleet
    killed while it recorded its runs is built again with all of its runs, to restore its
    checkpoint (:func:`runners.record.fleet_checkpoints.fleet_to_train`); only ``mine`` are recorded."""
    limit_threads()
    clock = RunClock.start()
    ours = {run_id for run_id, _ in mine}
    trained = fleet_to_train(results_dir, mine) if checkpoint_every_s > 0 else mine
    engine = f"fleet:{len(trained)}"
    first = mine[0][1]
    try:
        device = device.checked(here=True)  # checked once on this machine, or here on a SLURM node; the fleet takes it as it is
    except SpecError as exc:  # e.g. a SLURM node without the GPU the submitting host had: a failure, not a silent CPU run
        yield from _all_failed(mine, results_dir, gif, clock, engine, exc)
        return
    try:
        spec, protocol = first.algo, first.protocol  # resolved: the fleet applies nothing again
        fleet = make_fleet(spec, [FleetRun(c.bound_chain(), c.seed) for _, c in trained], protocol, max_steps=first.max_steps,
                           device=device, update=update)
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
    checkpoint = training.checkpoint(results_dir, spec, protocol, device, checkpoint_every_s, update) if checkpoint_every_s > 0 else None
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

    def checkpoint(self, results_dir: Path, spec: Any, protocol: Any, device: Device, every_s: float,
                   update: str = DEFAULT_UPDATE_ENGINE) -> FleetCheckpoint | None:
        """The fleet's checkpoint in ``results_dir`` (:mod:`runners.record.fleet_checkpoints`), keyed by
        the runs, the learner, protocol and device (and the update engine, when not the default), and the fingerprint of the training code
        (:func:`runners.execute.run.training_code`; None,
        with a warning, when the directory cannot be written)."""
        key = {"runs": sorted(self.run_ids), "learner": spec.name, "protocol": protocol.name, "device": device.name,
               "fleet_size": len(self.run_ids), "code": training_code()}
        if update != DEFAULT_UPDATE_ENGINE:  # as the fleet's own state says it: eager keys stay those of the releases
            key["update"] = update
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

