"""A local pool of worker processes that survives the death of any of them.

``concurrent.futures.ProcessPoolExecutor`` gives up entirely when one worker is killed; a sweep
must instead record the runs it held as failed, start a replacement and carry on. Each worker is a
spawned process (torch is imported once per worker, not once per run) that executes one job at a
time (one run, or a fleet of runs trained together: :mod:`runners.jobs`), reports each run as
soon as its result is written (so a worker killed late in a fleet's recording loses only the runs
not yet written), and
asks the kernel to kill it when the parent dies (``PR_SET_PDEATHSIG``), so ``kill -9`` of the
sweep leaves no orphan that could race a resumed sweep.
"""

from __future__ import annotations

import ctypes
import multiprocessing as mp
import os
import signal
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

from runners.execute import git_commit, limit_threads, training_code
from runners.jobs import Job, execute_job
from runners.plan import PlannedRun

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


def _worker_main(conn: Connection, results_dir: str, gif: bool, parent_pid: int, device: str = "cpu",
                 checkpoint_every_s: float = 0.0) -> None:
    _die_with_parent()
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle

    limit_threads()
    git_commit()  # the commit of the code this worker loads now, recorded for every run it trains
    training_code()  # and its fingerprint, which keys the fleet checkpoints it writes
    import stable_baselines3  # noqa: F401

    import morality_gym  # noqa: F401 - warm imports before the first run

    conn.send(("ready", os.getpid()))
    while True:
        try:
            message = conn.recv()
        except EOFError:
            return
        if message is None:
            return
        items, engine = message
        for summary in execute_job(items, results_dir, gif, engine, device, _throttled_progress(conn), checkpoint_every_s):
            conn.send(("done", summary))
        conn.send(("free", None))


def _throttled_progress(conn: Connection, every_s: float = 1.0) -> Callable[[int, int], None]:
    """A fleet's ``progress(steps, total)`` sent to the parent at most once per ``every_s`` (and at the end)."""
    last = [0.0]

    def send(steps: int, total: int) -> None:
        now = time.monotonic()
        if steps >= total or now - last[0] >= every_s:
            last[0] = now
            conn.send(("progress", (steps, total)))

    return send


@dataclass
class _Worker:
    process: Any
    conn: Connection
    job: Job | None = None
    pending: dict[str, PlannedRun] = field(default_factory=dict)  # the job's runs not reported yet


class WorkerPool:
    """Run planned runs on ``n_workers`` processes; ``on_result`` is called in the parent."""

    def __init__(self, n_workers: int, results_dir: Path, gif: bool, device: str = "cpu", checkpoint_every_s: float = 0.0) -> None:
        self.n_workers = n_workers
        self.results_dir = str(results_dir)
        self.gif = gif
        self.device = device
        self.checkpoint_every_s = checkpoint_every_s  # how often fleets checkpoint their training (0: never)
        self._ctx = mp.get_context("spawn")
        self._workers: list[_Worker] = []

    def _start(self) -> _Worker:
        parent, child = self._ctx.Pipe()
        process = self._ctx.Process(
            target=_worker_main, args=(child, self.results_dir, self.gif, os.getpid(), self.device, self.checkpoint_every_s),
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
        self._workers = [self._start() for _ in range(min(self.n_workers, max(1, len(jobs))))]
        try:
            while self._queue or self._busy():
                self._dispatch()
                for obj in wait(self._waitables(), timeout=1.0):
                    self._handle(obj)
        finally:
            self.close()

    def _busy(self) -> bool:
        return any(w.job is not None for w in self._workers)

    def _dispatch(self) -> None:
        """Give the next queued job to each idle worker that has finished its imports, unless a
        busy run was just requeued (``_deferred_until``: retry it a second later, not at once)."""
        for w in self._workers:
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
        else:
            self._bury(worker)

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
