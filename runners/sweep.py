"""``python -m runners.sweep algo=cpo chain=utility``: compose, validate, plan, dispatch, record.

The path of a sweep, from the command line to its first run (docs/architecture.md):

1. :func:`main` reads the command line once (:func:`runners.compose.command_line.parse_command_line`):
   Hydra-style flags and ``key=value`` overrides. :func:`runners.compose.command_line.prepare_overrides` adds
   the installed plugins' config packages to the search path, rewrites user scenarios and chain
   files into options Hydra can compose (:mod:`runners.compose.options`) and checks group options and
   hyper-parameter names, naming the closest valid ones (:func:`runners.compose.command_line.precheck`).
2. :func:`runners.compose.command_line.compose_sweep` composes ``conf/`` once, with Hydra's compose API; :func:`runners.compose.sweep_config.validate`
   resolves it into a typed :class:`~runners.compose.sweep_config.SweepConfig`, and :func:`runners.launch.preflight.preflight`
   checks the machine (results directory, MLflow, SLURM) before anything is written.
3. :func:`make_plan` expands chain x scenario x variant x algorithm x seed into a :class:`Plan`:
   the runs, which are finished (their Parquet file exists with status ``ok``; failed ones are
   retried unless ``retry_failed=false``), the jobs that do the rest and an estimate of the
   time. :func:`print_plan` shows it and :func:`record_plan` writes the sweep manifest (what
   should exist when it is done); ``dry_run=true`` lists the runs (:func:`print_dry_run`) and stops
   without writing anything (``plan_file=PATH``: the plan as JSON there).
4. :func:`dispatch` sends the jobs to the local pool or SLURM; each finished run is mirrored into
   MLflow by this process, and anything left unmirrored by an earlier, interrupted sweep is
   mirrored at the end (:func:`mirror_finished`). :func:`report` prints the outcome.

Exit status: 0 if every planned run is ``ok``, 1 if some failed (they are listed), 2 for an
invalid configuration or another user error (one line; ``--debug`` or ``MORALITY_GYM_DEBUG=1``
shows the traceback). Killing the sweep at any point and running it again finishes it with no
lost and no duplicated results; an unreadable result file is moved aside and its run done again
(:mod:`morality_gym.results.quarantine`); two sweeps on one directory share it safely (per-run locks, and one
MLflow writer at a time).

Flags (read by :mod:`runners.compose.command_line`). The configuration is composed with Hydra's compose API,
not run as a ``@hydra.main`` application, so the flags are this command's own, spelt as Hydra spells them: ``--config-dir``/``-cd``,
``--config-name``/``-cn``, ``--cfg``/``-c`` ``job|hydra|all`` (with ``--resolve`` and
``--package``/``-p``: print the composed configuration and run nothing), ``--info``/``-i``
``searchpath|config``, ``--multirun``/``-m`` (one sweep per combination of comma-separated
values, ``algo=random,ppo``: each is checked before the first runs), ``--run``/``-r`` (the default),
``--help``/``-h``, ``--version`` and ``--debug``. Hydra's ``--hydra-help``, ``--shell-completion``,
``--config-path`` and ``--experimental-rerun`` and ``--info`` ``defaults|defaults-tree|plugins``
no longer apply (an unknown flag is a one-line error, exit 2). ``hydra.*`` overrides are still
composed (``hydra/job_logging``, ``hydra.verbose`` configure logging as before), but nothing is
written under ``hydra.run.dir`` or ``hydra.sweep.dir``: the configuration never wrote a file
there (``hydra.output_subdir: null``), so the only change is that a ``--multirun`` sweep no longer
leaves an empty ``multirun/`` directory behind.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import hydra
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from morality_gym.baselines.specs import DEFAULT_UPDATE_ENGINE, fleet_trains
from morality_gym.baselines.targets import learner_trains
from morality_gym.clitools import DEBUG_ENV, debug_enabled, duration, one_line, run_cli, version_text
from morality_gym.norms.chain import ChainError
from morality_gym.results.manifest import manifest_body, manifest_name, write_manifest
from morality_gym.results.quarantine import Quarantined, check_run_files, read_table_or_quarantine
from morality_gym.results.recording import finished_status
from morality_gym.results.schema import run_path
from runners.compose.command_line import (
    CommandLineError,
    load_sweeps,
    parse_command_line,
    prepare_overrides,
    show,
)
from runners.compose.sweep_config import ConfigError, SweepConfig  # also stores the schemas (runners.compose.schema)
from runners.execute.run import record_failure
from runners.launch.local_pool import JobProgress, PoolStopped, WorkerPool
from runners.launch.preflight import preflight
from runners.launch.slurm import run_on_slurm
from runners.launch.slurm_controller import SlurmUnavailable
from runners.plan.estimate import (
    Estimate,
    MachineLoad,
    device_estimate_note,
    device_rates,
    dispatch_order,
    jobs_estimate,
    sweep_overheads,
)
from runners.plan.fleets import Job, make_jobs
from runners.plan.runs import PlannedRun, describe, expand_sweep
from runners.record.fleet_checkpoints import fleets_to_form, remove_stale
from runners.record.leftovers import remove_leftovers
from runners.record.mlflow_mirror import Tracker, TrackingError


# ---------------------------------------------------------------------------------------- the plan
def _workers(sweep: SweepConfig) -> int:
    if sweep.launcher["name"] == "slurm":
        return int(sweep.launcher["array_parallelism"])
    return int(sweep.launcher.get("workers") or len(os.sched_getaffinity(0)) or 1)


@dataclass(frozen=True)
class Plan:
    """A sweep's runs and what is left of them, as a value: printed, recorded and dispatched.

    ``status``: each run's result before the sweep (``ok``, ``failed`` or None); ``todo``: the runs
    to train, cut into ``jobs`` for ``workers`` parallel workers (:mod:`runners.plan.fleets`); ``counts``:
    :func:`runners.plan.runs.describe`'s totals per learner; ``estimate_s``: the wall time of what
    remains on an idle machine, and ``estimate`` the same at the machine's load when the plan was
    made (:mod:`runners.plan.estimate`); ``moved``: unreadable result files moved aside while the plan was made.
    """

    runs: tuple[PlannedRun, ...]
    status: Mapping[str, str | None]
    todo: tuple[PlannedRun, ...]
    jobs: tuple[Job, ...]
    workers: int
    counts: Mapping[str, Any]
    estimate_s: float
    moved: tuple[Quarantined, ...] = ()
    checkpointed: tuple[tuple[str, ...], ...] = ()  # run ids of fleets formed again to resume from a checkpoint
    estimate: Estimate | None = None

    @property
    def resuming(self) -> tuple[Job, ...]:
        """The fleets that resume their training from a checkpoint (:mod:`runners.record.fleet_checkpoints`)."""
        sets = {frozenset(ids) for ids in self.checkpointed}
        return tuple(j for j in self.fleets if frozenset(r.run_id for r in j.runs) in sets)

    @property
    def fleets(self) -> tuple[Job, ...]:
        """The jobs that train several runs together."""
        return tuple(j for j in self.jobs if j.engine == "fleet")


def make_plan(sweep: SweepConfig) -> Plan:
    """Expand the sweep into runs, learn which are finished (moving unreadable files aside) and cut
    the rest into jobs, longest first."""
    runs = expand_sweep(sweep)
    if sweep.dry_run:  # reads what exists, writes nothing: no directory, no file moved aside
        moved = []
    else:
        sweep.results_dir.mkdir(parents=True, exist_ok=True)
        moved = check_run_files(sweep.results_dir, [r.run_id for r in runs])
    status = {r.run_id: finished_status(sweep.results_dir, r.run_id) for r in runs}
    done = {rid for rid, s in status.items() if s == "ok" or (s == "failed" and not sweep.retry_failed)}
    workers = _workers(sweep)
    todo = [r for r in runs if r.run_id not in done]
    # fleets with a training checkpoint are formed again, to resume (runners.record.fleet_checkpoints)
    checkpointed = fleets_to_form(sweep.results_dir, [r.run_id for r in todo]) if sweep.checkpoint_every_s > 0 else []
    jobs = dispatch_order(make_jobs(todo, sweep.engine, sweep.fleet_size, workers,
                                    {a.spec.name: a.rates.fleet_speedup for a in sweep.algos}, checkpointed,
                                    mix_scenarios=not sweep.device.on_cpu, device_rates=device_rates(sweep.device.kind, sweep.algos, sweep.fleet_update)),
                          workers)
    idle = jobs_estimate(jobs, done, workers) + sweep_overheads(sweep.results_dir, sweep.mlflow, len(todo))
    machine = None if sweep.launcher["name"] == "slurm" else MachineLoad.now()  # SLURM: other nodes' load
    return Plan(runs=tuple(runs), status=status, todo=tuple(todo), jobs=tuple(jobs), workers=workers,
                counts=describe(runs, done), estimate_s=idle, moved=tuple(moved), checkpointed=tuple(checkpointed),
                estimate=Estimate.of(idle, workers, machine))


def _warn(console: Console, text: str) -> None:
    console.print(f"[yellow]{escape(text)}[/yellow]", markup=True, highlight=False, soft_wrap=True)


def _engine_line(plan_: Plan, sweep: SweepConfig) -> str | None:
    """How the runs to do train: in fleets (how many, how large) or one by one, and why."""
    fleets, todo = plan_.fleets, plan_.todo
    if fleets:
        in_fleets = sum(len(j.runs) for j in fleets)
        resuming = len(plan_.resuming)
        return (f"engine [bold]fleet[/bold]: {in_fleets} of {len(todo)} runs to do train in {len(fleets)} fleet(s) of "
                f"{min(len(j.runs) for j in fleets)}-{max(len(j.runs) for j in fleets)} runs, the other {len(todo) - in_fleets} "
                "one by one (engine=single trains every run on its own)"
                + (f"; {resuming} fleet(s) resume their training from a checkpoint" if resuming else "")
                + (f"; update engine [bold]{sweep.fleet_update}[/bold] (fleet_update=eager reruns a release bit for bit)"
                   if sweep.fleet_update != DEFAULT_UPDATE_ENGINE else ""))
    if todo:
        return "engine [bold]single[/bold]: every run trains on its own" + (
            "" if sweep.engine == "single" else " (no two runs to do can share a fleet)")
    return None


def _estimate_text(plan_: Plan) -> str:
    """The estimate as printed: idle, and at the machine's load when that is noticeably longer."""
    return plan_.estimate.text() if plan_.estimate is not None else duration(plan_.estimate_s)


