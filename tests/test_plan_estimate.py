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
