"""How much slower a local sweep runs on a machine that is already busy, for the plan's estimate.

Why: the plan prices each run as if its worker had a core to itself (``planning`` in each algo
file, fitted on an idle machine). On a shared 2-core machine a smoke Table 1 estimated at 3m26s
took 8m48s under a load average of 3 (issue 36): the two workers shared the cores with other
processes. So the plan states two figures: the idle estimate and the one at the load the
machine has when the sweep starts. The second is the idle estimate times :func:`load_factor`.

The model is the kernel's fair share: ``workers`` busy workers among ``load`` other runnable
processes on ``cores`` cores each get ``cores / (load + workers)`` of a core when that is below
one. The load is the larger of the 1- and 5-minute load averages (a sweep that starts in a quiet
minute of a busy hour is still slowed). The planning process itself is runnable while it reads
the load, which roughly stands for the sweep's own main process (it mirrors runs into MLflow
while the workers train). Measured on 2026-11-26 on a 2-core machine shared with two other
engineers' test runs, the smoke Table 1 (630 runs, 3m26s idle): at load 4.6 the plan said 11m16s
and the sweep took 10m44s; at load 1.2 it said 5m27s and took 7m56s, because the load rose to 5
during the sweep (the estimate is of the load when the plan is made, and says so).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass

from morality_gym.clitools import duration


@dataclass(frozen=True)
class MachineLoad:
    """The machine's cores and its load average when the plan was made."""

    cores: int
    load: float

    @classmethod
    def now(cls, loadavg: Callable[[], tuple[float, float, float]] = os.getloadavg) -> MachineLoad:
        """This machine's cores available to the process and the larger of its 1- and 5-minute load averages."""
        try:
            one, five, _ = loadavg()
        except OSError:  # no load average on this platform: assume an idle machine
            one = five = 0.0
        return cls(cores=len(os.sched_getaffinity(0)) or 1, load=max(one, five))


def load_factor(workers: int, machine: MachineLoad) -> float:
    """How many times longer ``workers`` busy workers take than on an idle machine (at least 1)."""
    return max(1.0, (machine.load + max(workers, 1)) / max(machine.cores, 1))


@dataclass(frozen=True)
class Estimate:
    """The plan's wall-time estimate of what remains: idle, and at the machine's load (local pool only)."""

    idle_s: float
    loaded_s: float
    machine: MachineLoad | None  # None: the runs go to SLURM, this machine's load does not matter

    def text(self) -> str:
        """``3m26s on an idle machine, 8m35s at this machine's load (...)``: what the plan prints."""
        if self.machine is None or self.loaded_s <= self.idle_s * 1.05:
            return duration(self.idle_s)
        return (f"{duration(self.idle_s)} on an idle machine, {duration(self.loaded_s)} at this machine's load "
                f"(load average {self.machine.load:.1f} on {self.machine.cores} core(s))")


def estimate(idle_s: float, workers: int, machine: MachineLoad | None) -> Estimate:
    """The idle estimate and the loaded one (the same when the runs do not run on this machine)."""
    if machine is None:
        return Estimate(idle_s, idle_s, None)
    return Estimate(idle_s, idle_s * load_factor(workers, machine), machine)
