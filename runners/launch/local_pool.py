"""A local pool of worker processes that survives the death of any of them.

``concurrent.futures.ProcessPoolExecutor`` gives up entirely when one worker is killed; a sweep
must instead record the runs it held as failed, start a replacement and carry on. Each worker is a
spawned process (torch is imported once per worker, not once per run) that executes one job at a
time (one run, or a fleet of runs trained together: :mod:`runners.execute.jobs`), reports each run as
soon as its result is written (so a worker killed late in a fleet's recording loses only the runs
not yet written), and
asks the kernel to kill it when the parent dies (``PR_SET_PDEATHSIG``), so ``kill -9`` of the
sweep leaves no orphan that could race a resumed sweep.

SIGTERM (to the sweep, or to its whole process group: ``timeout``, a SLURM time limit of a job
that runs the sweep) stops the pool cleanly: no new job starts, every worker ends as
:mod:`runners.execute.stopping` says (a fleet in training writes its checkpoint first), and :meth:`WorkerPool.run`
raises :class:`PoolStopped` with the runs it interrupted, none of them recorded as failed. A worker
that meets a full disk ends the same way and the pool raises its
:class:`~morality_gym.clitools.DiskFullError`: every other run would fail to be written too.
"""

from __future__ import annotations

import ctypes
import multiprocessing as mp
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

from morality_gym.baselines.device import CPU, Device
from morality_gym.baselines.specs import DEFAULT_UPDATE_ENGINE
from morality_gym.baselines.stopped import TrainingStopped
from morality_gym.clitools import DiskFullError
from morality_gym.results.recording import git_commit
from runners.execute import stopping
from runners.execute.run import limit_threads, training_code
from runners.launch.entry_points import training
from runners.plan.fleets import Job
from runners.plan.runs import PlannedRun

ResultHook = Callable[[PlannedRun, dict[str, Any]], None]


class JobProgress:
    """What the pool tells about jobs while they run (the default tells nothing): a fleet's training
    steps as it trains (``update``), and that a job is over (``end``)."""

    def update(self, job: Job, steps: int, total: int) -> None:
        """``job`` (a fleet) has trained ``steps`` of ``total`` steps per run."""

    def end(self, job: Job) -> None:
        """``job`` is over (all its runs reported, or its worker died)."""
_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except OSError:  # pragma: no cover - non-Linux
        pass


def _worker_main(conn: Connection, results_dir: str, gif: bool, parent_pid: int, device: Device = CPU,
                 checkpoint_every_s: float = 0.0, fleet_update: str = DEFAULT_UPDATE_ENGINE) -> None:
    _die_with_parent()
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle

    limit_threads()
    git_commit()  # the commit of the code this worker loads now, recorded for every run it trains
    training_code()  # and its fingerprint, which keys the fleet checkpoints it writes
    jobs = training()  # the training code (torch) loads here, before the first job

    stopping.install()  # SIGTERM: a fleet checkpoints and the worker ends (runners.execute.stopping)
    _send(conn, ("ready", os.getpid()))
    try:
        _serve(jobs.execute_job, conn, results_dir, gif, device, checkpoint_every_s, fleet_update)
    except TrainingStopped as exc:
        stopping.ignore()  # stopping already: a second signal has nothing left to stop
        _send(conn, ("stopped", str(exc)))
    except DiskFullError as exc:  # the sweep stops: writing more runs (or failed rows) would fail too
        stopping.ignore()  # the sweep's SIGTERM to its workers follows: this one is done already
        _send(conn, ("fatal", str(exc)))
    finally:
        stopping.ignore()  # nothing runs after this: a late SIGTERM must not raise while the process exits


def _serve(execute_job: Callable[..., Iterator[dict[str, Any]]], conn: Connection, results_dir: str, gif: bool,
           device: Device, checkpoint_every_s: float, fleet_update: str = DEFAULT_UPDATE_ENGINE) -> None:
    """Execute the jobs the parent sends (with :func:`runners.execute.jobs.execute_job`) until it sends
    None or goes away."""
    while True:
        try:
            message = conn.recv()
        except EOFError:
            return
        if message is None:
            return
        items, engine = message
        for summary in execute_job(items, results_dir, gif, engine, device, _throttled_progress(conn), checkpoint_every_s,
                                   fleet_update):
            _send(conn, ("done", summary))
        _send(conn, ("free", None))


def _send(conn: Connection, message: Any) -> None:
    """Send ``message`` whole: a stop signal waits until it is sent (a torn message would break the
    parent's pipe), and a parent already gone is no error of the worker's."""
    with stopping.signals_held():
        try:
            conn.send(message)
        except (BrokenPipeError, OSError):
            pass


