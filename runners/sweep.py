"""``python -m runners.sweep algo=cpo chain=utility``: compose, validate, plan, dispatch, record.

1. Hydra composes ``conf/``; :mod:`runners.config` validates everything and :mod:`runners.preflight`
   checks the machine before anything runs.
2. The plan expands chain x scenario x variant x algorithm x seed, prints the counts and an
   estimate of the time, and writes the sweep manifest (what should exist when it is done).
3. Finished runs are skipped (their Parquet file exists with status ``ok``; failed ones are
   retried unless ``retry_failed=false``); the rest go to the local pool or SLURM.
4. Each finished run is mirrored into MLflow by this process; anything left unmirrored by an
   earlier, interrupted sweep is mirrored at the end.
Exit status: 0 if every planned run is ``ok``, 1 if some failed (they are listed), 2 for an
invalid configuration or another user error (one line; ``--debug`` or ``MORALITY_GYM_DEBUG=1``
shows the traceback). Killing the sweep at any point and running it again finishes it with no
lost and no duplicated results; an unreadable result file is moved aside and its run done again
(:mod:`runners.quarantine`); two sweeps on one directory share it safely (per-run locks, and one
MLflow writer at a time).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

import hydra
from omegaconf import DictConfig
from rich.markup import escape

from morality_gym.clitools import DEBUG_ENV, debug_enabled, duration, one_line, run_cli
from runners.config import ConfigError, SweepConfig, validate  # also stores the schemas (runners.config_schema)
from runners.execute import finished_status, record_failure
from runners.jobs import dispatch_order, jobs_estimate, make_jobs
from runners.manifest import manifest_name, write_manifest
from runners.paths import CONF_DIR
from runners.plan import PlannedRun, describe, plan
from runners.preflight import preflight
from runners.quarantine import check_run_files, read_table_or_quarantine

_EXIT = {"code": 0, "entered": 0}


def _workers(sweep: SweepConfig) -> int:
    if sweep.launcher["name"] == "slurm":
        return int(sweep.launcher["array_parallelism"])
    return int(sweep.launcher.get("workers") or len(os.sched_getaffinity(0)) or 1)


class FleetBars:
    """One progress bar per fleet while it trains (steps per run), under the sweep's bar of runs:
    at the paper's budget a fleet trains for many minutes before its first run is written.
    (A :class:`runners.pool.JobProgress`; SLURM jobs train on other nodes and show none.)"""

    def __init__(self, progress: Any) -> None:
        self.progress = progress
        self.tasks: dict[int, Any] = {}

    def update(self, job: Any, steps: int, total: int) -> None:
        if id(job) not in self.tasks:
            config = job.runs[0].config
            label = f"  fleet: {len(job.runs)} {config['algo']['label']} runs on {config['scenario']}"
            self.tasks[id(job)] = self.progress.add_task(escape(label), total=total, note="steps per run")
        self.progress.update(self.tasks[id(job)], completed=steps, total=total)

    def end(self, job: Any) -> None:
        task = self.tasks.pop(id(job), None)
        if task is not None:
            self.progress.remove_task(task)


def sweep_overheads(sweep: SweepConfig, n_todo: int) -> float:
    """Seconds the sweep spends besides training its runs (:class:`runners.config_schema.SweepOverheads`)."""
    from runners.config_schema import SweepOverheads
    from runners.tracking import tracking_uri

    uri = tracking_uri(sweep.results_dir)
    new_store = uri.startswith("sqlite:///") and not Path(uri.removeprefix("sqlite:///")).exists()
    return SweepOverheads().seconds(n_todo, new_store=new_store, mlflow=sweep.mlflow)


def run_sweep(sweep: SweepConfig, console: Any = None) -> int:
    """Plan and execute a validated sweep; returns the exit status."""
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )
    from rich.table import Table

    console = console or Console(stderr=True)
    runs = plan(sweep)
    sweep.results_dir.mkdir(parents=True, exist_ok=True)
    for moved in check_run_files(sweep.results_dir, [r.run_id for r in runs]):
        console.print(f"[yellow]{escape(moved.describe(sweep.results_dir))}[/yellow]", markup=True, highlight=False, soft_wrap=True)
    status = {r.run_id: finished_status(sweep.results_dir, r.run_id) for r in runs}
    done = {rid for rid, s in status.items() if s == "ok" or (s == "failed" and not sweep.retry_failed)}
    workers = _workers(sweep)
    info = describe(runs, done, workers)
    todo_runs = [r for r in runs if r.run_id not in done]
    jobs = dispatch_order(make_jobs(todo_runs, sweep.engine, sweep.fleet_size, workers,
                                    {a.spec.name: a.fleet_speedup for a in sweep.algos}), workers)
    info["est_seconds"] = jobs_estimate(jobs, done, workers) + sweep_overheads(sweep, len(todo_runs))
    fleets = [j for j in jobs if j.engine == "fleet"]
    console.print(f"sweep [bold]{sweep.name}[/bold]: {info['total']} runs ({info['done']} done, {info['todo']} to run)")
    table = Table()
    for col in ("learner", "runs", "done"):
        table.add_column(col, justify="right" if col != "learner" else "left")
    for label, (n, d) in info["by_algo"].items():
        table.add_row(label, str(n), str(d))
    console.print(table)
    for warning in sweep.warnings:
        console.print(f"[yellow]warning: {escape(warning)}[/yellow]", markup=True, highlight=False, soft_wrap=True)
    console.print(
        f"protocol [bold]{sweep.protocol.name}[/bold], preset [bold]{sweep.preset.name}[/bold], seeds {list(sweep.seeds)}, "
        f"launcher [bold]{sweep.launcher['name']}[/bold] ({workers} parallel), results in {sweep.results_dir}; "
        f"estimated time for what remains: [bold]{duration(info['est_seconds'])}[/bold]"
    )
    if fleets:
        in_fleets = sum(len(j.runs) for j in fleets)
        console.print(
            f"engine [bold]fleet[/bold]: {in_fleets} of {len(todo_runs)} runs to do train in {len(fleets)} fleet(s) of "
            f"{min(len(j.runs) for j in fleets)}-{max(len(j.runs) for j in fleets)} runs, the other {len(todo_runs) - in_fleets} "
            "one by one (engine=single trains every run on its own)"
        )
    elif todo_runs:
        console.print("engine [bold]single[/bold]: every run trains on its own" + (
            "" if sweep.engine == "single" else " (no two runs to do can share a fleet)"))
    tracker = None
    if sweep.mlflow and not sweep.dry_run:
        from runners.tracking import Tracker

        tracker = Tracker(sweep.results_dir)  # before the manifest: a broken store stops nothing half-way
    name = manifest_name(sweep.name, [r.run_id for r in runs])
    write_manifest(
        sweep.results_dir,
        name,
        [r.identity for r in runs],
        command=" ".join(sys.argv),
        preset=sweep.preset.name,
        protocol=sweep.protocol.name,
        preset_seeds=list(sweep.preset.seeds),
        dry_run=sweep.dry_run,
    )
    console.print(f"plan recorded in {sweep.results_dir / 'manifests' / (name + '.json')}"
                  + (" (dry run: not counted as planned by the leaderboard)" if sweep.dry_run else ""), soft_wrap=True)
    if sweep.dry_run:
        listing = Table(title="planned runs")
        for col in ("run id", "env id", "chain", "learner", "seed", "budget", "job", "status"):
            listing.add_column(col)
        job_of = {r.run_id: (f"fleet {i + 1} ({len(j.runs)} runs)" if j.engine == "fleet" else "single")
                  for i, j in enumerate(jobs) for r in j.runs}
        for r in runs:
            c = r.config
            listing.add_row(r.run_id, c["env_id"], c["chain"]["name"], c["algo"]["label"], str(c["seed"]), str(c["budget"]),
                            job_of.get(r.run_id, "-"), status[r.run_id] or "-")
        console.print(listing)
        return 0

    todo = todo_runs
    failures: dict[str, str] = {}
    started = time.perf_counter()
    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[note]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=False,
    ) as progress:
        task = progress.add_task(sweep.name, total=len(todo), note="0 failed")

        def finish(run: PlannedRun, summary: dict[str, Any]) -> None:
            if summary["status"] != "ok":
                failures[run.run_id] = str(summary.get("error"))
            else:
                failures.pop(run.run_id, None)
            if tracker is not None:
                try:
                    tracker.sync(run.run_id)
                except Exception as exc:  # noqa: BLE001 - tracking must never lose a result
                    console.print(f"[yellow]MLflow mirror of {run.run_id} failed ({exc}); it is retried next time[/yellow]")
            progress.update(task, advance=1, note=f"{len(failures)} failed")

        def fail(run: PlannedRun, error: str) -> None:
            record_failure(run.config, run.run_id, sweep.results_dir, error)
            finish(run, {"status": "failed", "error": error})

        if todo:
            if sweep.launcher["name"] == "slurm":
                from runners.slurm_launcher import run_on_slurm

                run_on_slurm(jobs, sweep.launcher, sweep.results_dir, sweep.gif, sweep.name, finish, fail, sweep.device)
            else:
                from runners.pool import WorkerPool

                WorkerPool(workers, sweep.results_dir, sweep.gif, sweep.device).run(jobs, finish, fail, FleetBars(progress))
    if tracker is not None:
        for r in runs:
            if finished_status(sweep.results_dir, r.run_id) is not None:
                try:
                    tracker.sync(r.run_id)
                except Exception as exc:  # noqa: BLE001
                    console.print(f"[yellow]MLflow mirror of {r.run_id} failed: {exc}[/yellow]")
    final = {r.run_id: finished_status(sweep.results_dir, r.run_id) for r in runs}
    failed = [r for r in runs if final[r.run_id] == "failed"]
    missing = [r for r in runs if final[r.run_id] is None]
    console.print(
        f"finished in {duration(time.perf_counter() - started)}: {sum(s == 'ok' for s in final.values())} ok, "
        f"{len(failed)} failed, {len(missing)} missing (of {len(runs)})"
    )
    if failed:
        from runners.results_schema import run_path

        console.print("[red]failed runs:[/red]")
        for r in failed:
            table = read_table_or_quarantine(sweep.results_dir, run_path(sweep.results_dir, r.run_id), columns=["error"])
            err = table.column("error")[0].as_py() if table is not None else "(result file unreadable)"
            c = r.config
            console.print(f"  {r.run_id} {c['algo']['label']} {c['env_id']} {c['chain']['name']} seed {c['seed']}: {err}")
    return 0 if not failed and not missing else 1


@hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name="config")
def _app(cfg: DictConfig) -> None:
    from rich.console import Console

    _EXIT["entered"] = 1  # past Hydra's composition: a SystemExit from here on is a crash, not a config error
    console = Console(stderr=True, width=None if sys.stderr.isatty() else 160)
    try:
        sweep = validate(cfg)
        preflight(sweep)  # the machine: results directory, MLflow, SLURM
    except ConfigError as exc:
        if debug_enabled():
            raise
        console.print(f"[red]configuration error:[/red] {escape(one_line(exc))}", markup=True, highlight=False, soft_wrap=True)
        _EXIT["code"] = 2
        return
    try:
        _EXIT["code"] = run_sweep(sweep, console)
    except user_errors() as exc:  # Hydra would print these with a traceback
        if debug_enabled():
            raise
        console.print(f"[red]error:[/red] {escape(one_line(exc))}", markup=True, highlight=False, soft_wrap=True)
        _EXIT["code"] = 2


_GROUPS = ("scenario", "chain", "algo", "protocol", "preset", "launcher", "experiment")


def _hparam_override(key: str, value: str, argv: list[str]) -> str | None:
    """An ``[+]algo.<option>.hparams.<name>=...`` override whose name the algorithm does not take.

    Hydra would answer a name without ``+`` with "Key ... is not in struct" and advise adding
    ``+``; the real problem is usually a typo, so it is named here, with the closest names. Works
    for any learner: the names are its class's constructor parameters.
    """
    from morality_gym.baselines.hparams import accepted_hparams
    from morality_gym.baselines.specs import SpecError
    from runners.paths import find_config

    parts = key.lstrip("+~").split(".")
    if len(parts) != 4 or parts[0] != "algo" or parts[2] != "hparams" or key.startswith("~"):
        return None
    path = find_config("algo", parts[1], argv)
    if path is None:
        return None
    import yaml

    target = (yaml.safe_load(path.read_text()) or {}).get("_target_")
    try:
        accepted = accepted_hparams(str(target))
    except (SpecError, ValueError):
        return None  # reported with its file by the validation
    if parts[3] in accepted:
        return None
    import difflib

    close = difflib.get_close_matches(parts[3], list(accepted), n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return f"{key}={value}: {parts[3]!r} is not a hyper-parameter of algo {parts[1]}{hint}; valid: {', '.join(sorted(accepted))}"


def precheck(argv: list[str]) -> str | None:
    """Check config-group selections and hyper-parameter names on the command line, before Hydra
    (whose messages for these do not say what the valid options are). Returns an error or None.

    Options are looked up on the whole search path: ``conf/``, ``--config-dir DIR`` (either form),
    ``hydra.searchpath=[...]`` and the installed plugins.
    """
    import difflib

    from runners.options import options as group_options
    from runners.paths import source_dir, sources_from_argv

    for source in sources_from_argv(argv):
        directory = source_dir(source)
        if directory is None or not directory.is_dir():
            return (f"config search path entry {source!r} is not a directory; give an existing directory "
                    "(--config-dir DIR, hydra.searchpath=[file:///abs/dir] or [pkg://package])")
    for arg in argv:
        if "=" not in arg or arg.startswith("-"):
            continue
        key, value = arg.split("=", 1)
        problem = _hparam_override(key, value, argv)
        if problem:
            return problem
        group = key.lstrip("+~")
        if group not in _GROUPS:
            continue
        value = value.strip()
        options = [o.strip() for o in value.strip("[]").split(",") if o.strip()] if value not in ("null", "[]") else []
        valid = group_options(group, argv)
        for option in options:
            if option not in valid:
                skipped = _skipped_scenario(option) if group == "scenario" else None
                if skipped:
                    return f"scenario={option}: {skipped}"
                close = difflib.get_close_matches(option, valid, n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                return f"{group}={value}: unknown {group} {option!r}{hint}; valid: {', '.join(valid)}"
    return None


def _skipped_scenario(option: str) -> str | None:
    """Why a scenario of this name is missing, when a ``MORALITY_GYM_SCENARIOS`` file declaring it
    was skipped as invalid (its file, field and fix), else None."""
    from morality_gym.envs.naming import squash
    from morality_gym.envs.registry import skipped_scenario_files

    for item in skipped_scenario_files():
        if squash(item.name or item.path.stem) == squash(option):
            return f"the file defining it, {item.path}, was skipped as invalid: {item.error.removeprefix(f'{item.path}: ')}"
    return None


def compose_check(argv: list[str]) -> str | None:
    """Compose the configuration once before Hydra's own run, to report a key or value the typed
    schemas (:mod:`runners.config_schema`) refuse as one line naming the key, its file or override and
    the closest valid key (Hydra would print several lines and a hint about ``+key=``). Returns the
    error or None. Hydra's own flags are parsed by Hydra's parser; ``--config-dir`` becomes a
    search-path entry, as Hydra itself treats it."""
    from hydra import compose, initialize_config_dir
    from hydra._internal.utils import get_args_parser

    from runners.paths import source_dir, split_list
    from runners.config_schema import composition_error

    try:
        args = get_args_parser().parse_args(argv)
    except SystemExit:
        return None  # Hydra reports its own command-line errors
    if args.help or args.hydra_help or args.info or args.shell_completion or args.multirun:
        return None
    overrides = list(args.overrides)
    if args.config_dir:
        directory = source_dir(args.config_dir)
        extra = f"file://{directory}"
        merged = False
        for i, item in enumerate(overrides):
            if item.lstrip("+").startswith("hydra.searchpath="):
                key, value = item.split("=", 1)
                overrides[i] = f"{key}=[{','.join([*split_list(value), extra])}]"
                merged = True
        if not merged:
            overrides.append(f"hydra.searchpath=[{extra}]")
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            compose(args.config_name or "config", overrides=overrides)
    except Exception as exc:  # noqa: BLE001 - every composition error is the user's to fix
        from runners.paths import find_config

        return composition_error(exc, lambda group, option: find_config(group, option, argv))
    return None


def with_plugins(argv: list[str]) -> list[str]:
    """``argv`` with the installed plugins' config packages added to ``hydra.searchpath`` (merged
    with the user's own entries, which come first), and every user config directory made
    importable, here and in the workers (:func:`morality_gym.baselines.targets.add_python_roots`):
    a ``_target_`` module kept next to ``algo/`` in a config directory needs no install."""
    from morality_gym.baselines.targets import add_python_roots
    from runners.paths import plugin_sources, source_dir, sources_from_argv, split_list

    add_python_roots([d for s in sources_from_argv(argv) if not s.startswith("pkg://") and (d := source_dir(s)) is not None])
    plugins = plugin_sources()
    if not plugins:
        return argv
    out, merged = [], False
    for arg in argv:
        if arg.lstrip("+").startswith("hydra.searchpath="):
            key, value = arg.split("=", 1)
            items = [*split_list(value), *(p for p in plugins if p not in split_list(value))]
            out.append(f"{key}=[{','.join(items)}]")
            merged = True
        else:
            out.append(arg)
    if not merged:
        out.append(f"hydra.searchpath=[{','.join(plugins)}]")
    return out


def user_errors() -> tuple[type[BaseException], ...]:
    """Errors that are the user's or the environment's to fix (one line, exit 2), not bugs."""
    from runners.slurm_launcher import SlurmUnavailable
    from runners.tracking import TrackingError

    return (ConfigError, TrackingError, SlurmUnavailable)


def main() -> int:
    os.environ.setdefault("MORALITY_GYM_ORIGINAL_CWD", os.getcwd())
    if "--version" in sys.argv[1:]:  # ours, with Hydra's: Hydra's own flag printed only Hydra's, and twice
        from morality_gym.clitools import version_text

        print(f"{version_text('python -m runners.sweep')}, Hydra {hydra.__version__}")
        return 0
    if "--debug" in sys.argv[1:]:  # ours, not Hydra's: strip it before Hydra parses the line
        sys.argv = [a for a in sys.argv if a != "--debug"]
        os.environ[DEBUG_ENV] = "1"

    def body() -> int:
        from morality_gym.norms.chain import ChainError
        from runners.options import normalise_argv

        try:
            sys.argv[1:] = normalise_argv(with_plugins(sys.argv[1:]))
        except ChainError as exc:  # a user's chain file that cannot be read (a norm, a field): say what
            if debug_enabled():
                raise
            print(f"configuration error: {one_line(exc)}", file=sys.stderr)
            return 2
        problem = precheck(sys.argv[1:]) or compose_check(sys.argv[1:])
        if problem:
            print(f"configuration error: {problem}", file=sys.stderr)
            return 2
        try:
            _app()
        except SystemExit as exc:  # Hydra could not compose the configuration, or the sweep crashed (a bug)
            if not exc.code:
                return 0
            return 1 if _EXIT.get("entered") else 2
        return _EXIT["code"]

    return run_cli(body, user_errors())


if __name__ == "__main__":
    sys.exit(main())