def print_plan(plan_: Plan, sweep: SweepConfig, console: Console) -> None:
    """The files moved aside, the counts per learner, the warnings, the settings and the estimate,
    and how the runs train."""
    for moved in plan_.moved:
        _warn(console, moved.describe(sweep.results_dir))
    counts = plan_.counts
    console.print(f"sweep [bold]{sweep.name}[/bold]: {counts['total']} runs ({counts['done']} done, {counts['todo']} to run)")
    table = Table()
    for col in ("learner", "runs", "done"):
        table.add_column(col, justify="right" if col != "learner" else "left")
    for label, (n, d) in counts["by_algo"].items():
        table.add_row(label, str(n), str(d))
    console.print(table)
    for warning in sweep.warnings:
        _warn(console, f"warning: {warning}")
    console.print(
        f"protocol [bold]{sweep.protocol.name}[/bold], preset [bold]{sweep.preset.name}[/bold], seeds {list(sweep.seeds)}, "
        f"launcher [bold]{sweep.launcher['name']}[/bold] ({plan_.workers} parallel), results in {sweep.results_dir}; "
        f"estimated time for what remains: [bold]{escape(_estimate_text(plan_))}[/bold]"
    )
    note = device_estimate_note(sweep.device.kind, [a for a in sweep.algos
                                               if fleet_trains(a.spec.target) and learner_trains(a.spec.target)],
                                sweep.fleet_update)
    if note:
        _warn(console, f"note: {note}")
    engine = _engine_line(plan_, sweep)
    if engine:
        console.print(engine)


