"""The sweep's time estimate, in one place: rates, interpolation, sharing, machine load and notes.

Why a room of its own: the estimate never changes what runs (no run id, no result depends on
it), yet it used to be spread over six files, so that the configuration priced learners and the
job cutter priced fleets. Here, in the order a plan uses them:

1. **Rates** (:class:`Planning`, :class:`DeviceRate`, ...): the schema of ``planning`` in each algo
   file (typed by Hydra through :mod:`runners.compose.schema`), resolved for one learner under one
   protocol by :func:`learner_rates` (:class:`PlanningError` names the key and where it came from).
2. **Runs and jobs**: a run costs its overhead plus its training steps at the learner's rate
   (:func:`run_seconds`); a fleet shares only the training, at the measured fleet speed-up
   (:func:`fleet_seconds`) or at its measured rate on an accelerator (:func:`device_price`, with
   :func:`device_fleet_rate` interpolating between measured sizes).
3. **Wall time**: the jobs handed to the workers longest first (:func:`dispatch_order`), as the
   local pool hands them out (:func:`makespan`; fleets sharing one device: :func:`shared_makespan`,
   each at :func:`device_share` of it), plus what the sweep pays once (:class:`SweepOverheads`).
4. **The machine's load** (:class:`MachineLoad`, :func:`load_factor`): how much longer the same
   work takes on a machine that is already busy, and the printed :class:`Estimate`.
5. **Notes** (:func:`device_estimate_note`): what the figure is worth on an accelerator.

The rates are measured, not guessed: each algo file states its fitted values, BENCHMARKS.md
and benchmarks/gpu_check.sh measure the fleet's, and ``python -m benchmarks.project_table1``
holds the whole estimate against measured sweeps.
"""

from __future__ import annotations

import heapq
import math
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from morality_gym.baselines import typed
from morality_gym.baselines.specs import DEFAULT_UPDATE_ENGINE, LearnerSpec
from morality_gym.clitools import did_you_mean, duration
from runners.record.mlflow_mirror import tracking_uri


# ------------------------------------------------------------------------------------------ rates
@dataclass(frozen=True)
class DeviceRate:
    """How fast one learner's fleets train on an accelerator, as measured (benchmarks/gpu_check.sh).

    Why its own table and not a factor on the CPU rate: on a GPU a fleet's rate grows with its
    size (one process is bound by launching small kernels, not by arithmetic), and several
    processes sharing the device add up to less than their sum. ``fleet_steps_per_s``: env steps
    per second of one process training a fleet of K runs, by K, with the algo file's settings;
    ``processes``: the aggregate rate of N processes sharing the device over one process's, by N
    (1 process: 1); ``measured_on``: the card and the date, printed with the estimate, since
    another card trains at another speed.

    ``compiled_gain`` and ``compiled_processes``, for sweeps with ``fleet_update=compiled``: one
    process's rate with the compiled update over the eager one's, by the fleet sizes where both
    were measured, and the aggregate of N processes over one with it (the compiled update frees
    the host, so processes share the card differently). A learner without them is priced at its
    eager rates, and the plan says so (:func:`device_estimate_note`).
    """

    measured_on: str = ""
    fleet_steps_per_s: Mapping[int, float] = field(default_factory=dict)
    processes: Mapping[int, float] = field(default_factory=dict)
    compiled_gain: Mapping[int, float] = field(default_factory=dict)
    compiled_processes: Mapping[int, float] = field(default_factory=dict)

    def for_update(self, update: str) -> DeviceRate:
        """The rates of fleets whose update runs on the ``update`` engine: eager as measured; compiled
        as eager times the measured gain (interpolated in log K between the sizes where it was
        measured, held beyond them), with the compiled processes' sharing."""
        if update != "compiled" or not self.compiled_gain:
            return self
        gains = {math.log(k): g for k, g in self.compiled_gain.items()}
        rates = {k: v * _interpolate(gains, math.log(k)) for k, v in self.fleet_steps_per_s.items()}
        return DeviceRate(self.measured_on, rates, self.compiled_processes or self.processes)


@dataclass(frozen=True)
class PlanningOverride:
    """Some of :class:`Planning`'s values, replaced under one protocol (unset: the algo's own)."""

    steps_per_s: float | None = None
    update_share: float | None = None
    overhead_s: float | None = None
    fleet_speedup: float | None = None
    devices: Mapping[str, DeviceRate] | None = None  # per device, replacing the algo's rate on that device


