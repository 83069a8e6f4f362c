"""The SLURM test fixture's hand-over between test sessions (no cluster needed).

The session that started the cluster used to stop it at its end even while another ``pytest`` run
on the machine had an array task running, which slurm_down.sh then cancelled. Each session now
holds a shared lock while it uses the cluster; only the last one out may stop it.
"""

from __future__ import annotations

import fcntl
import subprocess
import sys
import threading
from pathlib import Path

from tests.slurm_cluster import _join, _last_user, _one_at_a_time

HOLD = """
import fcntl, sys, time
f = open(sys.argv[1], "a")
fcntl.flock(f, fcntl.LOCK_SH)
print("holding", flush=True)
sys.stdin.read()  # until the test closes our stdin
"""


def _other_session(lock: Path) -> subprocess.Popen:
    """Another test session holding the cluster (its shared lock) until its stdin is closed."""
    other = subprocess.Popen([sys.executable, "-c", HOLD, str(lock)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             text=True)
    assert other.stdout is not None and other.stdout.readline().strip() == "holding"
    return other


def _end(other: subprocess.Popen) -> None:
    assert other.stdin is not None
    other.stdin.close()
    other.wait(timeout=30)


def test_a_second_session_joins_without_waiting_for_the_first_to_end(tmp_path: Path) -> None:
    """Starting takes the start lock only: a session that is running its tests does not hold it."""
    users_lock, start_lock = tmp_path / "users.lock", tmp_path / "start.lock"
    other = _other_session(users_lock)
    joined: list[object] = []

    def join() -> None:
        with _one_at_a_time(start_lock):
            joined.append(_join(users_lock))

    try:
        thread = threading.Thread(target=join, daemon=True)
        thread.start()
        thread.join(timeout=10)
        assert joined, "the second session waited for the first one's whole run"
        assert not _last_user(joined[0])  # and the first still holds it
    finally:
        _end(other)
    assert _last_user(joined[0])


def test_the_last_session_out_is_the_only_one_that_may_stop_the_cluster(tmp_path: Path) -> None:
    lock = tmp_path / "users.lock"
    ours = lock.open("a")
    fcntl.flock(ours, fcntl.LOCK_SH)
    other = _other_session(lock)
    try:
        assert not _last_user(ours)  # another session still uses the cluster
    finally:
        _end(other)
    assert _last_user(ours)  # now ours is the only one: it may stop the cluster
    ours.close()