def record_plan(plan_: Plan, sweep: SweepConfig, command: str, console: Console) -> Path:
    """Write the sweep manifest (what should exist when the sweep is done) and say where."""
    name = manifest_name(sweep.name, [r.run_id for r in plan_.runs])
    write_manifest(
        sweep.results_dir,
        name,
        [r.manifest_entry for r in plan_.runs],
        command=command,
        preset=sweep.preset.name,
        protocol=sweep.protocol.name,
        preset_seeds=list(sweep.preset.seeds),
        dry_run=sweep.dry_run,
    )
    path = sweep.results_dir / "manifests" / (name + ".json")
    console.print(f"plan recorded in {path}", soft_wrap=True)
    return path


def write_plan_file(plan_: Plan, sweep: SweepConfig, command: str, console: Console) -> None:
    """A dry run's plan: written to ``plan_file`` when one is set (the manifest's format), else nowhere."""
    if sweep.plan_file is None:
        console.print(f"dry run: nothing written (no manifest, {sweep.results_dir} not created or changed; "
                      "plan_file=PATH writes the plan as JSON)",
                      soft_wrap=True)
        return
    name = manifest_name(sweep.name, [r.run_id for r in plan_.runs])
    body = manifest_body(name, [r.manifest_entry for r in plan_.runs], command=command, preset=sweep.preset.name,
                         protocol=sweep.protocol.name, preset_seeds=list(sweep.preset.seeds), dry_run=True)
    sweep.plan_file.parent.mkdir(parents=True, exist_ok=True)
    sweep.plan_file.write_text(json.dumps(body, indent=1) + "\n", encoding="utf-8")
    console.print(f"dry run: plan written to {sweep.plan_file} ({sweep.results_dir} untouched)", soft_wrap=True)


