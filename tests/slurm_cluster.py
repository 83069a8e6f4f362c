"""Session fixture ``slurm_cluster``: a real single-node SLURM cluster for the ``slurm`` tests.

Imported by tests/conftest.py. The fixture

* skips (with the reason) when not root or when the slurm / munge / MariaDB programs are missing;
* reuses a cluster that is already up and healthy (e.g. after ``make slurm-up``) and leaves it
  running afterwards;
* otherwise starts one with runners/slurm/slurm_up.sh and stops it with slurm_down.sh at the end
  of the session; a failed or hung bring-up fails with the tail of the daemons' logs;
* never stops a cluster that another test session on the machine is still using: every session
  holds a shared lock on :data:`USERS_LOCK` while it uses the cluster, and the cluster a test
  session started (:data:`STARTED_BY_TESTS`) is stopped by the last session to leave it. Checking,
  starting and stopping happen one session at a time (:data:`START_LOCK`), so a second session
  waits at most for a bring-up or a shutdown, never for the first session's tests.
  slurm_down.sh cancels every job, so a second ``pytest`` run (a targeted one beside the full
  suite) used to stop the first one's running array task when it ended:
  ``test_fleet_sweep_through_real_slurm`` then saw its fleet's task stopped by a signal.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import signal
import subprocess
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = REPO / "runners" / "slurm"
PARTITION = "debug"  # defined by slurm_up.sh
NODE = "localhost"
SLURMD_PID = "/run/slurmd.pid"  # SlurmdPidFile in the slurm.conf written by slurm_up.sh
USERS_LOCK = Path("/run/morality-gym-slurm-tests.lock")  # shared by every test session using the cluster
START_LOCK = Path("/run/morality-gym-slurm-tests.start.lock")  # held while one session checks, starts or stops it
STARTED_BY_TESTS = Path("/run/morality-gym-slurm-tests.started")  # absent for a `make slurm-up` cluster
# slurm_up.sh stops on its own after SLURM_UP_TIMEOUT; the subprocess timeout is the backstop.
UP_TIMEOUT_S = 120
DOWN_TIMEOUT_S = 90
LOGS = [
    Path("/var/log/slurm/slurmctld.log"),
    Path("/var/log/slurm/slurmd.log"),
    Path("/var/log/slurm/slurmdbd.log"),
    Path("/var/log/slurm/mariadb.log"),
    Path("/var/log/munge/munged.log"),
]
# Package that provides each program the cluster needs (for the skip message).
PROGRAMS = {
    "slurmctld": "slurm-wlm",
    "slurmd": "slurm-wlm",
    "srun": "slurm-wlm",
    "sacct": "slurm-wlm",
    "slurmdbd": "slurmdbd",
    "munged": "munge",
    "mariadbd": "mariadb-server",
}


@dataclass(frozen=True)
class SlurmCluster:
    partition: str
    node: str
    cpus: int
    memory_mb: int
    started_here: bool  # False when an already running cluster was reused


def _which(program: str) -> str | None:
    # The daemons live in /usr/sbin, which is not on every PATH.
    return shutil.which(program) or shutil.which(program, path="/usr/sbin:/usr/bin")


def _run(cmd: list[str], timeout: float) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)


def _slurmd_running() -> bool:
    # slurmctld keeps showing the node "idle" for minutes after its slurmd died (SlurmdTimeout),
    # so look at the process itself.
    try:
        pid = int(Path(SLURMD_PID).read_text().strip())
        stat = Path(f"/proc/{pid}/stat").read_text()
        # "PID (comm) STATE ...": a zombie (Z) has exited; PID 1 here reaps orphans lazily.
        return stat.startswith(f"{pid} (slurmd) ") and stat.split(") ", 1)[1][0] != "Z"
    except (OSError, ValueError):
        return False


def _healthy() -> bool:
    """slurmd runs, the controller answers, the node takes jobs, accounting (slurmdbd + MariaDB) answers."""
    if not _slurmd_running():
        return False
    try:
        # scontrol ping answers at once; sinfo retries for ~10 s when there is no controller.
        ping = _run(["scontrol", "ping"], 10)
        if ping.returncode != 0 or "is UP" not in ping.stdout:
            return False
        state = _run(["sinfo", "-h", "-N", "-n", NODE, "-p", PARTITION, "-o", "%t"], 10)
        acct = _run(["sacctmgr", "-n", "-P", "list", "cluster", "format=cluster"], 10)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return state.stdout.strip() in {"idle", "mix", "alloc"} and acct.returncode == 0 and bool(acct.stdout.strip())


def _log_tails(lines: int = 30) -> str:
    parts = []
    for log in LOGS:
        try:
            tail = log.read_text(errors="replace").splitlines()[-lines:]
        except OSError:
            continue
        parts.append(f"----- {log} (last {len(tail)} lines) -----\n" + "\n".join(tail))
    return "\n".join(parts) or "(no daemon logs found)"


def _script(name: str, timeout: float, env: dict[str, str] | None = None) -> tuple[bool, str]:
    """Run one of the runners/slurm scripts; return (ok, its combined output).

    The output goes to a temporary file, not a pipe: a daemon started by the script that kept an
    inherited pipe open would otherwise block us until it exits. The script runs in its own
    process group so that a timeout kills it together with whatever it is waiting on (the daemons
    detach into their own sessions and are not hit).
    """
    with tempfile.TemporaryFile(mode="w+") as out:
        proc = subprocess.Popen(
            ["bash", str(SCRIPTS / name)],
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
            env={**os.environ, **(env or {})},
            start_new_session=True,
        )
        try:
            code = proc.wait(timeout=timeout)
            status = f"{name} exited with code {code}"
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            code, status = -1, f"{name} did not finish within {timeout:.0f} s (killed)"
        out.seek(0)
        return code == 0, f"{out.read()}\n{status}"


def _clip(text: str, head: int = 3000, tail: int = 15000) -> str:
    """Keep the start (the script's progress and error line) and the end (the log tails)."""
    return text if len(text) <= head + tail else f"{text[:head]}\n[...]\n{text[-tail:]}"


def _node_resources() -> tuple[int, int]:
    out = _run(["sinfo", "-h", "-N", "-n", NODE, "-p", PARTITION, "-o", "%c %m"], 10).stdout.split()
    return int(out[0]), int(out[1])


@contextlib.contextmanager
def _one_at_a_time(lock: Path) -> Iterator[None]:
    """Held while a session checks and starts the cluster, or leaves it (and maybe stops it)."""
    with lock.open("a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        yield


def _join(lock: Path) -> IO[str]:
    """A shared hold on the cluster, kept open for the session: other sessions may join too."""
    users = lock.open("a")
    fcntl.flock(users, fcntl.LOCK_SH)
    return users


def _last_user(users: IO[str]) -> bool:
    """Whether no other session holds the cluster: our shared lock becomes exclusive only then."""
    try:
        fcntl.flock(users, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


@pytest.fixture(scope="session")
def slurm_cluster() -> Iterator[SlurmCluster]:
    if os.geteuid() != 0:
        pytest.skip("slurm tests need root: they start munged, MariaDB, slurmdbd, slurmctld and slurmd")
    missing = {prog: pkg for prog, pkg in PROGRAMS.items() if _which(prog) is None}
    if missing:
        packages = " ".join(sorted(set(missing.values())))
        pytest.skip(
            f"SLURM programs not found: {', '.join(sorted(missing))}; "
            f"install with `make system-deps` or `apt-get install {packages}`"
        )

    with _one_at_a_time(START_LOCK):  # two sessions never both run slurm_up.sh
        started_here = False
        if not _healthy():
            # The script gets a slightly smaller budget so that it fails by itself, with its own
            # message and the logs, before the subprocess timeout has to kill it.
            ok, output = _script("slurm_up.sh", UP_TIMEOUT_S, {"SLURM_UP_TIMEOUT": str(UP_TIMEOUT_S - 15)})
            if not ok:
                # slurm_up.sh prints the daemon logs itself when it fails; when it had to be killed,
                # read them here (before the teardown below adds its own lines).
                logs = "" if "----- last lines of" in output else _log_tails()
                # Do not leave a half-started cluster behind.
                _script("slurm_down.sh", DOWN_TIMEOUT_S)
                STARTED_BY_TESTS.unlink(missing_ok=True)
                pytest.fail(f"SLURM bring-up failed (runners/slurm/slurm_up.sh):\n{_clip(output)}\n{logs}", pytrace=False)
            started_here = True
            STARTED_BY_TESTS.touch()
        users = _join(USERS_LOCK)

    try:
        cpus, memory_mb = _node_resources()
        yield SlurmCluster(PARTITION, NODE, cpus, memory_mb, started_here)
    finally:
        # No session joins while we decide and stop: it waits, then finds the cluster down and starts it.
        with _one_at_a_time(START_LOCK):
            try:
                if _last_user(users) and STARTED_BY_TESTS.exists():
                    ok, output = _script("slurm_down.sh", DOWN_TIMEOUT_S)
                    STARTED_BY_TESTS.unlink(missing_ok=True)
                    if not ok:
                        pytest.fail(f"SLURM teardown failed.\n{_clip(output)}\n{_log_tails()}", pytrace=False)
            finally:
                users.close()
