"""What a killed writer leaves behind is removed by the next command, never what a live one writes.

Issue 33: ``kill -9`` of a build left a hidden ``.<site>.build-XXXX/`` (11-29 MB) beside the site
that later builds never removed (under ``make leaderboard`` it showed in ``git status``); a killed
fleet could leave ``checkpoints/fleet-*.pt.tmp``. Builds and release creation now remove such
directories when no other build holds the parent directory (:mod:`leaderboard.leftovers`), and a
sweep removes temporary files of runs and fleets whose run locks are free (:mod:`runners.record.leftovers`).
"""

from __future__ import annotations

import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from morality_gym.results.recording import RunLock
from runners.record.fleet_checkpoints import fleet_name

REPO = Path(__file__).resolve().parents[1]
SMOKE = ["algo=random", "chain=utility", "scenario=[switch_standard]", "variant=[HumanA,HumanB]", "preset=smoke",
         "seed=[41]", "mlflow=false", "gif=false", "launcher.workers=1"]


def command(*args: str, background: bool = False) -> subprocess.CompletedProcess | subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)
    if background:
        return subprocess.Popen([sys.executable, *args], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                env=env, start_new_session=True)
    return subprocess.run([sys.executable, *args], cwd=REPO, check=False, capture_output=True, text=True, timeout=600, env=env)


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("leftovers") / "r"
    out = command("-m", "runners.sweep", f"results_dir={path}", *SMOKE)
    assert out.returncode == 0, out.stderr
    return path


def hidden(parent: Path, marker: str) -> list[Path]:
    return sorted(p for p in parent.iterdir() if p.name.startswith(".") and marker in p.name)


@pytest.mark.slow
def test_the_directory_of_a_killed_build_is_removed_by_the_next_build(results: Path, tmp_path: Path) -> None:
    site = tmp_path / "out" / "site"
    build = ["-m", "leaderboard.build", "--results", str(results), "--site", str(site), "--out", str(tmp_path / "tables"),
             "--no-reference"]
    proc = command(*build, background=True)
    deadline = time.monotonic() + 300
    while not hidden(site.parent, ".build-") if site.parent.exists() else True:
        assert proc.poll() is None, "the build ended before it could be killed"
        assert time.monotonic() < deadline
        time.sleep(0.005)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    left = hidden(site.parent, ".build-")
    assert left, "kill -9 left nothing to clean up"
    out = command(*build)
    assert out.returncode == 0, out.stderr
    assert hidden(site.parent, ".build-") == [] and hidden(site.parent, ".old-") == []
    assert (site / "index.html").is_file()


def test_a_build_never_removes_the_directory_of_a_build_that_runs(results: Path, tmp_path: Path) -> None:
    """A running build holds the parent directory (a shared flock): another build leaves its
    directory alone; once it is gone (the kernel drops a killed process's lock), it is removed."""
    parent = tmp_path / "out"
    parent.mkdir()
    running = parent / ".site.build-live1234"
    running.mkdir()
    (running / "index.html").write_text("being written")
    build = ["-m", "leaderboard.build", "--results", str(results), "--site", str(parent / "site"),
             "--out", str(tmp_path / "tables"), "--no-reference"]
    fd = os.open(parent, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_SH)  # as a build in progress holds it
        out = command(*build)
        assert out.returncode == 0, out.stderr
        assert (running / "index.html").read_text() == "being written"
    finally:
        os.close(fd)
    out = command(*build)
    assert out.returncode == 0, out.stderr
    assert not running.exists()


def test_a_release_removes_what_a_killed_release_left(results: Path, tmp_path: Path) -> None:
    root = tmp_path / "releases"
    root.mkdir()
    (root / ".old-v1.create-abcd1234").mkdir()
    (root / ".old-v1.create-abcd1234" / "runs.parquet").write_bytes(b"half")
    out = command("-m", "leaderboard.release", "create", "--results", str(results), "--name", "new-v1", "--root", str(root))
    assert out.returncode == 0, out.stderr
    assert sorted(p.name for p in root.iterdir()) == ["new-v1"]


