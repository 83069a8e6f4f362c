"""The fleet's update engines side by side on a whole Table 1 row: eager vs compiled, CPU core time per learner.

Why a whole row: the issue's target (core time per learner down 2x) is about what a sweep pays, and
a sweep trains a row's runs as the fleet it forms from them (every variant x seed of the row, cut
to at most ``fleet_size`` runs): the fleet here is that one, formed by the sweep's own planner
(:func:`benchmarks.project_table1.table1_plan` and :func:`~benchmarks.project_table1.plan_jobs`,
i.e. :func:`runners.plan.fleets.make_jobs`), and built as the sweep builds it (:func:`~morality_gym.baselines.fleet.make_fleet`
with the run's resolved learner). Each learner is trained eager and compiled, one after the
other in the same process, on the same reduced budget (the ratio is per env step).

Core time is this process's CPU time plus its finished children's (``RUSAGE_CHILDREN``): inductor
runs the C++ compiler as a child process, whose CPU is part of the compile's cost; the benchmark
sets inductor's ``compile_threads`` to 1 so that the compiler is this process's direct child (a
compile worker pool would hide it).
"""

from __future__ import annotations

import os
import resource
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch._dynamo
import torch._inductor.config as inductor_config
from torch._inductor.utils import clear_caches, fresh_cache

from benchmarks import Context, Section, register
from benchmarks.project_table1 import plan_jobs, table1_plan
from morality_gym.baselines.fleet import FleetRun, compiled, make_fleet
from morality_gym.baselines.specs import learner_spec

#: The Table 1 row (chain, scenario) every learner is trained on: its sweep fleet holds all 10
#: variants x seeds 41-43 (K = 30), a typical row's size (Table 1's rows hold 15 to 36 runs).
ROW = ("DualProcess", "PushOrSwitch")
#: (learner, rollouts per training): about 0.5-1M env steps of the whole fleet per training.
LEARNERS: tuple[tuple[str, int], ...] = (("ppo", 2), ("ppo_shaped", 2), ("ppo_lag", 16), ("cpo", 8))
#: The compiled step function each learner's updates run (learners sharing one share its kernels).
STEP = {"ppo": "ppo_step", "ppo_shaped": "ppo_step", "ppo_lag": "lag_step", "cpo": "critic_step"}
TARGET = 2.0
#: The paper preset's budget of the row (env steps per run), for the compile-included projection.
PAPER_BUDGET = 1_000_000


def core_seconds() -> float:
    """CPU seconds of this process and of its children that have finished (the C++ compiler)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


@dataclass
class Phases:
    """Core seconds of one training, split where the update functions are entered."""

    total: float = 0.0
    update: float = 0.0  # inside ``_train`` (every learner's update)
    critics: float = 0.0  # inside ``_train_critics`` (PPO-Lag's and CPO's critic passes; CPO's actor step is update - critics)
    marks: list[float] = field(default_factory=list)


def _timed(phases: Phases, attr: str, fn: Callable[[], Any]) -> Callable[[], Any]:
    def run() -> Any:
        t0 = core_seconds()
        try:
            return fn()
        finally:
            setattr(phases, attr, getattr(phases, attr) + core_seconds() - t0)

    return run


def row_fleets(learners: Sequence[str], chain: str, scenario: str, quick: bool) -> dict[str, list[tuple[Any, list[Any]]]]:
    """Per learner, the fleets a paper Table 1 sweep forms of the row ``(chain, scenario)``:
    ``(resolved spec, [FleetRun, ...])`` each, with the protocol and ``max_steps`` of its runs.
    ``quick``: the first 3 runs of each fleet only (a smoke check)."""
    with tempfile.TemporaryDirectory() as scratch:
        runs, sweep = table1_plan("paper", "paper", "fleet", Path(scratch))
        jobs = plan_jobs(runs, sweep, 2)
    out: dict[str, list[tuple[Any, list[Any]]]] = {name: [] for name in learners}
    for job in jobs:
        c = job.runs[0].config
        if job.engine != "fleet" or c.algo.name not in out or c.scenario != scenario:
            continue
        if c.bound_chain().chain.name != chain:
            continue
        configs = [r.config for r in job.runs][: 3 if quick else None]
        out[c.algo.name].append((c, [FleetRun(x.bound_chain(), x.seed) for x in configs]))
    missing = [name for name, fleets in out.items() if not fleets]
    if missing:
        raise RuntimeError(f"the Table 1 plan has no fleet of {', '.join(missing)} on ({chain}, {scenario})")
    return out


def _distinct_share(obs: np.ndarray, batch: int, rng: np.random.Generator) -> float:
    """The mean share of distinct observations in a run's minibatches of ``batch`` (random order):
    the most a minibatch's forward pass on its distinct states only could save of its rows."""
    rows = obs.view(np.dtype((np.void, obs.dtype.itemsize * obs.shape[1])))[:, 0]
    order = rng.permutation(len(rows))
    blocks = [rows[order[i : i + batch]] for i in range(0, len(rows) - batch + 1, batch)]
    return float(np.mean([len(np.unique(b)) / batch for b in blocks]))


