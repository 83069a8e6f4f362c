"""Issue 46, items 6 and 7: the last tracebacks, the late checks and the run files that disagree with themselves.

Each case is one line and exit 2 (or a one-line refusal) before any work, or a damaged file moved
aside (or left out, by the leaderboard) with its reason:

* ``eval --max-steps 2`` (and a sweep with ``max_steps=2``, which trained every run first);
* ``leaderboard.llm run --script`` with a byte that is not UTF-8;
* a worker told to stop by the sweep after it reported a full disk;
* ``runners.track --policy nosuch.py:act`` (or without ``--name``), which generated the splits first;
* a run file copied under another run's name; a run file whose metric was edited.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from morality_gym.clitools import UserError
from morality_gym.results.recording import finished_status
from morality_gym.results.schema import read_runs, run_files
from tests.leaderboard_data import REPO, make_results


def _cli(*args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, *args], cwd=REPO, capture_output=True, text=True, timeout=timeout, check=False)


def _one_line(proc: subprocess.CompletedProcess[str]) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    return lines[0]


# ---------------------------------------------------------------------------------------- max_steps
@pytest.mark.parametrize("max_steps", ["0", "2", "3"])
def test_eval_refuses_a_max_steps_too_short_to_score_the_env(max_steps: str) -> None:
    line = _one_line(_cli("-m", "morality_gym", "eval", "--chain", "Utility", "--scenario", "SwitchStandard",
                          "--variant", "HumanA", "--max-steps", max_steps, "--episodes", "5", "--seed", "1"))
    assert f"--max-steps: max_steps={max_steps} is too short for SwitchStandard-HumanA-v1" in line
    assert "n_human_harm total 0, outside the variant's bounds [1, 5]" in line and "use max_steps >= 5" in line


def test_eval_with_a_long_enough_max_steps_still_runs() -> None:
    proc = _cli("-m", "morality_gym", "eval", "--chain", "Utility", "--scenario", "SwitchStandard", "--variant", "HumanA",
                "--max-steps", "5", "--exact", "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)


def test_a_sweep_refuses_max_steps_2_before_training(tmp_path: Path) -> None:
    from runners.compose.sweep_config import ConfigError
    from tests.test_fleet_sweep import _sweep_config

    with pytest.raises(ConfigError, match=r"max_steps=2 is too short for SwitchStandard-HumanA-v1.*use max_steps >= 5"):
        _sweep_config(tmp_path, "algo=ppo", "chain=utility", "scenario=[switch_standard]", "variant=[HumanA]",
                      "preset=smoke", "max_steps=2")
    assert _sweep_config(tmp_path, "algo=ppo", "chain=utility", "scenario=[switch_standard]", "variant=[HumanA]",
                         "preset=smoke", "max_steps=5").max_steps == 5


# ---------------------------------------------------------------------------------------- llm --script
def test_an_llm_script_that_is_not_utf8_is_one_line(tmp_path: Path) -> None:
    from leaderboard.llm import scripted_model

    script = tmp_path / "answers.txt"
    script.write_bytes(b"RIGHT\nLEFT \xff\xfe\n")
    with pytest.raises(UserError, match=r"not UTF-8 text \(byte 0xff on line 2\)"):
        scripted_model(script)


# ---------------------------------------------------------------------------------------- worker SIGTERM
WORKER = """
import os, signal, sys
from multiprocessing import Pipe
from morality_gym.clitools import DiskFullError
from runners.execute import jobs
from runners.launch import local_pool as pool

def full(*args, **kwargs):
    raise DiskFullError("results/runs: the disk is full (0 bytes free)")
    yield

sent = pool._send
def send_then_stopped(conn, message):
    sent(conn, message)
    if message[0] == "fatal":  # the sweep's SIGTERM to every worker follows the report at once
        os.kill(os.getpid(), signal.SIGTERM)