def print_dry_run(plan_: Plan, console: Console) -> None:
    """Every planned run: its id, env, chain, learner, seed, budget, the job it trains in, its status."""
    listing = Table(title="planned runs")
    for col in ("run id", "env id", "chain", "learner", "seed", "budget", "job", "status"):
        listing.add_column(col)
    job_of = {r.run_id: (f"fleet {i + 1} ({len(j.runs)} runs)" if j.engine == "fleet" else "single")
              for i, j in enumerate(plan_.jobs) for r in j.runs}
    for r in plan_.runs:
        c = r.config
        listing.add_row(r.run_id, c.env_id, c.chain["name"], c.algo.label, str(c.seed), str(c.budget),
                        job_of.get(r.run_id, "-"), plan_.status[r.run_id] or "-")
    console.print(listing)


# ---------------------------------------------------------------------------------------- dispatch
def fleet_label(job: Any) -> str:
    """``30 PPO on PushOrSwitch (Utility)``: a fleet in words; the chain when all its runs share one
    (a fleet may hold several chains of one scenario, and two fleets of one scenario are common)."""
    config = job.runs[0].config
    chains = {r.config["chain"]["name"] for r in job.runs}
    chain = f" ({next(iter(chains))})" if len(chains) == 1 else f" ({len(chains)} chains)"
    return f"{len(job.runs)} {config['algo']['label']} on {config['scenario']}{chain}"


class FleetBars(JobProgress):
    """One progress bar per fleet while it trains (steps per run), under the sweep's bar of runs:
    at the paper's budget a fleet trains for many minutes before its first run is written.
    (A :class:`runners.launch.local_pool.JobProgress`; SLURM jobs train on other nodes and show none.)"""

    def __init__(self, progress: Any) -> None:
        self.progress = progress
        self.tasks: dict[int, Any] = {}

    def update(self, job: Any, steps: int, total: int) -> None:
        if id(job) not in self.tasks:
            label = f"  fleet: {fleet_label(job)}"
            self.tasks[id(job)] = self.progress.add_task(escape(label), total=total, note="steps per run")
        self.progress.update(self.tasks[id(job)], completed=steps, total=total)

    def end(self, job: Any) -> None:
        task = self.tasks.pop(id(job), None)
        if task is not None:
            self.progress.remove_task(task)