@dataclass
class Trained:
    """One learner's trainings on the row: phases per engine, compile overheads, steps."""

    label: str
    k: int
    steps_per_run: int
    eager: Phases
    steady: Phases
    first: float
    cached: float
    batched: Phases | None = None  # CPO only: compiled, with the batched actor step (:mod:`.cpo_batch`)


def _train(fleets: list[tuple[Any, list[Any]]], rollouts: int, update: str, batched_actor: bool = False) -> tuple[Phases, Any]:
    """Train each fleet of the row on ``rollouts`` rollouts with the ``update`` engine; building
    untimed. Returns the summed phases and the last fleet trained."""
    phases, fleet = Phases(), None
    for config, runs in fleets:
        spec = config.algo
        fleet = make_fleet(spec, runs, config.protocol, max_steps=config.max_steps, update=update)
        if batched_actor:
            fleet.batched_actor_step = True
        fleet._train = _timed(phases, "update", fleet._train)
        if hasattr(fleet, "_train_critics"):
            fleet._train_critics = _timed(phases, "critics", fleet._train_critics)
        budget = int(spec.hparams["n_steps"]) * spec.n_envs * rollouts
        t0 = core_seconds()
        fleet.learn(budget)
        phases.total += core_seconds() - t0
    return phases, fleet


def measure(name: str, fleets: list[tuple[Any, list[Any]]], rollouts: int, quick: bool) -> tuple[Trained, Any]:
    """Train ``name``'s row fleets: eager, compiled into an empty cache (first), compiled again
    after ``torch._dynamo.reset()`` with the kernels on disk (cached), compiled with the graphs in
    memory (steady); for CPO also compiled with the batched actor step."""
    inductor_config.compile_threads = 1  # the C++ compiler a direct child: its CPU is counted (module docstring)
    eager, _ = _train(fleets, rollouts, "eager")
    with fresh_cache():  # an empty inductor cache, in memory and on disk: a cold compile
        torch._dynamo.reset()
        compiled._compiled.cache_clear()
        first, _ = _train(fleets, rollouts, "compiled")
        torch._dynamo.reset()
        compiled._compiled.cache_clear()
        clear_caches()  # what a new process has: nothing in memory, the kernels on disk
        cached, _ = _train(fleets, rollouts, "compiled")
        steady, fleet = _train(fleets, rollouts, "compiled")
        batched = _train(fleets, rollouts, "compiled", batched_actor=True)[0] if name == "cpo" else None
    spec = learner_spec(name)
    k = sum(len(runs) for _, runs in fleets)
    steps = int(spec.hparams["n_steps"]) * spec.n_envs * rollouts
    label = spec.label + (" (3 runs of the row: quick)" if quick else "")
    return Trained(label, k, steps, eager, steady, first.total - steady.total, cached.total - steady.total, batched), fleet


