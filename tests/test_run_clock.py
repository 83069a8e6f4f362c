"""A run's clock: wall and CPU time, and a fleet run's share of both."""

from __future__ import annotations

import time

import pandas as pd
import pytest

from morality_gym.results.recording import RunClock
from morality_gym.results.schema import RUN_COLUMNS, compute_seconds


def _work(cpu_seconds: float) -> None:
    """Busy work until this process has used ``cpu_seconds`` of CPU (however busy the machine is)."""
    end = time.process_time() + cpu_seconds
    while time.process_time() < end:
        pass


def test_cpu_time_counts_work_and_not_waiting() -> None:
    clock = RunClock.start()
    _work(0.1)
    time.sleep(0.3)
    wall, cpu = clock.elapsed()
    assert cpu >= 0.1  # the work
    assert wall >= cpu + 0.3 - 0.02  # the sleep is wall time only


def test_a_fleet_run_starts_from_its_share() -> None:
    own = RunClock.already_spent("2026-11-25T00:00:00+00:00", wall=10.0, cpu=4.0)
    wall, cpu = own.elapsed()
    assert wall == pytest.approx(10.0, abs=0.05) and cpu == pytest.approx(4.0, abs=0.05)
    assert own.started == "2026-11-25T00:00:00+00:00"


def test_compute_is_cpu_time_where_recorded_else_wall_time() -> None:
    assert "cpu_time_s" in RUN_COLUMNS
    runs = pd.DataFrame({"wall_time_s": [10.0, 20.0], "cpu_time_s": [4.0, None]})
    assert compute_seconds(runs).tolist() == [4.0, 20.0]
    assert compute_seconds(runs.drop(columns="cpu_time_s")).tolist() == [10.0, 20.0]  # files older than the column