class ProgressLines(JobProgress):
    """Plain progress lines for a log file, at most one every ``every_s`` seconds.

    Rich's live bars draw nothing when stderr is not a terminal (``nohup ... > log``, a SLURM batch
    log, CI), so a paper-budget sweep would be silent for hours. Each line says how many runs are
    done and failed, the time since the sweep started and, for every fleet in training, its steps
    per run: ``[22:14:05] 523/1389 runs done, 0 failed, 27m elapsed; training: 30 PPO on
    PushOrSwitch 420,000/1,000,000 steps``. ``clock`` and ``wall`` are injectable for tests."""

    def __init__(self, console: Console, total: int, every_s: float,
                 clock: Callable[[], float] = time.monotonic, wall: Callable[[], str] = lambda: time.strftime("%H:%M:%S")) -> None:
        self.console, self.total, self.every_s, self.clock, self.wall = console, total, every_s, clock, wall
        self.done = self.failed = 0
        self.started = self.last = clock()
        self.fleets: dict[int, tuple[str, int, int]] = {}

    def run_finished(self, ok: bool) -> None:
        self.done += 1
        self.failed += not ok
        self._maybe_print(final=self.done == self.total)

    def update(self, job: Any, steps: int, total: int) -> None:
        self.fleets[id(job)] = (fleet_label(job), steps, total)
        self._maybe_print()

    def end(self, job: Any) -> None:
        self.fleets.pop(id(job), None)

    def line(self) -> str:
        """The progress line as of now."""
        text = (f"[{self.wall()}] {self.done}/{self.total} runs done, {self.failed} failed, "
                f"{duration(self.clock() - self.started)} elapsed")
        if self.fleets:
            text += "; training: " + ", ".join(f"{label} {steps:,}/{total:,} steps" for label, steps, total in self.fleets.values())
        return text

    def _maybe_print(self, final: bool = False) -> None:
        now = self.clock()
        if self.every_s <= 0 or (not final and now - self.last < self.every_s):
            return
        self.last = now
        self.console.print(escape(self.line()), highlight=False, soft_wrap=True)


class _Both(JobProgress):
    """Fleet progress told to the bars and to the plain lines."""

    def __init__(self, *parts: JobProgress) -> None:
        self.parts = parts

    def update(self, job: Any, steps: int, total: int) -> None:
        for part in self.parts:
            part.update(job, steps, total)

    def end(self, job: Any) -> None:
        for part in self.parts:
            part.end(job)


class _Outcomes:
    """What :func:`dispatch` hears of each run: its result is mirrored into MLflow (a failure to
    mirror is retried by the next sweep, never loses the result) and the bar advances."""

    def __init__(self, sweep: SweepConfig, tracker: Tracker | None, progress: Progress, console: Console, total: int,
                 lines: ProgressLines | None = None) -> None:
        self.sweep, self.tracker, self.progress, self.console, self.lines = sweep, tracker, progress, console, lines
        self.failures: dict[str, str] = {}
        self.interrupted: list[PlannedRun] = []
        self.task = progress.add_task(sweep.name, total=total, note="0 failed")

    def finish(self, run: PlannedRun, summary: dict[str, Any]) -> None:
        if summary["status"] == "interrupted":  # a SLURM task stopped by SIGTERM: not recorded, not failed
            self.interrupted.append(run)
            self.progress.update(self.task, advance=1)
            return
        if summary["status"] != "ok":
            self.failures[run.run_id] = str(summary.get("error"))
        else:
            self.failures.pop(run.run_id, None)
        if self.tracker is not None:
            try:
                self.tracker.sync(run.run_id)
            except Exception as exc:  # noqa: BLE001 - tracking must never lose a result
                self.console.print(f"[yellow]MLflow mirror of {run.run_id} failed ({escape(str(exc))}); it is retried next time[/yellow]")
        self.progress.update(self.task, advance=1, note=f"{len(self.failures)} failed")
        if self.lines is not None:
            self.lines.run_finished(summary["status"] == "ok")

    def fail(self, run: PlannedRun, error: str) -> None:
        """A run whose worker (or SLURM task) died before reporting it. If the run wrote its result
        before the death (a kill between the write and the report), that result stands and is
        counted as what it says; otherwise the run is recorded as failed with ``error``."""
        status = finished_status(Path(self.sweep.results_dir), run.run_id)
        if status is not None:
            self.finish(run, {"status": status, "error": None if status == "ok" else error})
            return
        record_failure(run.config, run.run_id, self.sweep.results_dir, error)
        self.finish(run, {"status": "failed", "error": error})