def test_a_sweep_removes_temporary_files_of_runs_no_one_writes(results: Path) -> None:
    """Temporary files as a kill leaves them (a run's Parquet and model, a fleet's checkpoint): a
    sweep removes them, except those of a run whose lock a live process holds."""
    runs = sorted(p.stem for p in (results / "runs").glob("*.parquet") if "." not in p.stem)
    free, held = runs
    leftovers = [results / "runs" / f".{free}.parquet.k1l2l3.tmp", results / "runs" / free / ".model.zip.4242.tmp"]
    checkpoint = results / "checkpoints" / f"{fleet_name(['a1', 'b2'])}.pt.tmp"
    checkpoint.parent.mkdir(exist_ok=True)
    checkpoint.with_name(checkpoint.name.removesuffix(".pt.tmp") + ".json").write_text(json.dumps({"runs": [["a1", {}], ["b2", {}]]}))
    leftovers.append(checkpoint)
    kept = results / "runs" / f".{held}.parquet.z9y8x7.tmp"
    for path in [*leftovers, kept]:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"cut short")
    lock = RunLock(results, held)
    assert lock.acquire()  # a live writer of this run
    try:
        out = command("-m", "runners.sweep", f"results_dir={results}", *SMOKE)
        assert out.returncode == 0, out.stderr
    finally:
        lock.release()
    assert [p for p in leftovers if p.exists()] == []
    assert kept.read_bytes() == b"cut short"


@pytest.mark.slow
def test_sigterm_to_a_build_cleans_up_and_keeps_the_previous_site(results: Path, tmp_path: Path) -> None:
    """SIGTERM (``timeout``, a stopping machine) used to end a build as kill -9 does; now its
    clean-up runs: the temporary directory is removed, the previous site stays, one line, exit 143."""
    site = tmp_path / "out" / "site"
    build = ["-m", "leaderboard.build", "--results", str(results), "--site", str(site), "--out", str(tmp_path / "tables"),
             "--no-reference"]
    assert command(*build).returncode == 0
    before = {p.relative_to(site): p.read_bytes() for p in site.rglob("*") if p.is_file()}
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, *build], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env, start_new_session=True)
    deadline = time.monotonic() + 300
    while not hidden(site.parent, ".build-"):
        assert proc.poll() is None, "the build ended before the signal"
        assert time.monotonic() < deadline
        time.sleep(0.005)
    os.kill(proc.pid, signal.SIGTERM)
    _out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1].startswith("stopped by SIGTERM: ") and "Traceback" not in err, err
    assert hidden(site.parent, ".build-") == [] and hidden(site.parent, ".old-") == []
    assert {p.relative_to(site): p.read_bytes() for p in site.rglob("*") if p.is_file()} == before


def _without_root_overrides() -> list[str]:
    """The command prefix that makes permission bits bind: root ignores them, so as root the
    command runs without the capabilities that let it (``setpriv``, as tests/test_faults.py's
    read-only build does); skips the test where that cannot be done."""
    import shutil

    if os.geteuid() != 0:
        return []
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: a read-only directory cannot be made")
    return ["setpriv", "--bounding-set=-dac_override,-dac_read_search,-fowner", "--"]


def test_a_release_into_a_read_only_directory_is_one_line(results: Path, tmp_path: Path) -> None:
    """Root ignores permission bits, so as root the command runs without the capabilities that let
    it (``setpriv``, as tests/test_faults.py's read-only build does)."""
    wrapper = _without_root_overrides()
    root = tmp_path / "readonly"
    root.mkdir()
    root.chmod(0o555)
    try:
        out = subprocess.run([*wrapper, sys.executable, "-m", "leaderboard.release", "create", "--results", str(results),
                              "--name", "ro-v1", "--root", str(root / "releases")], cwd=REPO, check=False,
                             capture_output=True, text=True, timeout=300)
    finally:
        root.chmod(0o755)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert out.stderr.strip() == (f"error: cannot write {root / 'releases'} (Permission denied): the directory is "
                                  "read-only for this user; choose a writable one"), out.stderr
    assert list(root.iterdir()) == []


@pytest.mark.parametrize("what", ["sweep", "submit"])
def test_a_read_only_results_directory_is_one_line(tmp_path: Path, what: str) -> None:
    """The sweep's preflight and the submission's check name the directory before anything runs."""
    wrapper = _without_root_overrides()
    results = tmp_path / "readonly"
    results.mkdir()
    results.chmod(0o555)
    args = (["-m", "runners.sweep", f"results_dir={results}", *SMOKE] if what == "sweep" else
            ["-m", "leaderboard.submit", "random", "--name", "Coin", "--results", str(results), "--chain", "utility",
             "--scenario", "switch_standard", "--variant", "HumanA", "--preset", "smoke"])
    try:
        out = subprocess.run([*wrapper, sys.executable, *args], cwd=REPO, check=False, capture_output=True, text=True,
                             timeout=300)
    finally:
        results.chmod(0o755)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    lines = [line for line in out.stderr.splitlines() if "error" in line]
    assert len(lines) == 1 and str(results) in lines[0] and "writable" in lines[0], out.stderr
    assert list(results.iterdir()) == []