@dataclass(frozen=True)
class Planning:
    """The sweep plan's time estimate for one learner (never part of a run's identity).

    ``steps_per_s``: training steps per second with the algo file's own settings, one thread;
    ``update_share``: the part of a step's time that is gradient work (scales with the epochs);
    ``overhead_s``: what every run pays regardless of its budget; ``fleet_speedup``: the fleet
    engine's measured gain at K >= 12 over single runs (1: no gain assumed); ``devices``: the
    fleets' measured rates on an accelerator, by device type (``cuda``), for ``device=`` sweeps
    (a learner without one is priced at its CPU rate, and the plan says so). The defaults are a
    guess for a learner nobody measured; each built-in algo file states its fitted values.
    """

    steps_per_s: float = 2000.0
    update_share: float = 1.0
    overhead_s: float = 1.0
    fleet_speedup: float = 1.0
    devices: Mapping[str, DeviceRate] = field(default_factory=dict)
    protocols: Mapping[str, PlanningOverride] = field(default_factory=dict)


@dataclass(frozen=True)
class SweepOverheads:
    """What a sweep pays once, besides its runs, for the plan's time estimate (never part of a run's identity).

    The per-learner :class:`Planning` prices the runs (its ``overhead_s`` is what each run pays);
    a smoke sweep's runs take seconds, and its estimate was 2-8x below the wall time because these
    once-per-sweep costs were left out. ``new_store_s``: creating the MLflow store of a new results
    directory (its SQLite schema migrations, before the first run); ``worker_start_s``: the
    workers starting (imports of torch and SB3; they start in parallel). Mirroring runs into MLflow
    happens in the sweep's process while the workers train, so it is not added. Measured on this
    2-core machine on 2026-11-25 while another sweep ran (load 2.3-3.1): 7.2-8.0 s and 1.85-1.94 s.
    """

    new_store_s: float = 7.5
    worker_start_s: float = 1.9

    def seconds(self, n_runs: int, *, new_store: bool, mlflow: bool) -> float:
        """The overhead of a sweep with ``n_runs`` runs to do (nothing when none is left)."""
        if n_runs == 0:
            return 0.0
        return self.worker_start_s + (self.new_store_s if new_store and mlflow else 0.0)


class PlanningError(ValueError):
    """A ``planning`` block that cannot price its learner; the message says which key and where.
    (:mod:`runners.compose.sweep_config` reports it as a configuration error.)"""


@dataclass(frozen=True)
class LearnerRates:
    """One learner's resolved planning rates, under the sweep's protocol and with its settings."""

    steps_per_s: float  # training steps per second per worker
    overhead_s: float  # what each run pays whatever it trains
    fleet_speedup: float = 1.0  # measured speed-up of the fleet engine at K >= 12
    device_rates: Mapping[str, DeviceRate] = field(default_factory=dict)  # by device type, scaled to the spec


_PLANNING_KEYS = set(typed.valid_keys(Planning)) - {"protocols"}
_DEVICE_RATE_KEYS = set(typed.valid_keys(DeviceRate))


def planning_where(where: str, option: str, overrides: Sequence[str]) -> str:
    """Where an algo's planning values come from: its file, and the command-line overrides that
    change them (a bad value given there must not be blamed on the file)."""
    prefix = f"algo.{option}.planning"
    given = [o for o in overrides if o.lstrip("+~").startswith(prefix)]
    return f"{where} with {', '.join(given)}" if given else where


def learner_rates(where: str, planning: Mapping[str, Any], file_values: Mapping[str, Any], spec: LearnerSpec,
                  protocol: str | None = None) -> LearnerRates:
    """``planning`` (an algo file's block, as composed) resolved for ``spec`` under ``protocol``."""
    steps_per_s, overhead, speedup = planning_rate(where, planning, file_values, spec, protocol)
    return LearnerRates(steps_per_s, overhead, speedup, _device_rates(where, planning, file_values, spec, protocol))


