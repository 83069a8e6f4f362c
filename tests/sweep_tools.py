"""Helpers shared by the tests that drive real sweep subprocesses (test_sweep, test_faults)."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path


def run_files(results: Path) -> dict[str, Path]:
    """Main run files by run id (not the ``.learn``/``.updates`` side files, not the quarantine)."""
    return {p.stem: p for p in (results / "runs").glob("*.parquet") if "." not in p.stem}


def wait_for_results(results: Path, n: int, proc: subprocess.Popen, timeout: float = 300) -> None:
    """Block until ``n`` runs have a result file; fail if the sweep died or stalled first."""
    deadline = time.monotonic() + timeout
    while len(run_files(results)) < n:
        assert proc.poll() is None, proc.stdout.read() if proc.stdout else ""
        assert time.monotonic() < deadline, "the sweep made no progress"
        time.sleep(0.1)


def children(pid: int) -> list[int]:
    """The ids of ``pid``'s child processes, read from /proc (the field after the command name is the parent)."""
    out = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            try:
                fields = (proc / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(proc.name))
    return out