def dispatch(plan_: Plan, sweep: SweepConfig, tracker: Tracker | None, console: Console) -> list[PlannedRun]:
    """Train the plan's jobs on the sweep's launcher (the local pool, or SLURM), under a bar of runs;
    returns the runs a SLURM task's stop signal interrupted (a local stop raises :class:`PoolStopped`)."""
    columns = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[note]}"),
               TimeElapsedColumn(), TimeRemainingColumn())
    # Without a terminal the bars draw nothing until the end: plain lines tell a log how it goes.
    lines = None if console.is_terminal else ProgressLines(console, len(plan_.todo), sweep.progress_every_s)
    with Progress(*columns, console=console, transient=False) as progress:
        outcomes = _Outcomes(sweep, tracker, progress, console, len(plan_.todo), lines)
        if not plan_.todo:
            return []
        if sweep.launcher["name"] == "slurm":
            run_on_slurm(list(plan_.jobs), sweep.launcher, sweep.results_dir, sweep.gif, sweep.name, outcomes.finish,
                         outcomes.fail, sweep.device, sweep.checkpoint_every_s, sweep.fleet_update)
        else:
            WorkerPool(plan_.workers, sweep.results_dir, sweep.gif, sweep.device, sweep.checkpoint_every_s,
                       sweep.fleet_update).run(
                list(plan_.jobs), outcomes.finish, outcomes.fail, FleetBars(progress) if lines is None else _Both(FleetBars(progress), lines))
    return outcomes.interrupted


def mirror_finished(plan_: Plan, sweep: SweepConfig, tracker: Tracker, console: Console) -> None:
    """Mirror every finished run of the plan into MLflow: those an earlier, interrupted sweep left
    unmirrored too (a run already mirrored is not mirrored twice)."""
    for r in plan_.runs:
        if finished_status(sweep.results_dir, r.run_id) is not None:
            try:
                tracker.sync(r.run_id)
            except Exception as exc:  # noqa: BLE001 - tracking must never lose a result
                console.print(f"[yellow]MLflow mirror of {r.run_id} failed: {escape(str(exc))}[/yellow]")


def report(plan_: Plan, sweep: SweepConfig, console: Console, seconds: float) -> int:
    """Print how the sweep ended (ok, failed, missing; each failed run with its error); the exit status."""
    final = {r.run_id: finished_status(sweep.results_dir, r.run_id) for r in plan_.runs}
    failed = [r for r in plan_.runs if final[r.run_id] == "failed"]
    missing = [r for r in plan_.runs if final[r.run_id] is None]
    console.print(
        f"finished in {duration(seconds)}: {sum(s == 'ok' for s in final.values())} ok, "
        f"{len(failed)} failed, {len(missing)} missing (of {len(plan_.runs)})"
    )
    if failed:
        console.print("[red]failed runs:[/red]")
        for r in failed:
            table = read_table_or_quarantine(sweep.results_dir, run_path(sweep.results_dir, r.run_id), columns=["error"])
            err = table.column("error")[0].as_py() if table is not None else "(result file unreadable)"
            c = r.config
            # no markup: an error quotes values ("[nan, 0.5]") that rich would read as tags and drop
            console.print(f"  {r.run_id} {c.algo.label} {c.env_id} {c.chain['name']} seed {c.seed}: {err}",
                          markup=False, highlight=False, soft_wrap=True)
    return 0 if not failed and not missing else 1