def planning_rate(where: str, planning: Mapping[str, Any], file_values: Mapping[str, Any],
                  spec: LearnerSpec, protocol: str | None = None) -> tuple[float, float, float]:
    """Training steps per second, fixed seconds per run and the fleet speed-up, for the plan's estimate.

    ``planning.steps_per_s`` is measured with the algorithm file's own settings. Only part of a
    training step's time is gradient work (``update_share``); that part scales with the number of
    update epochs per rollout, the rest (simulation, rollout bookkeeping) does not. Scaling the
    whole rate by the epoch ratio, as a first version did, made the smoke preset (2 epochs
    instead of 10-40) look 2.7x slower than it ran. ``overhead_s`` covers what every run pays
    regardless of its budget: building the envs, the final and exact evaluations, the GIF, writes.

    ``planning.protocols.<protocol>`` replaces some of these values under one protocol: a protocol
    can change a learner's speed by an order of magnitude (PPO-Lag's early stop ends its update
    after one pass under ``paper`` and after up to 40 under ``corrected``). ``fleet_speedup`` is
    the fleet engine's measured gain at K >= 12 (BENCHMARKS.md), used by :func:`fleet_seconds`.
    """
    steps_per_s, share, overhead, speedup = _planning_values(where, _planning_for(where, planning, protocol))
    return steps_per_s / _epoch_factor(file_values, spec, share), overhead, speedup


def _epoch_factor(file_values: Mapping[str, Any], spec: LearnerSpec, share: float) -> float:
    """How much longer a training step takes with ``spec``'s update epochs than with the algo
    file's, at which the rates were measured: only the update's ``share`` of a step scales."""
    ratio = 1.0
    for key in ("n_epochs", "n_critic_updates"):
        reference, actual = file_values.get("hparams", {}).get(key), spec.hparams.get(key)
        if reference and actual:
            ratio *= actual / reference
    return (1.0 - share) + share * ratio


def _device_rates(where: str, planning: Mapping[str, Any], file_values: Mapping[str, Any], spec: LearnerSpec,
                  protocol: str | None = None) -> dict[str, DeviceRate]:
    """``planning.devices`` under ``protocol``, each checked by :func:`_device_rate` and scaled by
    the epochs as the CPU rate is (the GPU's update share is not measured apart)."""
    planning = _planning_for(where, planning, protocol)
    factor = _epoch_factor(file_values, spec, _planning_values(where, planning)[1])
    return {str(device): _device_rate(f"{where}: planning.devices.{device}", given, factor)
            for device, given in dict(planning.get("devices") or {}).items()}


def _device_rate(at: str, given: Mapping[str, Any], factor: float) -> DeviceRate:
    """One device's rates checked (sizes and process counts >= 1, rates > 0), divided by ``factor``.

    Not a mapping at all cannot reach here: the typed schema (DeviceRate) refuses it while composing."""
    for key in set(given) - _DEVICE_RATE_KEYS:  # a typo would silently price the device at nothing measured
        raise PlanningError(f"{at}: unknown key {key!r}{did_you_mean(str(key), sorted(_DEVICE_RATE_KEYS))}; "
                            f"valid: {sorted(_DEVICE_RATE_KEYS)}")
    rates = _positive_table(at, given, "fleet_steps_per_s", "at least one fleet size >= 1 with a rate > 0")
    if not rates:
        raise PlanningError(f"{at}.fleet_steps_per_s needs at least one fleet size >= 1 with a rate > 0, got {rates}")
    processes = _positive_table(at, given, "processes", "process counts >= 1 with aggregate factors > 0")
    gain = _positive_table(at, given, "compiled_gain", "fleet sizes >= 1 with a compiled/eager ratio > 0")
    shared = _positive_table(at, given, "compiled_processes", "process counts >= 1 with aggregate factors > 0")
    return DeviceRate(str(given.get("measured_on") or ""), {k: v / factor for k, v in rates.items()}, processes, gain, shared)


def _positive_table(at: str, given: Mapping[str, Any], key: str, needs: str) -> dict[int, float]:
    """``given[key]`` as {int: float}, sorted, every key >= 1 and every value > 0 (empty if not given)."""
    try:
        table = {int(k): float(v) for k, v in dict(given.get(key) or {}).items()}
    except (TypeError, ValueError, AttributeError) as exc:
        raise PlanningError(f"{at}: fleet sizes, process counts and rates must be numbers ({exc})") from exc
    if table and (min(table) < 1 or min(table.values()) <= 0):
        raise PlanningError(f"{at}.{key} needs {needs}, got {table}")
    return dict(sorted(table.items()))


