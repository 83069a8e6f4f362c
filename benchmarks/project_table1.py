"""Project a whole Table 1 sweep's wall time from rows of it that were actually run.

Why this exists: the sweep planner's estimate comes from per-learner rates fitted once
(``planning`` in ``conf/algo``) and a fleet speed-up measured on one scenario; at the paper's
budget a Table 1 takes hours, so a claim such as "the paper preset fits a workstation" should rest
on runs that were measured, not on the planner alone. This tool reads the finished runs of a
results directory or a results release (a few Table 1 rows run at the preset in question), measures each learner's
core-seconds per training step (every run's ``cpu_time_s``, or its ``wall_time_s`` in files written
before that column: its share of its fleet's training plus its own evaluations and writes), and prices every job of the full Table 1 plan with it. The
jobs are those the sweep itself would make (:func:`runners.plan.fleets.make_jobs`, fleets of up to
``fleet_size``), handed to ``W`` workers in the sweep's dispatch order (longest estimated job
first) as each becomes free, as the local pool does, so the projection includes the tail where
one long fleet keeps a worker busy.

Usage::

    python -m benchmarks.project_table1 RESULTS_DIR|RELEASE_DIR [--preset paper] [--protocol paper]
        [--engine fleet] [--workers 2 8] [--set KEY=VALUE ...] [--relative-to RESULTS_DIR] [--out FILE.md]

A learner with no measured run keeps the planner's estimate and is marked so in the output.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
from hydra import compose, initialize_config_dir

from leaderboard.runs.releases import MANIFEST, load
from morality_gym.baselines.specs import CONF_DIR, fleet_trains, learner_spec
from morality_gym.clitools import duration, write_atomically
from morality_gym.results.schema import compute_seconds, read_runs
from runners.compose.sweep_config import validate
from runners.plan.estimate import dispatch_order, jobs_estimate, makespan
from runners.plan.fleets import make_jobs
from runners.plan.runs import expand_sweep


@dataclass(frozen=True)
class Rate:
    """Measured cost of one learner's runs: core-seconds per training step of one run."""

    runs: int
    steps: int
    core_seconds: float
    rows: tuple[str, ...]
    fleet_sizes: tuple[int, ...]
    scenarios: tuple[str, ...] = ()
    cpu_runs: int = 0  # of ``runs``, those that recorded their CPU time (the others count their wall time)

    @property
    def seconds_per_step(self) -> float:
        return self.core_seconds / max(self.steps, 1)


def _target(config: str, algo: str) -> str:
    """The learner class a run was trained with: its recorded config's, else its algo file's."""
    try:
        return str(json.loads(config)["algo"]["target"])
    except (TypeError, ValueError, KeyError):
        return learner_spec(algo).target


def finished_runs(results_dir: Path, protocol: str, preset: str | None, engine: str) -> Any:
    """The ``ok`` runs under ``protocol`` (and ``preset``, unless None) trained by ``engine``.

    A run that trains nothing, or whose learner the fleet engine does not reproduce, counts
    whatever ``engine`` says: it never joins a fleet.
    """
    frame = _run_rows(results_dir)
    if frame.empty:
        return frame
    keep = (frame["status"] == "ok") & (frame["protocol"] == protocol)
    if preset is not None:
        keep &= frame["preset"] == preset
    frame = frame[keep]
    kind = frame["engine"].fillna("single").astype(str).str.split(":").str[0]
    alone = [budget <= 0 or not fleet_trains(_target(config, algo))
             for budget, config, algo in zip(frame["budget"], frame["config"], frame["algo"], strict=True)]
    return frame[(kind == engine) | pd.Series(alone, index=frame.index)]


def readable(path: Path) -> bool:
    """Whether ``path`` holds runs this tool reads: a results directory or a results release."""
    return (path / "runs").is_dir() or (path / MANIFEST).is_file()


def _run_rows(results_dir: Path) -> Any:
    """Every run row of a results directory, or of a results release (``release.json``, checked
    against its checksums first), so a shipped sweep's cost can be re-measured from the repository."""
    if (results_dir / MANIFEST).is_file():
        return load(results_dir).runs
    return read_runs(results_dir, skipped=[])


