"""The SLURM test fixture's hand-over between test sessions (no cluster needed).

The session that started the cluster used to stop it at its end even while another ``pytest`` run
on the machine had an array task running, which slurm_down.sh then cancelled. Each session now
holds a shared lock while it uses the cluster; only the last one out may stop it.
"""

from __future__ import annotations

import fcntl
import subprocess
import sys
from pathlib import Path

from tests.slurm_cluster import _last_user

HOLD = """
import fcntl, sys, time
f = open(sys.argv[1], "a")
fcntl.flock(f, fcntl.LOCK_SH)
print("holding", flush=True)
sys.stdin.read()  # until the test closes our stdin
"""


def test_the_last_session_out_is_the_only_one_that_may_stop_the_cluster(tmp_path: Path) -> None:
    lock = tmp_path / "users.lock"
    ours = lock.open("a")
    fcntl.flock(ours, fcntl.LOCK_SH)
    other = subprocess.Popen([sys.executable, "-c", HOLD, str(lock)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             text=True)
    try:
        assert other.stdout is not None and other.stdout.readline().strip() == "holding"
        assert not _last_user(ours)  # another session still uses the cluster
    finally:
        assert other.stdin is not None
        other.stdin.close()
        other.wait(timeout=30)
    assert _last_user(ours)  # now ours is the only one: it may stop the cluster
    ours.close()