def _planning_for(where: str, planning: Mapping[str, Any], protocol: str | None) -> dict[str, Any]:
    """The algo's planning values with those of ``planning.protocols.<protocol>`` over them."""
    planning = dict(planning)
    by_protocol = planning.pop("protocols", None) or {}
    if not isinstance(by_protocol, Mapping):
        raise PlanningError(f"{where}: planning.protocols must map protocol names to planning values, got {by_protocol!r}")
    if protocol is not None and protocol in by_protocol:
        chosen = by_protocol[protocol]
        if not isinstance(chosen, Mapping):
            raise PlanningError(f"{where}: planning.protocols.{protocol} must be a mapping, got {chosen!r}")
        devices = {**dict(planning.get("devices") or {}), **dict(chosen.get("devices") or {})}  # per device
        planning.update({k: v for k, v in chosen.items() if v is not None})  # unset: the algo's own value
        planning["devices"] = devices
    unknown = set(planning) - _PLANNING_KEYS
    if unknown:
        raise PlanningError(f"{where}: unknown planning key(s) {sorted(unknown)}; valid: {sorted(_PLANNING_KEYS | {'protocols'})}")
    return planning


def _planning_values(where: str, planning: Mapping[str, Any]) -> tuple[float, float, float, float]:
    """``steps_per_s``, ``update_share``, ``overhead_s`` and ``fleet_speedup`` as numbers in range
    (:class:`Planning`'s defaults for those not given)."""
    default = Planning()
    try:
        steps_per_s = float(planning.get("steps_per_s", default.steps_per_s))
        share = float(planning.get("update_share", default.update_share))
        overhead = float(planning.get("overhead_s", default.overhead_s))
        speedup = float(planning.get("fleet_speedup", default.fleet_speedup))
    except (TypeError, ValueError) as exc:
        raise PlanningError(f"{where}: planning values must be numbers ({exc})") from exc
    if steps_per_s <= 0 or not 0.0 <= share <= 1.0 or overhead < 0 or speedup < 1.0:
        raise PlanningError(f"{where}: planning needs steps_per_s > 0, 0 <= update_share <= 1, overhead_s >= 0, "
                            f"fleet_speedup >= 1; got {dict(planning)}")
    return steps_per_s, share, overhead, speedup


# ----------------------------------------------------------------------------------- runs and jobs
class PricedRun(Protocol):
    """What the estimate reads of a planned run (:class:`runners.plan.runs.PlannedRun`)."""

    @property
    def run_id(self) -> str: ...
    @property
    def est_seconds(self) -> float: ...
    @property
    def overhead_s(self) -> float: ...
    @property
    def train_steps(self) -> int: ...


@dataclass(frozen=True)
class DeviceWork:
    """The part of a job that trains on a shared accelerator: its seconds alone on the device, and
    how the device's aggregate rate grows with the processes sharing it (``DeviceRate.processes``).
    The rest of the job's ``est_seconds`` (its runs' evaluations and writes) is CPU time."""

    alone_s: float
    processes: tuple[tuple[int, float], ...] = ()  # (N, aggregate of N processes over one's), hashable


class PricedJob(Protocol):
    """What the estimate reads of a job (:class:`runners.plan.fleets.Job`)."""

    @property
    def runs(self) -> Sequence[PricedRun]: ...
    @property
    def est_seconds(self) -> float: ...
    @property
    def device(self) -> DeviceWork | None: ...


def run_seconds(rates: LearnerRates, train_steps: int) -> float:
    """One run alone on a core: what every run pays, plus its training steps at the learner's rate."""
    return rates.overhead_s + train_steps / max(rates.steps_per_s, 1e-9)


def fleet_speedup(measured: float, size: int) -> float:
    """The planning speed-up of a fleet of ``size`` runs from the speed-up ``measured`` at K >= 12.

    BENCHMARKS.md's fleet section shows the gain saturating by K = 12 (K = 12 and K = 36 within
    10-40% of each other); below 12 it is taken to grow linearly from 1 at K = 1. An estimate for
    the plan's time only; it never changes what runs.
    """
    if size <= 1:
        return 1.0
    return 1.0 + (max(measured, 1.0) - 1.0) * min(1.0, (size - 1) / 11)


