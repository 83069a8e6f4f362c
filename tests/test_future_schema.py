"""A run file of another schema version (issue 33): one rule for the sweep, the build and the docs.

Before: the sweep counted such a file done (``1 ok, 0 missing``), the build counted its run
missing, and ``table1.md`` said a sweep would move it aside and run it again, which it did not:
the cell stayed incomplete for good. Now (:func:`runners.results_schema.version_problem`): no
reader takes it as a result; the build lists it as unreadable, a sweep moves it to
``runs/.quarantine/`` (kept byte for byte) and runs the run again.
"""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from morality_gym.results.schema import SCHEMA_VERSION, read_runs
from tests.sweep_tools import run_files

REPO = Path(__file__).resolve().parents[1]
ARGS = ["algo=random", "chain=utility", "scenario=[switch_standard]", "variant=[HumanA,HumanB]", "preset=smoke",
        "seed=[41]", "gif=false", "mlflow=false"]


def command(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)
    return subprocess.run([sys.executable, *args], cwd=REPO, check=False, capture_output=True, text=True, timeout=600, env=env)


def as_future_version(path: Path) -> bytes:
    """Rewrite a run file as a newer morality-gym would (schema version + 1); its bytes."""
    table = pq.read_table(path)
    index = table.column_names.index("schema_version")
    table = table.set_column(index, table.schema.field(index), pa.array([SCHEMA_VERSION + 1], pa.int32()))
    pq.write_table(table, path)
    return path.read_bytes()


@pytest.mark.slow
def test_a_run_file_of_a_future_schema_is_listed_by_the_build_and_run_again_by_the_sweep(tmp_path: Path) -> None:
    results, site = tmp_path / "r", tmp_path / "site"
    out = command("-m", "runners.sweep", f"results_dir={results}", *ARGS)
    assert out.returncode == 0, out.stderr
    victim_id, victim = min(run_files(results).items())
    future = as_future_version(victim)
    reason = f"schema version {SCHEMA_VERSION + 1}, this code reads version {SCHEMA_VERSION}"

    build = ["-m", "leaderboard.build", "--results", str(results), "--site", str(site), "--no-reference"]
    out = command(*build)
    assert out.returncode == 0, out.stderr
    assert f"SKIPPED {victim}" in out.stdout
    md = (results / "table1.md").read_text()
    assert "## Unreadable files, left out (1)" in md and reason in md
    assert "moves such files to `runs/.quarantine/` and runs them again" in md  # the promise the sweep keeps
    assert cell_runs(results) == 1  # the run counts as missing, not as done

    out = command("-m", "runners.sweep", f"results_dir={results}", *ARGS)
    assert out.returncode == 0, out.stderr
    said = " ".join(out.stderr.split())
    assert f"moved unreadable runs/{victim.name} to runs/.quarantine/{victim.name} (ValueError: {reason}); " \
           "the run is planned again" in said, out.stderr
    assert "1 done, 1 to run" in said and "2 ok, 0 failed, 0 missing" in said
    assert (results / "runs" / ".quarantine" / victim.name).read_bytes() == future  # kept for the newer code
    runs = read_runs(results)
    assert sorted(runs.run_id) == sorted(run_files(results)) and victim_id in set(runs.run_id)
    assert (runs.schema_version == SCHEMA_VERSION).all() and (runs.status == "ok").all()

    out = command(*build)
    assert out.returncode == 0, out.stderr
    assert "files moved aside by sweeps: 1" in out.stdout
    assert "Unreadable files, left out" not in (results / "table1.md").read_text()
    assert cell_runs(results) == 2


def cell_runs(results: Path) -> int:
    """The runs the build counts in the cell (Utility, SwitchStandard, Random)."""
    with (results / "table1.csv").open() as fh:
        rows = [r for r in csv.DictReader(fh) if (r["chain"], r["scenario"], r["learner"]) == ("Utility", "SwitchStandard", "Random")]
    assert len(rows) == 1
    return int(rows[0]["n_runs"])
