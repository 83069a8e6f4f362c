"""A full disk (issue 33): one line naming the path and the free space, exit 2, nothing half-written,
and the results written before intact; what killed writers leave behind is swept up later.

The disk is real: a tmpfs of a few MB mounted by the test (root only; skipped with the reason
otherwise), filled with a filler file until the next write cannot fit. Each command runs as a
subprocess, as a user runs it.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from morality_gym.results.schema import read_runs
from tests.sweep_tools import run_files

REPO = Path(__file__).resolve().parents[1]
DISK_MB = 4
SMOKE = ["algo=random", "chain=utility", "scenario=[switch_standard]", "preset=smoke", "seed=[41]", "mlflow=false",
         "launcher.workers=1"]


@pytest.fixture
def disk(tmp_path: Path) -> Iterator[Path]:
    """A fresh tmpfs of :data:`DISK_MB` MB, unmounted afterwards."""
    mount = tmp_path / "disk"
    mount.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a small tmpfs needs root and mount(8): a full disk cannot be made here")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={DISK_MB}m", "tmpfs", str(mount)], capture_output=True,
                          text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.strip()}): a full disk cannot be made")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True, check=False)


def fill(disk: Path, leave: int = 0) -> Path:
    """Fill ``disk`` up to ``leave`` bytes of free space; the filler file is returned (delete it to free the disk)."""
    filler = disk / "filler"
    free = shutil.disk_usage(disk).free - leave
    with open(filler, "ab") as fh:
        while free > 0:
            chunk = min(free, 1 << 20)
            try:
                fh.write(b"\0" * chunk)
                fh.flush()
            except OSError:
                break
            free -= chunk
    return filler


def command(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)
    env.pop("MORALITY_GYM_DEBUG", None)
    return subprocess.run([sys.executable, *args], cwd=REPO, check=False, capture_output=True, text=True, timeout=timeout, env=env)


def disk_full_line(proc: subprocess.CompletedProcess, where: Path) -> str:
    """Exit 2, no traceback, exactly one ``error: disk full: cannot write <path under where> (<free>)`` line."""
    output = proc.stdout + proc.stderr
    assert proc.returncode == 2, output
    assert "Traceback" not in output, output
    lines = [line for line in output.splitlines() if "disk full" in line]
    assert len(lines) == 1, output
    assert lines[0].startswith(f"error: disk full: cannot write {where}"), lines[0]
    assert " free)" in lines[0] or "bytes free" in lines[0], lines[0]
    return lines[0]


def temporary_files(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.name.endswith(".tmp") or ".build-" in p.name or ".create-" in p.name]


def snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


# ---------------------------------------------------------------------------------------- sweep
@pytest.mark.slow
def test_a_sweep_into_a_full_disk_is_one_line_and_keeps_what_was_written(disk: Path) -> None:
    results = disk / "r"
    first = command("-m", "runners.sweep", f"results_dir={results}", *SMOKE, "variant=[HumanA,HumanB]")
    assert first.returncode == 0, first.stderr
    before = snapshot(results / "runs")
    filler = fill(disk)
    out = command("-m", "runners.sweep", f"results_dir={results}", *SMOKE, "variant=[HumanA,HumanB,AnimalA,AnimalB]")
    disk_full_line(out, results)
    assert not temporary_files(results), temporary_files(results)
    after = snapshot(results / "runs")
    assert {k: v for k, v in after.items() if k in before} == before  # what was written is untouched
    runs = read_runs(results)
    assert len(runs) == 2 and (runs.status == "ok").all()  # no failed row for a full disk
    filler.unlink()
    again = command("-m", "runners.sweep", f"results_dir={results}", *SMOKE, "variant=[HumanA,HumanB,AnimalA,AnimalB]")
    assert again.returncode == 0, again.stderr
    assert "2 done, 2 to run" in again.stderr
    assert len(read_runs(results)) == 4


@pytest.mark.slow
def test_a_sweep_with_mlflow_into_a_full_disk_is_one_line(disk: Path) -> None:
    """MLflow's SQLite store on the full disk too: still one line, the run files intact."""
    results = disk / "r"
    args = [a for a in SMOKE if a != "mlflow=false"]
    first = command("-m", "runners.sweep", f"results_dir={results}", *args, "variant=[HumanA]", "gif=false")
    assert first.returncode == 0, first.stderr
    before = snapshot(results / "runs")
    filler = fill(disk)
    out = command("-m", "runners.sweep", f"results_dir={results}", *args, "variant=[HumanA,HumanB]", "gif=false")
    disk_full_line(out, results)
    assert {k: v for k, v in snapshot(results / "runs").items() if k in before} == before
    assert not temporary_files(results / "runs")
    filler.unlink()
    again = command("-m", "runners.sweep", f"results_dir={results}", *args, "variant=[HumanA,HumanB]", "gif=false")
    assert again.returncode == 0, again.stderr
    assert len(read_runs(results)) == 2