def fleet_seconds(runs: Sequence[PricedRun], measured_speedup: float) -> float:
    """A fleet of ``runs`` on the CPU: only the training is shared (at :func:`fleet_speedup`); each
    run's evaluations and writes stay its own."""
    overhead = sum(r.overhead_s for r in runs)
    return overhead + (sum(r.est_seconds for r in runs) - overhead) / fleet_speedup(measured_speedup, len(runs))


def _interpolate(points: Mapping[float, float], x: float) -> float:
    """Piecewise-linear through the measured ``points``, held flat beyond the last one."""
    xs = sorted(points)
    if x >= xs[-1]:
        return points[xs[-1]]
    upper = next(k for k in xs if k >= x)
    lower = max((k for k in xs if k <= x), default=upper)
    if upper == lower:
        return points[upper]
    return points[lower] + (points[upper] - points[lower]) * (x - lower) / (upper - lower)


def device_fleet_rate(rate: DeviceRate, size: int) -> float:
    """Env steps per second of one fleet of ``size`` runs alone on the device.

    Between measured fleet sizes the rate is interpolated in log-log; below the smallest it falls
    in proportion to the size (a launch-bound process steps K envs for the price of one launch),
    above the largest it is held (no gain assumed that was not measured). An estimate for the
    plan's time only; it never changes what runs.
    """
    sizes = sorted(rate.fleet_steps_per_s)
    if size <= sizes[0]:
        return rate.fleet_steps_per_s[sizes[0]] * size / sizes[0]
    return math.exp(_interpolate({math.log(k): math.log(v) for k, v in rate.fleet_steps_per_s.items()}, math.log(size)))


def device_price(runs: Sequence[PricedRun], rate: DeviceRate) -> tuple[float, DeviceWork]:
    """A fleet of ``runs`` on an accelerator: its training steps at the fleet's rate alone on the
    device (shared with other workers' fleets in :func:`jobs_estimate`), plus its runs' overheads
    (evaluated on the CPU, one by one, as everywhere). Returns the seconds and the device's part."""
    alone = sum(r.train_steps for r in runs) / device_fleet_rate(rate, len(runs))
    return sum(r.overhead_s for r in runs) + alone, DeviceWork(alone, tuple(sorted(rate.processes.items())))


def device_share(processes: Mapping[int, float], sharing: int) -> float:
    """The speed of each of ``sharing`` processes on one device, as a fraction of one alone:
    the measured aggregate (linear between measured process counts, held beyond) split equally."""
    n = max(1, sharing)
    return _interpolate({1: 1.0, **processes}, n) / n


# ------------------------------------------------------------------------------------- wall time
def dispatch_order(jobs: Sequence[Any], workers: int) -> list[Any]:
    """The jobs in the order workers take them: longest (estimated) first when several run at once.

    Handed out in plan order, a long fleet planned last keeps one worker busy after the others
    have finished: on the quick Table 1 with 32 workers, 1m56s instead of 1m12s, and 5-10 % on 2-8
    workers (``python -m benchmarks.project_table1``). Longest-first (LPT) scheduling bounds that
    tail by the longest job. One worker keeps the plan's order, so results arrive row by row.
    """
    if workers <= 1:
        return list(jobs)
    return sorted(jobs, key=lambda job: -job.est_seconds)  # stable: equal estimates keep plan order


def makespan(durations: Iterable[float], workers: int) -> float:
    """Wall time when ``workers`` take jobs of these ``durations`` in order, each the next job as soon as it is free."""
    free = [0.0] * max(1, workers)
    for d in durations:
        heapq.heappush(free, heapq.heappop(free) + d)
    return max(free)


def jobs_estimate(jobs: Sequence[PricedJob], done: set[str], workers: int) -> float:
    """Wall-time estimate of what remains: the jobs' seconds (scaled by the share of each job still
    to run) handed to ``workers`` in :func:`dispatch_order`, as the local pool hands them out;
    fleets on a shared device train at the device's share (:func:`shared_makespan`)."""
    remaining = []
    for job in dispatch_order(jobs, workers):
        todo = sum(r.run_id not in done for r in job.runs)
        if todo:
            part = todo / len(job.runs)
            device = job.device or DeviceWork(0.0)
            remaining.append((device.alone_s * part, (job.est_seconds - device.alone_s) * part, dict(device.processes)))
    if not any(device_s for device_s, _, _ in remaining):
        return makespan([device_s + cpu_s for device_s, cpu_s, _ in remaining], workers)
    return shared_makespan(remaining, workers)