def measured_rates(results_dir: Path, protocol: str, preset: str, engine: str, cpu_only: bool = False) -> dict[str, Rate]:
    """Per algo name: what its finished runs under ``protocol``/``preset``/``engine`` cost.

    Random trains nothing, so its cost is per run, not per step: its ``steps`` are its runs.
    ``cpu_only``: only the runs that recorded their CPU time. A run written before ``cpu_time_s``
    existed counts its wall time, which on a shared machine (a sweep beside other work) is CPU
    time plus waiting: a sweep that spans both kinds is priced honestly from the first kind alone.
    """
    frame = finished_runs(results_dir, protocol, preset, engine)
    if cpu_only and not frame.empty:
        frame = frame[frame["cpu_time_s"].notna()] if "cpu_time_s" in frame else frame.iloc[:0]
    if frame.empty:
        return {}
    rates: dict[str, Rate] = {}
    for algo, group in frame.groupby("algo"):
        trained = int(group["budget"].max()) > 0
        sizes = sorted({int(e.split(":")[1]) for e in group["engine"].fillna("single").astype(str) if ":" in e})
        rates[str(algo)] = Rate(
            runs=len(group),
            steps=int(group["budget"].sum()) if trained else len(group),
            core_seconds=float(compute_seconds(group).sum()),
            rows=tuple(sorted({f"{c} / {s}" for c, s in zip(group["chain"], group["scenario"], strict=True)})),
            fleet_sizes=tuple(sizes),
            scenarios=tuple(sorted(set(group["scenario"]))),
            cpu_runs=int(group["cpu_time_s"].notna().sum()) if "cpu_time_s" in group else 0,
        )
    return rates


def scenario_factors(reference_dir: Path, protocol: str, engine: str, rates: dict[str, Rate]) -> dict[tuple[str, str], float]:
    """How much dearer per step each (learner, scenario) is than the scenarios ``rates`` measured.

    Why: a step's cost depends on the scenario (observation size, how many distinct states CPO's
    and PPO-Lag's whole-rollout arithmetic sees, how often norms fire); in the quick Table 1 the
    dearest scenarios cost about twice the cheapest per step. Rows measured at the paper's budget
    are few, so each scenario's cost relative to the measured ones is taken from a sweep that ran
    every scenario with the same engine (any preset, e.g. the quick Table 1), and the measured
    rate is scaled by it. Pairs the reference does not have keep a factor of 1.
    """
    frame = finished_runs(reference_dir, protocol, None, engine)
    frame = frame[frame["budget"] > 0] if not frame.empty else frame
    factors: dict[tuple[str, str], float] = {}
    for algo, rate in rates.items():
        mine = frame[frame["algo"] == algo] if not frame.empty else frame
        if mine.empty or rate.steps == rate.runs:
            continue
        compute = compute_seconds(mine)
        per_step = compute.groupby(mine["scenario"]).sum() / mine.groupby("scenario")["budget"].sum()
        base_rows = mine[mine["scenario"].isin(rate.scenarios)]
        if base_rows.empty:
            continue
        base = float(compute[base_rows.index].sum() / base_rows["budget"].sum())
        factors.update({(algo, str(scenario)): float(value) / base for scenario, value in per_step.items()})
    return factors


def table1_plan(preset: str, protocol: str, engine: str, scratch: Path, extra: Sequence[str] = ()) -> tuple[list[Any], Any]:
    """The full Table 1 plan (its runs and validated sweep), composed as the sweep would compose it."""
    overrides = ["experiment=table1", f"protocol={protocol}", f"preset={preset}", f"engine={engine}",
                 f"results_dir={scratch}", "mlflow=false", "dry_run=true"]
    if protocol == "corrected":  # the corrected table re-runs only the learners the fixes touch
        overrides.append("algo=[random,ppo_lag,cpo]")
    overrides += list(extra)
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=overrides)
    sweep = validate(cfg)
    return expand_sweep(sweep), sweep


def plan_jobs(runs: list[Any], sweep: Any, workers: int) -> list[Any]:
    """The plan cut into the jobs a sweep with ``workers`` workers runs, in the order they take them."""
    speedups = {a.spec.name: a.rates.fleet_speedup for a in sweep.algos}
    return dispatch_order(make_jobs(runs, sweep.engine, sweep.fleet_size, workers, speedups), workers)


def table1_jobs(preset: str, protocol: str, engine: str, workers: int, scratch: Path,
                extra: Sequence[str] = ()) -> tuple[list[Any], Any]:
    """The full Table 1 plan cut into the jobs a sweep with ``workers`` workers would run."""
    runs, sweep = table1_plan(preset, protocol, engine, scratch, extra)
    return plan_jobs(runs, sweep, workers), sweep