def run_sweep(sweep: SweepConfig, console: Console | None = None, command: str | None = None) -> int:
    """Plan, record and execute a validated sweep whose machine passed :func:`runners.launch.preflight.preflight`;
    returns the exit status. ``command``: the command line the manifest records (default: this process's)."""
    console = console or Console(stderr=True)
    plan_ = make_plan(sweep)
    print_plan(plan_, sweep, console)
    # Before the manifest: a broken store stops nothing half-way.
    tracker = Tracker(sweep.results_dir) if sweep.mlflow and not sweep.dry_run else None
    if sweep.dry_run:
        print_dry_run(plan_, console)
        write_plan_file(plan_, sweep, command if command is not None else " ".join(sys.argv), console)
        return 0
    record_plan(plan_, sweep, command if command is not None else " ".join(sys.argv), console)
    started = time.perf_counter()
    remove_stale(sweep.results_dir)  # checkpoints of fleets whose runs all finished: nothing to resume
    remove_leftovers(sweep.results_dir)  # temporary files of writers killed before they renamed them
    try:
        interrupted = dispatch(plan_, sweep, tracker, console)
    except PoolStopped as stop:
        if tracker is not None:
            mirror_finished(plan_, sweep, tracker, console)
        for detail in stop.details:  # e.g. "stopped by SIGTERM: fleet of 3 runs stopped at 3,072 of 8,192 steps, ..."
            if "fleet of" in detail:
                console.print(escape(detail), soft_wrap=True, highlight=False)
        console.print(escape(_stopped_line(stop.reason, len(stop.runs))), soft_wrap=True, highlight=False)
        return EXIT_STOPPED
    if tracker is not None:
        mirror_finished(plan_, sweep, tracker, console)
    status = report(plan_, sweep, console, time.perf_counter() - started)
    if interrupted:
        console.print(_stopped_line("SLURM task(s) stopped by a signal (time limit or preemption)", len(interrupted)),
                      soft_wrap=True, highlight=False)
    return status


#: A sweep stopped by SIGTERM exits as a program killed by it would (128 + 15), after a clean stop.
EXIT_STOPPED = 143


def _stopped_line(reason: str, n: int) -> str:
    """One line: why the sweep stopped, how many runs it interrupted, and how to resume them."""
    return (f"{reason}: {n} run(s) interrupted, none recorded as failed; fleets in training wrote their checkpoints; "
            "run the same command again to resume")


# ---------------------------------------------------------------------------------------- entry point
def user_errors() -> tuple[type[BaseException], ...]:
    """Errors that are the user's or the environment's to fix (one line, exit 2), not bugs."""
    return (ConfigError, TrackingError, SlurmUnavailable, CommandLineError)


def _one_line_error(console: Console, label: str, exc: BaseException) -> int:
    console.print(f"[red]{label}:[/red] {escape(one_line(exc))}", markup=True, highlight=False, soft_wrap=True)
    return 2


def sweep_command(argv: Sequence[str]) -> int:
    """The sweep command without :func:`main`'s exit-status mapping: read the command line, compose
    and check every sweep it asks for, then run them in turn (the worst exit status is returned)."""
    line = parse_command_line(argv)
    if line.debug:
        os.environ[DEBUG_ENV] = "1"  # ours, not Hydra's: also for the workers this sweep starts
    if line.version:  # ours, with Hydra's version: Hydra's own flag printed only Hydra's, and twice
        print(f"{version_text('python -m runners.sweep')}, Hydra {hydra.__version__}")
        return 0
    console = Console(stderr=True, width=None if sys.stderr.isatty() else 160)
    try:
        overrides, command = prepare_overrides(line)
        if line.help or line.show or line.info:
            return show(line, overrides)
        sweeps = load_sweeps(overrides, line)
    except (ConfigError, ChainError) as exc:  # ChainError: a user's chain file that cannot be read (a norm, a field)
        if debug_enabled():
            raise
        return _one_line_error(console, "configuration error", exc)
    return run_sweeps(sweeps, console, command)


def run_sweeps(sweeps: Sequence[SweepConfig], console: Console, command: str) -> int:
    """Check the machine for each sweep (:func:`runners.launch.preflight.preflight`) and run it; a user
    error stops at once (exit 2), else the worst exit status of the sweeps."""
    worst = 0
    for sweep in sweeps:
        try:
            preflight(sweep)
        except ConfigError as exc:
            if debug_enabled():
                raise
            return _one_line_error(console, "configuration error", exc)
        try:
            worst = max(worst, run_sweep(sweep, console, command))
        except user_errors() as exc:
            if debug_enabled():
                raise
            return _one_line_error(console, "error", exc)
    return worst


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m runners.sweep [flags] key=value ...``; returns the exit status (module docstring)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    os.environ.setdefault("MORALITY_GYM_ORIGINAL_CWD", os.getcwd())
    return run_cli(lambda: sweep_command(argv), user_errors(), argv)


if __name__ == "__main__":
    sys.exit(main())
