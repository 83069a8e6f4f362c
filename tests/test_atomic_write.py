"""The project's one atomic writer, :func:`morality_gym.clitools.write_atomically`, and the writers
built on it: whole files or the previous ones, the umask's mode, unique temporary names per call."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path
from typing import BinaryIO

import pyarrow as pa
import pytest

from leaderboard.runs.reference_rows import _write_json_atomic
from leaderboard.web.content_cache import atomic_write
from morality_gym.clitools import write_atomically
from morality_gym.results.schema import atomic_write_table
from runners.migrate import _write_json
from runners.record.fleet_checkpoints import _runs_path, write_fleet_runs


def _leftovers(directory: Path) -> list[Path]:
    return [p for p in directory.iterdir() if p.name.endswith(".tmp")]


def test_threads_of_one_process_writing_one_file_never_share_a_temporary_name(tmp_path: Path) -> None:
    # A name made of the pid alone (the writer's old one) makes the second thread's "xb" open fail
    # while the first is still writing: the site writes its pages from a thread pool.
    target = tmp_path / "page.html"
    errors: list[BaseException] = []
    barrier = threading.Barrier(6)

    def write(i: int) -> None:
        def body(fh: BinaryIO) -> None:
            fh.write(f"writer {i} ".encode() * 100)
            time.sleep(0.05)  # every thread holds its temporary file at the same time

        try:
            barrier.wait()
            write_atomically(target, body)
        except BaseException as exc:  # noqa: BLE001 - collected for the assertion
            errors.append(exc)

    threads = [threading.Thread(target=write, args=(i,)) for i in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    text = target.read_text()
    assert text in {f"writer {i} " * 100 for i in range(6)}  # one whole file, not a mix
    assert _leftovers(tmp_path) == []


def test_a_failed_write_keeps_the_previous_file_and_leaves_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "table.json"
    target.write_text("old")

    def fail(fh: BinaryIO) -> None:
        fh.write(b"half of the new")
        raise RuntimeError("killed")

    with pytest.raises(RuntimeError, match="killed"):
        write_atomically(target, fail)
    assert target.read_text() == "old"
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize("durable, syncs", [(True, 1), (False, 0)])
def test_only_a_durable_write_is_fsynced(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, durable: bool, syncs: int) -> None:
    calls: list[int] = []
    real = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (calls.append(fd), real(fd))[1])
    write_atomically(tmp_path / "f", lambda fh: fh.write(b"x"), durable=durable)
    assert len(calls) == syncs


def _every_writer(directory: Path) -> list[Path]:
    """One file from each writer built on :func:`write_atomically`; returns their paths."""
    table = pa.table({"a": [1, 2]})
    atomic_write_table(table, directory / "run.parquet")
    atomic_write(directory / "page.html", b"<p>")
    _write_json_atomic(directory / "reference.json", {"a": 1})
    _write_json(directory / "manifest.json", {"runs": []})
    checkpoint = write_fleet_runs(directory, [])
    return [
        directory / "run.parquet",
        directory / "page.html",
        directory / "reference.json",
        directory / "manifest.json",
        _runs_path(checkpoint),
    ]


@pytest.mark.parametrize("mask", [0o022, 0o027])
def test_every_writer_gives_the_umasks_mode_not_mkstemps_0600(tmp_path: Path, mask: int) -> None:
    old = os.umask(mask)
    try:
        paths = _every_writer(tmp_path)
    finally:
        os.umask(old)
    for path in paths:
        assert path.is_file(), path
        assert path.stat().st_mode & 0o777 == 0o666 & ~mask, path
    assert json.loads((tmp_path / "manifest.json").read_text()) == {"runs": []}
    assert [p for p in tmp_path.rglob("*") if p.name.endswith(".tmp")] == []