@register("fleet_compiled", "Fleet update engines on a whole Table 1 row: eager vs compiled, CPU core time per learner", order=77)
def fleet_compiled(ctx: Context) -> Section:
    torch.set_num_threads(1)
    chain, scenario = ROW
    load_start = os.getloadavg()[0]
    fleets = row_fleets([n for n, _ in LEARNERS], chain, scenario, ctx.quick)
    task = ctx.task("fleet_compiled", len(LEARNERS))
    results: list[Trained] = []
    shares: list[float] = []
    for name, rollouts in LEARNERS:
        trained, fleet = measure(name, fleets[name], 1 if ctx.quick else rollouts, ctx.quick)
        results.append(trained)
        if name == "ppo":
            rng = np.random.default_rng(0)
            batch = int(learner_spec("ppo").hparams["batch_size"])
            shares = [_distinct_share(fleet.rollout.obs[r].numpy(), batch, rng) for r in range(fleet.n_runs)]
        task.advance()
    task.done()
    return _section(results, shares, ctx.quick, (load_start, os.getloadavg()[0]))


def _per_1m(t: Trained, seconds: float) -> float:
    return seconds * 1e6 / (t.k * t.steps_per_run)


def _section(results: list[Trained], shares: list[float], quick: bool, load: tuple[float, float]) -> Section:
    rows, ratios, profile = [], [], []
    for t in results:
        eager, steady = _per_1m(t, t.eager.total), _per_1m(t, t.steady.total)
        ratio = eager / steady
        ratios.append((t.label, ratio))
        # the paper row at 1M steps per run, one process: eager vs compiled with a cold compile paid once
        row_eager_h = eager * t.k / 3600
        row_compiled_h = (steady * t.k + t.first) / 3600
        rows.append([
            t.label, str(t.k), f"{t.steps_per_run:,}", f"{eager:.1f}", f"{steady:.1f}", f"**{ratio:.2f}x**",
            f"{_per_1m(t, t.eager.update):.1f}", f"{_per_1m(t, t.steady.update):.1f}", f"{t.eager.update / t.steady.update:.2f}x",
            f"{_per_1m(t, t.eager.total - t.eager.update):.1f}", f"{_per_1m(t, t.steady.total - t.steady.update):.1f}",
            f"{t.first:.1f}", f"{t.cached:.1f}", f"{row_eager_h:.2f} / {row_compiled_h:.2f} ({row_eager_h / row_compiled_h:.2f}x)",
        ])
        parts = [f"rollouts and the rest {100 * (t.steady.total - t.steady.update) / t.steady.total:.0f}%"]
        if t.steady.critics:
            actor = t.steady.update - t.steady.critics
            parts += [f"critic passes {100 * t.steady.critics / t.steady.total:.0f}%",
                      f"{'actor step' if 'CPO' in t.label else 'the rest of the update'} {100 * actor / t.steady.total:.0f}%"]
        else:
            parts.append(f"update {100 * t.steady.update / t.steady.total:.0f}%")
        profile.append(f"{t.label}: " + ", ".join(parts))
    met = sum(r >= TARGET for _, r in ratios)
    notes = [
        (f"Target (issue 47): core time per learner down {TARGET:.0f}x on whole rows for PPO, PPO Shaped and CPO: met by "
         f"{met} of {len(ratios)} learners (" + ", ".join(f"{label} {r:.2f}x" for label, r in ratios) + "), steady state, "
         "compile not included; the last column includes one cold compile per learner."
         + (" A quick run on 3 runs of the row and one rollout: smoke figures, not a row's." if quick else "")),
        "Where the compiled engine's core time goes (steady trainings): " + "; ".join(profile) + ".",
    ]
    noisy = [t.label for t in results if t.cached < 0]
    notes.append(
        f"Load average (1 min) {load[0]:.2f} at the start and {load[1]:.2f} at the end, on {os.cpu_count()} logical CPUs"
        + (f"; {', '.join(noisy)}: the cached training took less core time than the steady one, so differences of that "
           "size (about 10%) are this run's noise, not the engines'." if noisy else ".")
    )
    cpo = next((t for t in results if t.batched is not None), None)
    if cpo is not None and cpo.batched is not None:
        per_run = _per_1m(cpo, cpo.steady.update - cpo.steady.critics)
        batched = _per_1m(cpo, cpo.batched.update - cpo.batched.critics)
        notes.append(
            f"CPO's actor step, the part the compiled engine leaves eager: {per_run:.1f} core-s / run / 1M on the per-run path "
            f"(the CPU's default, which keeps the releases' bits) against {batched:.1f} with the batched actor step "
            f"(`FleetCPO.batched_actor_step = True`, `fleet/cpo_batch.py`, the accelerators' default, other float rounding), "
            f"{per_run / batched:.2f}x; the whole CPO training compiled with it: "
            f"{_per_1m(cpo, cpo.batched.total):.1f} core-s / run / 1M, {_per_1m(cpo, cpo.eager.total) / _per_1m(cpo, cpo.batched.total):.2f}x eager."
        )
    if shares:
        notes.append(
            f"Repeated states in PPO's minibatches (this row, the last rollout of the steady training): a minibatch of "
            f"{int(learner_spec('ppo').hparams['batch_size'])} transitions holds on average {100 * float(np.mean(shares)):.0f}% "
            f"distinct observations (runs' range {100 * min(shares):.0f}-{100 * max(shares):.0f}%); a forward pass on those "
            "only would save at most the complement of its rows, but needs a data-dependent shape, which the compiled "
            "steps refuse (not built)."
        )
    chain, scenario = ROW
    return Section(
        intro=f"""
The Table 1 row ({chain}, {scenario}) as a paper-preset sweep trains it: the fleet its planner forms of the row's
runs (every variant x seeds 41-43, `fleet_size` 36 on the CPU: one fleet of K runs; `runners.plan.fleets.make_jobs`),
built as the sweep builds it (`make_fleet` with the runs' resolved learner and protocol), paper protocol, torch on
one thread. Each learner is trained on a reduced budget (the steps per run below, a few rollouts instead of the
paper's 1M; the ratio is per env step), in one process, in this order: eager (`update=eager`, the default, which
reruns the releases bit for bit), compiled into an empty compile cache (first), compiled after
`torch._dynamo.reset()` with its kernels on disk (cached: what a later process of a sweep pays), and compiled
with the graphs in memory (steady: what a later fleet of the same process pays). Core seconds are this process's
CPU time plus its children's (the C++ compiler inductor runs; `compile_threads=1`), so the compile's cost is
counted; learn-time evaluations are not included (they do not depend on the engine). "core-s / run / 1M": core
seconds per run per million env steps of the whole training; "update": inside the learner's update (`_train`),
"rest": the rollouts and everything else. Compile overheads are the first and cached trainings' extra core seconds
over the steady one. The last column prices the row at the paper budget (1M steps per run) in one process: eager
against compiled steady plus one cold compile. The compiled engine compiles PPO's and PPO-Lag's minibatch steps
and CPO's critic steps (`morality_gym/baselines/fleet/compiled.py`); CPO's actor step stays eager.
""",
        headers=["learner", "runs K", "steps per run", "eager core-s / run / 1M", "compiled core-s / run / 1M", "speed-up",
                 "eager update", "compiled update", "update speed-up", "eager rest", "compiled rest",
                 "compile s (first)", "compile s (cached)", "row at 1M steps, core-h eager / compiled incl. compile"],
        rows=rows,
        notes=notes,
        compare=["eager core-s / run / 1M", "compiled core-s / run / 1M"],
    )