jobs.execute_job = full  # what the worker runs (it imports the training code by name: runners.launch.entry_points)
pool._send = send_then_stopped
mine, theirs = Pipe()
theirs.send(([("r1", None)], "single"))
pool._worker_main(mine, "results", False, os.getppid())
print("worker ended", theirs.recv(), theirs.recv()[0])
"""


def test_a_worker_stopped_after_reporting_a_full_disk_prints_no_traceback() -> None:
    proc = _cli("-c", textwrap.dedent(WORKER), timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr and "TrainingStopped" not in proc.stderr, proc.stderr
    assert "worker ended" in proc.stdout and "fatal" in proc.stdout


# ---------------------------------------------------------------------------------------- runners.track
@pytest.mark.parametrize(("args", "said"), [
    (["--policy", "nosuch.py:act", "--name", "Mine"], "no file nosuch.py"),
    (["--policy", "nosuch.py:act"], "--policy needs --name"),
])
def test_track_checks_the_policy_before_generating_the_splits(args: list[str], said: str, tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    from runners import track

    def never(*_: object, **__: object) -> None:
        raise AssertionError("the splits were generated before the command line was checked")

    monkeypatch.setattr(track, "load_sets", never)
    with pytest.raises(UserError, match=said):
        track.main([*args, "--out", str(tmp_path)])


# ---------------------------------------------------------------------------------------- run files
@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("consistency") / "results"
    make_results(root)
    return root


def _copy(results: Path, tmp_path: Path) -> tuple[Path, list[Path]]:
    copy = tmp_path / "results"
    shutil.copytree(results, copy)
    return copy, sorted(p for p in run_files(copy) if pq.read_table(p).column("status")[0].as_py() == "ok")


def test_the_synthetic_results_are_consistent(synthetic: Path) -> None:
    skipped: list[dict[str, str]] = []
    runs = read_runs(synthetic, skipped=skipped)
    assert not skipped and len(runs) > 0


def test_a_run_file_copied_under_another_runs_name_is_moved_aside_and_left_out(synthetic: Path, tmp_path: Path) -> None:
    results, files = _copy(synthetic, tmp_path)
    source, victim = files[0], files[1]
    shutil.copy(source, victim)
    skipped: list[dict[str, str]] = []
    read_runs(results, skipped=skipped)
    assert [s["file"] for s in skipped] == [str(victim)]
    assert f"named for run {victim.stem} but holds run {source.stem}" in skipped[0]["reason"]
    assert finished_status(results, victim.stem) is None  # the sweep does the run again
    assert not victim.exists() and (results / "runs" / ".quarantine" / victim.name).exists()
    assert finished_status(results, source.stem) == "ok"


def _edit(path: Path, **values: float) -> None:
    table = pq.read_table(path)
    for name, value in values.items():
        i = table.column_names.index(name)
        table = table.set_column(i, table.schema.field(i), pa.array([value], type=table.schema.field(i).type))
    pq.write_table(table, path)


def test_a_run_file_whose_metric_was_edited_is_moved_aside_with_its_reason(synthetic: Path, tmp_path: Path) -> None:
    results, files = _copy(synthetic, tmp_path)
    victim = files[2]
    metric = pq.read_table(victim).column("metric")[0].as_py()
    _edit(victim, metric=min(1.0, metric + 0.05))
    skipped: list[dict[str, str]] = []
    read_runs(results, skipped=skipped)
    assert [s["file"] for s in skipped] == [str(victim)]
    assert "is not the weighted mean of its own morality functions" in skipped[0]["reason"]
    assert finished_status(results, victim.stem) is None
    index = (results / "runs" / ".quarantine" / "index.jsonl").read_text()
    assert "weighted mean of its own morality functions" in index


def test_a_metric_and_functions_edited_together_still_disagree_with_the_exact_metric(synthetic: Path, tmp_path: Path) -> None:
    results, files = _copy(synthetic, tmp_path)
    victim = files[3]
    table = pq.read_table(victim)
    mf = [n for n in table.column_names if n.startswith("mf_")]
    _edit(victim, metric=1.0, exact_metric=0.3, **{n: 1.0 for n in mf})
    skipped: list[dict[str, str]] = []
    read_runs(results, skipped=skipped)
    assert len(skipped) == 1 and "from its own exact metric" in skipped[0]["reason"], skipped