def shared_makespan(jobs: Sequence[tuple[float, float, Mapping[int, float]]], workers: int) -> float:
    """Wall time of jobs ``(device_s, cpu_s, processes)``, taken in order by ``workers``, each
    training first on one shared device (``device_s`` alone on it) and then working ``cpu_s`` on
    its own core.

    Why a simulation and not one price per job: how fast a fleet trains depends on how many others
    share the device at that moment (:func:`device_share`), and that changes as fleets finish and
    the last ones train on a device of their own. Processor sharing, advanced from one job's phase
    end to the next (:func:`_advance`)."""
    queue = list(jobs)[::-1]
    active: list[list[Any]] = []  # [device_s left, cpu_s left, processes]
    clock = 0.0
    while queue or active:
        while queue and len(active) < max(1, workers):
            active.append(list(queue.pop()))
        clock += _advance(active)
        active = [a for a in active if a[0] > 0 or a[1] > 1e-9]
    return clock


def _advance(active: list[list[Any]]) -> float:
    """Advance the ``active`` jobs to the next end of a phase (in place); returns the time taken."""
    sharing = sum(a[0] > 0 for a in active)
    speeds = [device_share(a[2], sharing) if a[0] > 0 else 1.0 for a in active]
    step = min(a[0] / s if a[0] > 0 else a[1] for a, s in zip(active, speeds, strict=True))
    for a, s in zip(active, speeds, strict=True):
        if a[0] > 0:
            a[0] = a[0] - step * s if a[0] - step * s > 1e-9 * (1 + a[0]) else 0.0
        else:
            a[1] -= step
    return step


def sweep_overheads(results_dir: Path, mlflow: bool, n_todo: int) -> float:
    """Seconds the sweep spends besides training its runs (:class:`SweepOverheads`): a new MLflow
    store is created when the tracking URI names a SQLite file that does not exist yet."""
    uri = tracking_uri(results_dir)
    new_store = uri.startswith("sqlite:///") and not Path(uri.removeprefix("sqlite:///")).exists()
    return SweepOverheads().seconds(n_todo, new_store=new_store, mlflow=mlflow)


# ---------------------------------------------------------------------------------- machine load
@dataclass(frozen=True)
class MachineLoad:
    """The machine's cores and its load average when the plan was made.

    Why: the plan prices each run as if its worker had a core to itself (``planning`` in each
    algo file, fitted on an idle machine). On a shared 2-core machine a smoke Table 1 estimated
    at 3m26s took 8m48s under a load average of 3 (issue 36): the two workers shared the cores
    with other processes. So the plan states two figures: the idle estimate and the one at the
    load the machine has when the sweep starts (:func:`load_factor`). Measured on 2026-11-26 on a
    2-core machine shared with two other engineers' test runs, the smoke Table 1 (630 runs, 3m26s
    idle): at load 4.6 the plan said 11m16s and the sweep took 10m44s; at load 1.2 it said 5m27s
    and took 7m56s, because the load rose to 5 during the sweep (the estimate is of the load when
    the plan is made, and says so).
    """

    cores: int
    load: float

    @classmethod
    def now(cls, loadavg: Callable[[], tuple[float, float, float]] = os.getloadavg) -> MachineLoad:
        """This machine's cores available to the process and the larger of its 1- and 5-minute load averages
        (a sweep that starts in a quiet minute of a busy hour is still slowed)."""
        try:
            one, five, _ = loadavg()
        except OSError:  # no load average on this platform: assume an idle machine
            one = five = 0.0
        return cls(cores=len(os.sched_getaffinity(0)) or 1, load=max(one, five))


def load_factor(workers: int, machine: MachineLoad) -> float:
    """How many times longer ``workers`` busy workers take than on an idle machine (at least 1).

    The kernel's fair share: ``workers`` busy workers among ``load`` other runnable processes on
    ``cores`` cores each get ``cores / (load + workers)`` of a core when that is below one. The
    planning process itself is runnable while it reads the load, which roughly stands for the
    sweep's own main process (it mirrors runs into MLflow while the workers train)."""
    return max(1.0, (machine.load + max(workers, 1)) / max(machine.cores, 1))