def _throttled_progress(conn: Connection, every_s: float = 1.0) -> Callable[[int, int], None]:
    """A fleet's ``progress(steps, total)`` sent to the parent at most once per ``every_s`` (and at the end)."""
    last = [0.0]

    def send(steps: int, total: int) -> None:
        now = time.monotonic()
        if steps >= total or now - last[0] >= every_s:
            last[0] = now
            _send(conn, ("progress", (steps, total)))

    return send


@dataclass
class _Worker:
    process: Any
    conn: Connection
    job: Job | None = None
    pending: dict[str, PlannedRun] = field(default_factory=dict)  # the job's runs not reported yet
    stopped: bool = False  # it said it ends (a stop signal, a full disk)


#: Signals that stop a sweep cleanly (:class:`PoolStopped`); SIGINT stays Ctrl-C's KeyboardInterrupt.
_PARENT_STOP_SIGNALS = (signal.SIGTERM,)


class PoolStopped(Exception):
    """The pool stopped early on a signal: ``runs`` were interrupted (not failed, not recorded);
    fleets in training wrote their checkpoints, so the same sweep run again resumes them."""

    def __init__(self, reason: str, runs: list[PlannedRun], details: list[str] | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.runs = runs
        self.details = list(details or [])


class WorkerPool:
    """Run planned runs on ``n_workers`` processes; ``on_result`` is called in the parent."""

    def __init__(self, n_workers: int, results_dir: Path, gif: bool, device: Device = CPU, checkpoint_every_s: float = 0.0,
                 fleet_update: str = DEFAULT_UPDATE_ENGINE) -> None:
        self.n_workers = n_workers
        self.results_dir = str(results_dir)
        self.gif = gif
        self.device = device
        self.checkpoint_every_s = checkpoint_every_s  # how often fleets checkpoint their training (0: never)
        self.fleet_update = fleet_update  # the fleets' update engine (eager reruns the releases bit for bit)
        self._ctx = mp.get_context("spawn")
        self._workers: list[_Worker] = []

    def _start(self) -> _Worker:
        parent, child = self._ctx.Pipe()
        process = self._ctx.Process(
            target=_worker_main,
            args=(child, self.results_dir, self.gif, os.getpid(), self.device, self.checkpoint_every_s, self.fleet_update),
            daemon=True,
            name="morality-gym-worker"
        )
        process.start()
        child.close()
        return _Worker(process, parent)

    def run(
        self,
        jobs: list[Job],
        on_result: ResultHook,
        on_failure: Callable[[PlannedRun, str], None],
        progress: JobProgress | None = None,
    ) -> None:
        """Execute ``jobs``; a worker that dies takes only its job's unreported runs with it
        (``on_failure``); ``progress`` hears of fleets' training steps.

        One loop of three phases: hand queued jobs to ready idle workers, wait up to a second for
        any worker's pipe or death, then handle each event. The state of one ``run`` (the queue,
        the workers that said "ready", the hooks) lives on the pool for its duration so each
        phase is a method of its own."""
        self._queue: deque[Job] = deque(jobs)
        self._ready: set[int] = set()
        self._deferred_until = 0.0
        self._on_result, self._on_failure = on_result, on_failure
        self._progress = progress or JobProgress()
        self._stop: str | None = None  # why the pool stops early (a signal, a full disk)
        self._fatal: str | None = None
        self.interrupted: list[PlannedRun] = []
        self.details: list[str] = []  # each stopped worker's word (a fleet: where it stopped, its checkpoint)
        self._workers = [self._start() for _ in range(min(self.n_workers, max(1, len(jobs))))]
        main = threading.current_thread() is threading.main_thread()  # only the main thread may set handlers
        previous = {signum: signal.signal(signum, self._on_signal) for signum in _PARENT_STOP_SIGNALS} if main else {}
        try:
            while (self._workers if self._stop else (self._queue or self._busy())):
                self._dispatch()
                for obj in wait(self._waitables(), timeout=1.0):
                    self._handle(obj)
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)
            self.close()
        if self._fatal is not None:
            raise DiskFullError(self._fatal)
        if self._stop is not None:
            raise PoolStopped(self._stop, self.interrupted, self.details)

    def _on_signal(self, signum: int, _frame: Any) -> None:
        """SIGTERM to the sweep: no new job; each worker is told (if the signal did not reach its
        process group already), its fleet checkpoints and it ends; their runs are interrupted."""
        self._begin_stop(f"stopped by {signal.Signals(signum).name}")

    def _begin_stop(self, reason: str) -> None:
        if self._stop is not None:
            return
        self._stop = reason
        for w in self._workers:
            if w.process.pid is not None and w.process.is_alive():
                try:
                    os.kill(w.process.pid, signal.SIGTERM)
                except ProcessLookupError:
                    pass

    def _busy(self) -> bool:
        return any(w.job is not None for w in self._workers)

    def _dispatch(self) -> None:
        """Give the next queued job to each idle worker that has finished its imports, unless a
        busy run was just requeued (``_deferred_until``: retry it a second later, not at once)."""
        for w in self._workers:
            if self._stop is not None:
                return
            if w.job is None and self._queue and id(w) in self._ready and time.monotonic() >= self._deferred_until:
                w.job = self._queue.popleft()
                w.pending = {r.run_id: r for r in w.job.runs}
                w.conn.send((w.job.items, w.job.engine))

    def _waitables(self) -> list[Any]:
        waitables: list[Any] = []
        for w in self._workers:
            waitables += [w.conn, w.process.sentinel]
        return waitables

    def _handle(self, obj: Any) -> None:
        """One ready pipe or sentinel: a message from its worker, or the worker's death."""
        # A dead worker makes both its pipe and its sentinel ready; handle it once.
        worker = next((w for w in self._workers if obj in (w.conn, w.process.sentinel)), None)
        if worker is None:
            return
        message = self._receive(worker) if obj is worker.conn else None
        if message is None:
            self._bury(worker)
        elif message[0] == "ready":
            self._ready.add(id(worker))
        elif message[0] == "free":
            self._job_over(worker)
        elif message[0] == "progress":
            if worker.job is not None:
                self._progress.update(worker.job, *message[1])
        elif message[0] == "done":
            self._run_done(worker, message[1])
        elif message[0] in ("stopped", "fatal"):
            self._worker_stopped(worker, message)
        else:
            self._bury(worker)

    def _worker_stopped(self, worker: _Worker, message: tuple[str, str]) -> None:
        """The worker ends on a stop signal or a full disk: its unreported runs are interrupted,
        not failed (a full disk stops every worker: writing more would fail too)."""
        if message[0] == "fatal" and self._fatal is None:
            self._fatal = message[1]
        self._begin_stop(message[1])
        self.details.append(message[1])
        self.interrupted += list(worker.pending.values())
        worker.pending = {}
        worker.stopped = True

    @staticmethod
    def _receive(worker: _Worker) -> Any:
        """The worker's next message, or None when its pipe is closed (it died)."""
        try:
            return worker.conn.recv()
        except (EOFError, OSError):
            return None

    def _job_over(self, worker: _Worker) -> None:
        if worker.job is not None:
            self._progress.end(worker.job)
        worker.job, worker.pending = None, {}

    def _run_done(self, worker: _Worker, summary: dict[str, Any]) -> None:
        run = worker.pending.pop(summary["run_id"], None)
        if run is not None and summary["status"] == "busy":
            # another process holds the run: try it again later, on its own
            self._queue.append(Job((run,), "single", run.est_seconds))
            self._deferred_until = time.monotonic() + 1.0
        elif run is not None:
            self._on_result(run, summary)

    def _bury(self, worker: _Worker) -> None:
        """The worker died (killed, crashed, out of memory): fail its unreported runs, and start a
        replacement if there is work left."""
        worker.process.join(timeout=5)
        if worker.stopped or self._stop is not None:  # it ended as told: nothing failed, none replaces it
            self.interrupted += list(worker.pending.values())
            self._job_over(worker)
            self._workers.remove(worker)
            self._ready.discard(id(worker))
            return
        code = worker.process.exitcode
        reason = f"signal {-code}" if code is not None and code < 0 else f"exit code {code}"
        what = "this configuration" if worker.job is None or len(worker.job.runs) == 1 else \
            f"a fleet of {len(worker.job.runs)} runs including this configuration"
        for run in worker.pending.values():
            self._on_failure(run, f"worker process died ({reason}) while running {what}")
        self._job_over(worker)
        self._workers.remove(worker)
        self._ready.discard(id(worker))
        if self._queue or self._busy():
            self._workers.append(self._start())

    def close(self) -> None:
        for w in self._workers:
            try:
                w.conn.send(None)
            except (OSError, BrokenPipeError):
                pass
        deadline = time.monotonic() + 5
        for w in self._workers:
            w.process.join(timeout=max(0.0, deadline - time.monotonic()))
            if w.process.is_alive():
                w.process.kill()
                w.process.join(timeout=5)
        self._workers = []
