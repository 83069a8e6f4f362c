"""Reproducible builds (issue 13): the same results give byte-identical tables, figures, pages and downloads.

Two builds of the same synthetic results directory into two different output directories must
produce the same files with the same bytes; the date they show comes from the newest run (or
``SOURCE_DATE_EPOCH``), never from the clock. A bad ``SOURCE_DATE_EPOCH`` is a one-line error.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.leaderboard_data import REPO, BuiltSite, shared_build


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> BuiltSite:
    out = shared_build(tmp_path_factory.getbasetemp() / "leaderboard-shared")
    assert out.proc.returncode == 0, out.proc.stderr + out.proc.stdout
    return out


def _build(results: Path, out: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    # the exact reference rows are cached in --out: start both builds from the same cache (computing
    # them is deterministic too, only slower)
    (out / "cache").mkdir(parents=True)
    shutil.copy(results / "cache" / "reference_rows.json", out / "cache" / "reference_rows.json")
    return subprocess.run([sys.executable, "-m", "leaderboard.build", "--results", str(results), "--out", str(out),
                           "--site", str(out / "site")], cwd=REPO, capture_output=True, text=True, timeout=600,
                          env=env if env is not None else {k: v for k, v in os.environ.items() if k != "SOURCE_DATE_EPOCH"},
                          check=False)


def _digests(directory: Path) -> dict[str, str]:
    return {str(p.relative_to(directory)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(directory.rglob("*")) if p.is_file() and "cache" not in p.relative_to(directory).parts}


def test_two_builds_are_byte_identical(built: BuiltSite, tmp_path: Path) -> None:
    first, second = tmp_path / "a", tmp_path / "b"
    for out in (first, second):
        proc = _build(built.results, out)
        assert proc.returncode == 0, proc.stderr
    a, b = _digests(first), _digests(second)
    assert a.keys() == b.keys()
    different = sorted(name for name in a if a[name] != b[name])
    assert different == [], different
    # the comparison covers what matters: pages, figures (also the statistics ones), tables, downloads
    names = set(a)
    assert {"site/index.html", "site/ranking.html", "table1.md", "table1.csv", "site/data/runs.parquet"} <= names
    assert any(n.startswith("site/figures/") and n.endswith(".png") and "/stats/" in n for n in names)
    assert any(n.startswith("figures/learn/") for n in names)
    # the date is the newest run's, not the clock's
    newest = max(r["finished_at"] for r in built.data.records if r.get("finished_at"))[:16].replace("T", " ")
    assert f"built {newest} UTC (newest run)" in (first / "site" / "index.html").read_text()
    assert f"built {newest} UTC (newest run)" in (first / "table1.md").read_text()


def test_source_date_epoch_sets_the_date_and_a_bad_one_is_refused(built: BuiltSite, tmp_path: Path) -> None:
    env = dict(os.environ, SOURCE_DATE_EPOCH="1700000000")
    proc = _build(built.results, tmp_path / "epoch", env)
    assert proc.returncode == 0, proc.stderr
    assert "2023-11-14 22:13 UTC (SOURCE_DATE_EPOCH)" in (tmp_path / "epoch" / "site" / "index.html").read_text()
    proc = _build(built.results, tmp_path / "bad", dict(os.environ, SOURCE_DATE_EPOCH="yesterday"))
    assert proc.returncode == 2
    assert "SOURCE_DATE_EPOCH='yesterday' is not a Unix time" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_built_files_get_the_umasks_mode_as_cp_would_give(built: BuiltSite, tmp_path: Path, umask: int) -> None:
    """Issue 45: the site was created 0700 and its pages 0600 (mkdtemp/mkstemp kept through the rename),
    so no web server running as another user could serve it. Every file and directory written, site,
    tables and caches alike, gets the mode a plain ``open()``/``cp`` would give under the umask."""
    out = tmp_path / "out"
    (out / "cache").mkdir(parents=True)
    shutil.copy(built.results / "cache" / "reference_rows.json", out / "cache" / "reference_rows.json")
    proc = subprocess.run([sys.executable, "-m", "leaderboard.build", "--results", str(built.results), "--out", str(out),
                           "--site", str(out / "site")], cwd=REPO, capture_output=True, text=True, timeout=600,
                          check=False, preexec_fn=lambda: os.umask(umask))
    assert proc.returncode == 0, proc.stderr
    wrong = {str(p.relative_to(out)): oct(p.stat().st_mode & 0o777) for p in [out / "site", *(out / "site").rglob("*"),
                                                                              *(out / "figures").rglob("*")]
             if p.stat().st_mode & 0o777 != (0o777 if p.is_dir() else 0o666) & ~umask}
    assert wrong == {}, sorted(wrong.items())[:10]
    assert len(list((out / "site" / "runs").glob("*.html"))) > 10
