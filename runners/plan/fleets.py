"""The sweep's runs cut into *jobs*: one run alone (single engine), or many runs trained as a fleet.

Pure planning, no training: which runs go in which job, and what each job is priced at
(:mod:`runners.plan.estimate`); :mod:`runners.execute.jobs` executes a job in a worker.

With ``engine=fleet`` (the default) the plan's runs are grouped into fleets: runs whose resolved
configurations differ only in env id (variant), chain and seed, on one scenario (on accelerators:
of any scenario of the same budget), of a learner the fleet engine reproduces
(:func:`morality_gym.baselines.specs.fleet_trains`), are trained together by
:mod:`morality_gym.baselines.fleet`, at most ``fleet_size`` at a time.
Everything else (Random, the oracle, a user's learner, a group of one) stays a single-run job.

A fleet killed while training resumes from its checkpoint only if the next sweep forms the same
fleet again: :func:`make_jobs` forms the checkpointed fleets first, exactly
(:mod:`runners.record.fleet_checkpoints`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from morality_gym.baselines.specs import fleet_trains
from morality_gym.results.run_config import RunConfig
from runners.compose.schema import ENGINES
from runners.plan.estimate import DeviceRate, DeviceWork, device_price, fleet_seconds
from runners.plan.runs import PlannedRun

#: Keys of a run config that may differ between the runs of one fleet (the rest must be equal).
FLEET_FREE_KEYS = ("env_id", "variant", "chain", "seed")
#: ... and with ``mix_scenarios``: a fleet pads observations of different widths (scenarios) to
#: one, each run's numbers unchanged bit for bit (tests/test_fleet_mixed.py).
MIXED_FREE_KEYS = (*FLEET_FREE_KEYS, "scenario")


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