def job_seconds(job: Any, rates: dict[str, Rate], factors: dict[tuple[str, str], float] | None = None) -> tuple[float, bool]:
    """A job's projected seconds, and whether every run in it was priced from measurements.

    ``factors`` (:func:`scenario_factors`) scale a learner's measured rate to each scenario."""
    factors = factors or {}
    total, measured = 0.0, True
    for run in job.runs:
        algo, budget = run.config["algo"]["name"], int(run.config["budget"])
        rate = rates.get(algo)
        if rate is None:
            measured = False
            total += run.est_seconds if job.engine == "single" else job.est_seconds / len(job.runs)
        else:
            total += rate.seconds_per_step * (budget if budget > 0 else 1) * factors.get((algo, run.config["scenario"]), 1.0)
    return total, measured


def report(results_dir: Path, preset: str, protocol: str, engine: str, workers: Sequence[int],
           extra: Sequence[str] = (), reference: Path | None = None, cpu_only: bool = False) -> str:
    """The measured rates and the projection (scenarios weighted by ``reference``'s sweep, if given), as Markdown."""
    rates = measured_rates(results_dir, protocol, preset, engine, cpu_only)
    factors = scenario_factors(reference, protocol, engine, rates) if reference else {}
    lines = _measured_table(results_dir, preset, protocol, engine, rates)
    with tempfile.TemporaryDirectory() as scratch:
        runs, sweep = table1_plan(preset, protocol, engine, Path(scratch), extra)  # composed and planned once for both tables
        lines += _against_plan_table(results_dir, preset, protocol, engine, plan_jobs(runs, sweep, workers[0]), workers[0])
        lines += _projected_table(preset, protocol, engine, workers, extra, rates, factors, runs, sweep)
    lines += ["", ("Each job is priced at the measured core-seconds per step of its learner times its runs' budgets "
                   "(evaluations included, as they are in each run's wall time); the workers take the jobs in the sweep's "
                   "order (longest estimated first), each as soon as it is free. The planner's estimate is what "
                   "`dry_run=true` prints for the same sweep.")]
    if factors:
        lines += _factors_table(reference, factors)
    return "\n".join(lines) + "\n"


def _measured_table(results_dir: Path, preset: str, protocol: str, engine: str, rates: dict[str, Rate]) -> list[str]:
    """One row per learner measured: its runs, the rows they came from, fleet sizes and cost per step."""
    lines = [f"### Measured: `{results_dir}` ({preset} preset, {protocol} protocol, engine {engine})", "",
             "| learner | runs | rows | fleet sizes | clock | core time | core-s per run per 1M steps |",
             "|---|---:|---|---|---|---:|---:|"]
    for algo, rate in sorted(rates.items()):
        per = f"per run: {rate.seconds_per_step:.1f} s" if rate.steps == rate.runs else f"{rate.seconds_per_step * 1e6:,.0f}"
        rows = "; ".join(rate.rows) if len(rate.rows) <= 3 else f"{len(rate.rows)} rows"
        clock = "CPU" if rate.cpu_runs == rate.runs else "wall" if rate.cpu_runs == 0 else f"CPU {rate.cpu_runs}, wall {rate.runs - rate.cpu_runs}"
        lines.append(f"| {learner_spec(algo).label} | {rate.runs} | {rows} | "
                     f"{', '.join(map(str, rate.fleet_sizes)) or 'single'} | {clock} | {duration(rate.core_seconds)} | {per} |")
    return lines


def planned_core_seconds(jobs: Sequence[Any]) -> dict[str, float]:
    """Each planned run's share of the planner's estimate: its own for a run trained alone, an equal
    share of its fleet's for one trained in a fleet (the planner prices a fleet as a whole)."""
    out: dict[str, float] = {}
    for job in jobs:
        for run in job.runs:
            out[run.run_id] = run.est_seconds if job.engine == "single" else job.est_seconds / len(job.runs)
    return out


def _against_plan_table(results_dir: Path, preset: str, protocol: str, engine: str, jobs: Sequence[Any],
                        workers: int) -> list[str]:
    """Per learner: the measured core time of its finished runs beside what the planner priced those
    same runs at (alone on an idle machine), and their ratio: how far this machine, in this session,
    is from the rates fitted in ``conf/algo``."""
    frame = finished_runs(results_dir, protocol, preset, engine)
    if frame.empty:
        return []
    priced = planned_core_seconds(jobs)
    lines = ["", f"### Against the planner: the same runs ({workers} workers' jobs)", "",
             "| learner | runs | measured core time | planner's estimate | measured / planned | runs not in the plan |",
             "|---|---:|---:|---:|---:|---:|"]
    measured = compute_seconds(frame)
    for algo, group in frame.groupby("algo"):
        known = group["run_id"].astype(str).isin(priced)
        ids = group.loc[known, "run_id"].astype(str)
        core, planned = float(measured[group.index[known]].sum()), float(sum(priced[i] for i in ids))
        ratio = f"{core / planned:.2f}" if planned > 0 else "—"
        lines.append(f"| {learner_spec(str(algo)).label} | {int(known.sum())} | {duration(core)} | {duration(planned)} | "
                     f"{ratio} | {int((~known).sum())} |")
    return lines


