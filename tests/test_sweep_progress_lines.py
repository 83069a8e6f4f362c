"""A sweep whose stderr is a log file (nohup, SLURM, CI) still tells how it goes: plain progress lines."""

from __future__ import annotations

import io
from pathlib import Path
from types import SimpleNamespace

from rich.console import Console

from runners.sweep import ProgressLines
from tests.test_sweep import SMALL, sweep


def _job(n: int, label: str, scenario: str, chains: tuple[str, ...] = ("Utility",)) -> SimpleNamespace:
    return SimpleNamespace(runs=[SimpleNamespace(config={"algo": {"label": label}, "scenario": scenario, "chain": {"name": chains[i % len(chains)]}})
                                 for i in range(n)])


def test_lines_are_throttled_and_name_the_fleets_in_training() -> None:
    now = [0.0]
    out = io.StringIO()
    lines = ProgressLines(Console(file=out, width=300), total=4, every_s=60, clock=lambda: now[0], wall=lambda: "22:14:05")
    fleet = _job(30, "PPO", "PushOrSwitch")
    lines.update(fleet, 16_384, 1_000_000)
    assert out.getvalue() == ""  # nothing before a minute has passed
    now[0] = 61.0
    lines.update(fleet, 32_768, 1_000_000)
    assert out.getvalue().strip() == ("[22:14:05] 0/4 runs done, 0 failed, 1m01s elapsed; "
                                      "training: 30 PPO on PushOrSwitch (Utility) 32,768/1,000,000 steps")
    now[0] = 70.0
    lines.run_finished(ok=False)
    lines.end(fleet)
    assert out.getvalue().count("\n") == 1  # throttled
    lines.run_finished(ok=True)
    lines.run_finished(ok=True)
    lines.run_finished(ok=True)  # the last run always prints
    last = out.getvalue().strip().splitlines()[-1]
    assert last.startswith("[22:14:05] 4/4 runs done, 1 failed, 1m10s elapsed") and "training" not in last
    lines.update(_job(4, "CPO", "Switch5", ("Utility", "DualProcess")), 1, 2)
    assert "4 CPO on Switch5 (2 chains) 1/2 steps" in lines.line()
    silent = io.StringIO()
    off = ProgressLines(Console(file=silent), total=1, every_s=0, clock=lambda: 1e9)
    off.run_finished(ok=True)
    assert silent.getvalue() == ""  # 0: no lines


def test_a_sweep_logged_to_a_file_prints_progress_lines(tmp_path: Path) -> None:
    out = sweep(tmp_path / "r", *SMALL, "mlflow=false", "gif=false", "progress_every_s=0.000001")
    assert out.returncode == 0, out.stderr
    progress = [line for line in out.stderr.splitlines() if " runs done, " in line]
    assert progress and progress[-1].split("] ", 1)[1].startswith("12/12 runs done, 0 failed"), out.stderr  # 12 variants


def test_progress_every_s_is_checked(tmp_path: Path) -> None:
    out = sweep(tmp_path / "r", *SMALL, "progress_every_s=-1")
    assert out.returncode == 2 and "progress_every_s" in out.stderr
