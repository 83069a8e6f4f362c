"""The plan's time estimate counts what a sweep pays besides its runs (issue #22).

A smoke sweep's runs take seconds; its estimate (0m02s) was 2-8x below the wall time (17 s)
because creating the MLflow store of a new results directory and the workers' start were left out (:class:`runners.config_schema.SweepOverheads`).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from runners.config_schema import SweepOverheads

REPO = Path(__file__).resolve().parents[1]


def test_the_estimate_counts_what_a_sweep_pays_besides_its_runs(tmp_path: Path) -> None:
    overheads = SweepOverheads()
    assert overheads.seconds(0, new_store=True, mlflow=True) == 0.0
    fresh = overheads.seconds(12, new_store=True, mlflow=True)
    assert fresh == pytest.approx(overheads.worker_start_s + overheads.new_store_s)
    assert overheads.seconds(12, new_store=False, mlflow=True) == pytest.approx(fresh - overheads.new_store_s)
    assert overheads.seconds(12, new_store=True, mlflow=False) == pytest.approx(overheads.worker_start_s)
    out = subprocess.run([sys.executable, "-m", "runners.sweep", "algo=random", "chain=utility", "scenario=switch_standard",
                          "variant=[HumanA]", "preset=smoke", "dry_run=true", f"results_dir={tmp_path}"],
                         cwd=REPO, check=False, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    shown = " ".join(out.stderr.split()).split("estimated time for what remains: ")[1].split()[0]  # the plan is on stderr
    minutes, seconds = shown.rstrip("s").split("m")
    assert int(minutes) * 60 + int(seconds) >= round(overheads.worker_start_s + overheads.new_store_s)


def test_the_estimate_says_what_a_busy_machine_costs() -> None:
    """Issue 36: on a shared machine the plan states the idle estimate and the one at the machine's load:
    workers share the cores with the other runnable processes (the kernel's fair share)."""
    from runners.machine_load import MachineLoad, estimate, load_factor

    assert load_factor(2, MachineLoad(cores=2, load=0.0)) == 1.0  # a core each: as fitted
    assert load_factor(2, MachineLoad(cores=2, load=3.0)) == pytest.approx(2.5)  # 5 runnable on 2 cores
    assert load_factor(2, MachineLoad(cores=8, load=3.0)) == 1.0  # room to spare
    busy = estimate(206.0, 2, MachineLoad(cores=2, load=3.0))
    assert busy.loaded_s == pytest.approx(515.0)
    assert busy.text() == "3m26s on an idle machine, 8m35s at this machine's load (load average 3.0 on 2 core(s))"
    assert estimate(206.0, 2, MachineLoad(cores=2, load=0.0)).text() == "3m26s"  # idle: one figure
    assert estimate(206.0, 2, None).text() == "3m26s"  # SLURM: this machine's load does not matter
    assert MachineLoad.now(lambda: (1.0, 2.5, 0.5)).load == 2.5  # a quiet minute of a busy hour counts as busy


def test_an_estimate_for_a_gpu_sweep_is_marked_as_priced_at_cpu_rates() -> None:
    """No GPU planning rates are fitted: a device=cuda sweep's estimate says so instead of posing as one."""
    from runners.sweep import device_estimate_note

    assert device_estimate_note("cpu") is None
    note = device_estimate_note("cuda")
    assert note is not None and "CPU rates" in note and "not a GPU estimate" in note and "gpu_check.sh" in note