def _projected_table(preset: str, protocol: str, engine: str, workers: Sequence[int], extra: Sequence[str],
                     rates: dict[str, Rate], factors: dict[tuple[str, str], float], runs: list[Any],
                     sweep: Any) -> list[str]:
    """One row per worker count: the whole Table 1's jobs (``runs`` of ``sweep``) priced at the measured rates."""
    title = f" ({', '.join(extra)})" if extra else ""
    lines = ["", f"### Projected: the whole Table 1 ({preset} preset, {protocol} protocol, engine {engine}){title}", "",
             "| workers (cores) | runs | jobs | core time | projected wall time | planner's estimate | unmeasured learners |",
             "|---:|---:|---:|---:|---:|---:|---|"]
    for w in workers:
        jobs = plan_jobs(runs, sweep, w)
        priced = [job_seconds(j, rates, factors) for j in jobs]

        missing = sorted({a.spec.label for a in sweep.algos if a.spec.name not in rates})
        lines.append(f"| {w} | {sum(len(j.runs) for j in jobs):,} | {len(jobs)} | {duration(sum(p for p, _ in priced))} | "
                     f"**{duration(makespan((p for p, _ in priced), w))}** | {duration(jobs_estimate(jobs, set(), w))} | "
                     f"{', '.join(missing) or 'none'} |")
    return lines


def _factors_table(reference: Path | None, factors: dict[tuple[str, str], float]) -> list[str]:
    """The per-scenario cost factors taken from ``reference``, one row per learner."""
    scenarios = sorted({sc for _, sc in factors})
    lines = ["", (f"Each scenario's cost per step relative to the measured scenarios is that of `{reference}` "
                  "(same protocol and engine), per learner:"), "",
             "| learner | " + " | ".join(scenarios) + " |",
             "|---|" + "---:|" * len(scenarios)]
    for algo in sorted({a for a, _ in factors}):
        lines.append(f"| {learner_spec(algo).label} | "
                     + " | ".join(f"{factors.get((algo, sc), 1.0):.2f}" for sc in scenarios) + " |")
    return lines


def build_parser() -> argparse.ArgumentParser:
    """The command's parser, apart from parsing: the docs' command-line reference is generated from it."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.project_table1", description=__doc__.split("\n\n")[0])
    parser.add_argument("results_dir", type=Path,
                        help="a results directory or a results release holding finished runs of some Table 1 rows")
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--protocol", default="paper", choices=("paper", "corrected"))
    parser.add_argument("--engine", default="fleet", choices=("fleet", "single"))
    parser.add_argument("--workers", type=int, nargs="+", default=[2, 8])
    parser.add_argument("--set", dest="extra", action="append", default=[], metavar="KEY=VALUE",
                        help="a further sweep override for the projected plan, e.g. --set 'preset.seeds=[41,42,43]'")
    parser.add_argument("--relative-to", dest="reference", type=Path, metavar="RESULTS_DIR",
                        help="a sweep of every Table 1 scenario (e.g. the quick Table 1) whose per-scenario costs "
                             "weight the measured rates: the rows measured may be cheaper or dearer than the rest")
    parser.add_argument("--cpu-time-only", dest="cpu_only", action="store_true",
                        help="price only from runs that recorded their CPU time (not the wall time of older runs)")
    parser.add_argument("--out", type=Path, help="also write the Markdown here")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not readable(args.results_dir):
        parser.error(f"{args.results_dir}: not a results directory (no runs/) nor a results release (no release.json)")
    if any(w < 1 for w in args.workers):
        parser.error("--workers: each count must be >= 1")
    if args.reference is not None and not readable(args.reference):
        parser.error(f"--relative-to {args.reference}: not a results directory (no runs/) nor a results release (no release.json)")
    text = report(args.results_dir, args.preset, args.protocol, args.engine, args.workers, args.extra, args.reference,
                  args.cpu_only)
    print(text)
    if args.out:
        write_atomically(args.out, lambda fh: fh.write(text.encode()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