@dataclass(frozen=True)
class Estimate:
    """The plan's wall-time estimate of what remains: idle, and at the machine's load (local pool only)."""

    idle_s: float
    loaded_s: float
    machine: MachineLoad | None  # None: the runs go to SLURM, this machine's load does not matter

    @classmethod
    def of(cls, idle_s: float, workers: int, machine: MachineLoad | None) -> Estimate:
        """The idle estimate and the loaded one (the same when the runs do not run on this machine)."""
        if machine is None:
            return cls(idle_s, idle_s, None)
        return cls(idle_s, idle_s * load_factor(workers, machine), machine)

    def text(self) -> str:
        """``3m26s on an idle machine, 8m35s at this machine's load (...)``: what the plan prints."""
        if self.machine is None or self.loaded_s <= self.idle_s * 1.05:
            return duration(self.idle_s)
        return (f"{duration(self.idle_s)} on an idle machine, {duration(self.loaded_s)} at this machine's load "
                f"(load average {self.machine.load:.1f} on {self.machine.cores} core(s))")


# ------------------------------------------------------------------------------------------ notes
class PricedLearner(Protocol):
    """What the notes read of a selected learner (:class:`runners.compose.sweep_config.AlgoChoice`)."""

    @property
    def spec(self) -> LearnerSpec: ...
    @property
    def rates(self) -> LearnerRates: ...


def device_rates(kind: str, algos: Sequence[PricedLearner], update: str = DEFAULT_UPDATE_ENGINE) -> dict[str, DeviceRate]:
    """The measured fleet rates on a ``kind`` of device (``cuda``), by algo name (none on the CPU),
    for fleets whose update runs on the ``update`` engine (:meth:`DeviceRate.for_update`)."""
    if kind == "cpu":
        return {}
    return {a.spec.name: a.rates.device_rates[kind].for_update(update) for a in algos if kind in a.rates.device_rates}


def device_estimate_note(kind: str, fleet_trained: Sequence[PricedLearner], update: str = DEFAULT_UPDATE_ENGINE,
                         ) -> str | None:
    """What the estimate is worth on a ``kind`` of device, for the learners whose runs fleets train there.

    Fleets of learners with measured device rates (``planning.devices`` in conf/algo) are priced
    at them, and the note names the card they were measured on: another card, or another load on
    this one, trains at another speed. A learner the fleet engine trains without a measured rate
    is priced at its CPU rate, and the note says which, so the figure never poses as a GPU
    estimate it is not (benchmarks/gpu_check.sh measures rates)."""
    if kind == "cpu":
        return None
    priced = [a for a in fleet_trained if kind in a.rates.device_rates]
    unpriced = [a for a in fleet_trained if kind not in a.rates.device_rates]
    parts = []
    if priced:
        cards = sorted({a.rates.device_rates[kind].measured_on or "an unnamed card" for a in priced})
        parts.append(f"fleets of {', '.join(a.spec.label for a in priced)} are priced at {kind} rates measured on "
                     f"{'; '.join(cards)} (another card or a shared one trains at another speed)")
    if unpriced:
        parts.append(f"{', '.join(a.spec.label for a in unpriced)}: no {kind} rates are measured, so their runs are priced "
                     "at CPU rates and that part is not a GPU estimate (benchmarks/gpu_check.sh measures them)")
    if update == "compiled" and priced:
        parts.append(_compiled_note(kind, priced))
    return "; ".join(parts) or None


def _compiled_note(kind: str, priced: Sequence[PricedLearner]) -> str:
    """How compiled fleets are priced: at the eager rates times a measured gain, or (none measured) at eager rates."""
    gained = [a for a in priced if a.rates.device_rates[kind].compiled_gain]
    plain = [a for a in priced if not a.rates.device_rates[kind].compiled_gain]
    parts = []
    if gained:
        parts.append("compiled updates at the eager rates times the gain measured for " + ", ".join(
            f"{a.spec.label} ({', '.join(f'{g:.2f}x at K={k}' for k, g in a.rates.device_rates[kind].compiled_gain.items())})"
            for a in gained))
    if plain:
        parts.append(f"{', '.join(a.spec.label for a in plain)}: no compiled gain is measured, so their compiled fleets are "
                     "priced at eager rates")
    return "; ".join(parts)