def test_a_fleet_checkpoint_that_does_not_fit_is_a_warning(disk: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """torch.save raises RuntimeError ('unexpected pos'), not OSError, when a short write leaves it
    out of room: the checkpoint still only warns, leaves no temporary file, and training goes on."""
    import torch as th

    from morality_gym.baselines.fleet import FleetCheckpoint
    from tests.test_fleet import ROLLOUT, small_spec
    from tests.test_fleet_checkpoint import make_fleet

    spec = small_spec("ppo")
    roomy = FleetCheckpoint(tmp_path / "roomy.pt", every_s=0.0)
    fleet = make_fleet(spec, "paper")
    fleet.learn(ROLLOUT, checkpoint=roomy)
    size = (tmp_path / "roomy.pt").stat().st_size
    th.set_num_threads(1)
    fill(disk, leave=size // 2)  # room for the start of the file, not its end: a short write
    path = disk / "checkpoints" / "fleet.pt"
    tight = FleetCheckpoint(path, every_s=0.0)
    again = make_fleet(spec, "paper")
    with caplog.at_level(logging.WARNING):
        assert again.learn(2 * ROLLOUT, checkpoint=tight) == 2 * ROLLOUT  # trained to the end regardless
    warnings = [r.getMessage() for r in caplog.records if "could not be written" in r.getMessage()]
    assert warnings and f"disk full: cannot write {path}" in warnings[0], caplog.text
    assert not path.exists() and not path.with_name(path.name + ".tmp").exists()


# ---------------------------------------------------------------------------------------- leaderboard
@pytest.fixture(scope="module")
def small_results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two smoke runs of Random (with GIFs) to build from, on an ordinary disk."""
    results = tmp_path_factory.mktemp("results") / "r"
    out = command("-m", "runners.sweep", f"results_dir={results}", *SMOKE, "variant=[HumanA,HumanB]")
    assert out.returncode == 0, out.stderr
    return results


@pytest.mark.slow
def test_a_build_into_a_full_disk_is_one_line_and_keeps_the_previous_site(small_results: Path, disk: Path) -> None:
    site, tables = disk / "site", disk / "tables"
    args = ["-m", "leaderboard.build", "--results", str(small_results), "--site", str(site), "--out", str(tables), "--no-reference"]
    first = command(*args)
    assert first.returncode == 0, first.stderr
    old_site, old_tables = snapshot(site), snapshot(tables)
    filler = fill(disk)
    out = command(*args)
    disk_full_line(out, disk)
    assert snapshot(site) == old_site and snapshot(tables) == old_tables  # the last good build stays whole
    assert not temporary_files(disk), temporary_files(disk)
    filler.unlink()
    assert command(*args).returncode == 0


@pytest.mark.slow
def test_a_submission_into_a_full_disk_is_one_line_and_leaves_no_gif(disk: Path) -> None:
    results = disk / "r"
    results.mkdir()
    filler = fill(disk)
    out = command("-m", "leaderboard.submit", "random", "--name", "Coin", "--results", str(results), "--chain", "utility",
                  "--scenario", "switch_standard", "--variant", "HumanA", "--preset", "smoke")
    disk_full_line(out, results)
    assert not list(results.rglob("*.gif")) and not list(results.rglob("*.parquet")), list(results.rglob("*"))
    assert not temporary_files(results)
    filler.unlink()
    out = command("-m", "leaderboard.submit", "random", "--name", "Coin", "--results", str(results), "--chain", "utility",
                  "--scenario", "switch_standard", "--variant", "HumanA", "--preset", "smoke")
    assert out.returncode == 0, out.stderr
    assert len(run_files(results)) == 1


@pytest.mark.slow
def test_a_release_into_a_full_disk_is_one_line_and_leaves_nothing(small_results: Path, disk: Path) -> None:
    root = disk / "releases"
    root.mkdir()
    filler = fill(disk)
    out = command("-m", "leaderboard.release", "create", "--results", str(small_results), "--name", "full-v1", "--root", str(root))
    disk_full_line(out, disk)
    assert list(root.iterdir()) == [], list(root.iterdir())
    filler.unlink()
    out = command("-m", "leaderboard.release", "create", "--results", str(small_results), "--name", "full-v1", "--root", str(root))
    assert out.returncode == 0, out.stderr
