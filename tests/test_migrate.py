"""runners.migrate: a results directory written before c0db801 counts again at the current code.

A real sweep at the current code (smoke preset, 2 runs: Random and PPO-Lag, with GIFs, models and
the MLflow mirror) is turned into the directory the code before c0db801 would have written: every
config through the inverse vocabulary (checked against the algo specs 4ec25b0's planner produced,
``tests/data/algo_specs_c0db801.json``), the ids hashed from it, every file renamed, the model
sidecars in the old words, the manifest and the MLflow mirror rebuilt under the old ids. Migrating
it must give back the original directory: the same ids, the same data, byte for byte.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from morality_gym.results.identity import config_key, run_id_of
from morality_gym.results.manifest import manifest_name, read_manifests
from morality_gym.results.schema import learn_path, run_path, runs_dir, updates_path
from runners.migrate import MigrateError, migrate, read_journal
from runners.record.rename_history import (
    LEARNER_TARGET,
    MIGRATIONS,
    MigrationError,
    migrate_config,
    unmigrate_config,
    unmigrate_sidecar,
    vocabulary_only,
)
from tests.sweep_tools import run_files

REPO = Path(__file__).resolve().parents[1]
SPECS = json.loads((REPO / "tests" / "data" / "algo_specs_c0db801.json").read_text())["algo"]
SELECTION = ["algo=[random,ppo_lag]", "chain=utility", "scenario=[switch_standard]", "variant=[HumanA]", "seed=[41]", "preset=smoke"]

pytestmark = pytest.mark.slow


def sweep(results: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)
    cmd = [sys.executable, "-m", "runners.sweep", f"results_dir={results}", *args]
    return subprocess.run(cmd, cwd=REPO, check=False, capture_output=True, text=True, timeout=900, env=env)


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "runners.migrate", *args], cwd=REPO, check=False, capture_output=True, text=True, timeout=600)


def mlflow_tags(results: Path) -> list[str]:
    from mlflow.tracking import MlflowClient

    client = MlflowClient(f"sqlite:///{results / 'mlflow.db'}")
    exp = client.get_experiment_by_name("morality-gym")
    return sorted(r.data.tags["run_id"] for r in client.search_runs([exp.experiment_id], max_results=1000))


def snapshot(results: Path) -> dict[str, Any]:
    """Everything a run is: its tables (schema and data) and its artifacts' bytes, by file name."""
    out: dict[str, Any] = {}
    for path in sorted(runs_dir(results).rglob("*")):
        rel = str(path.relative_to(results))
        if path.is_dir() or "/." in "/" + rel.split("runs/", 1)[1]:  # .locks, .quarantine, staging
            continue
        out[rel] = pq.read_table(path) if path.suffix == ".parquet" else path.read_bytes()
    return out


def same_table(a: pa.Table, b: pa.Table) -> bool:
    """Same schema (types, metadata) and the same values, NaN where NaN was."""
    return a.schema.equals(b.schema, check_metadata=True) and a.to_pandas().equals(b.to_pandas())


def same(a: dict[str, Any], b: dict[str, Any]) -> bool:
    return a.keys() == b.keys() and all(
        (same_table(x, b[k]) if isinstance(x, pa.Table) else x == b[k]) for k, x in a.items())


def files_state(results: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(results)): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(results.rglob("*")) if p.is_file()}


# ------------------------------------------------------------------ turning a directory into a pre-c0db801 one
def _set(table: pa.Table, name: str, value: Any) -> pa.Table:
    i = table.schema.get_field_index(name)
    return table.set_column(i, table.schema.field(i), pa.array([value] * table.num_rows, type=table.schema.field(i).type))


def make_old(results: Path) -> dict[str, str]:
    """Rewrite ``results`` as the code before c0db801 would have written it; returns {old id: new id}."""
    from runners.record.mlflow_mirror import Tracker, marker_path

    ids: dict[str, str] = {}
    for new_id, path in run_files(results).items():
        table = pq.read_table(path)
        row = table.to_pylist()[0]
        config = json.loads(row["config"])
        old = unmigrate_config(config, [LEARNER_TARGET])
        assert old["algo"] == SPECS[f"{config['preset']}/{config['protocol']['name']}/{config['algo']['name']}"]["4ec25b0"]
        old_id = run_id_of(old)
        ids[old_id] = new_id
        for column, value in (("run_id", old_id), ("config", json.dumps(old, sort_keys=True)),
                              ("model_path", row["model_path"] and row["model_path"].replace(new_id, old_id)),
                              ("gif_path", row["gif_path"] and row["gif_path"].replace(new_id, old_id))):
            table = _set(table, column, value)
        pq.write_table(table, run_path(results, old_id))
        path.unlink()
        for side in (learn_path, updates_path):
            if side(results, new_id).is_file():
                pq.write_table(_set(pq.read_table(side(results, new_id)), "run_id", old_id), side(results, old_id))
                side(results, new_id).unlink()
        artifacts = runs_dir(results) / old_id
        os.rename(runs_dir(results) / new_id, artifacts)
        sidecar = artifacts / "model.json"
        meta = unmigrate_sidecar(json.loads(sidecar.read_text()), [LEARNER_TARGET])
        assert list(meta)[:3] == ["algo", "label", "implementation"] and '"target"' not in json.dumps(meta)
        sidecar.write_text(json.dumps(meta, indent=1))
        marker_path(results, new_id).unlink()
    for manifest in read_manifests(results):
        body = json.loads((results / "manifests" / f"{manifest['_file']}.json").read_text())
        by_new = {v: k for k, v in ids.items()}
        for entry in body["runs"]:
            entry["run_id"] = by_new[entry["run_id"]]
            config = json.loads(pq.read_table(run_path(results, entry["run_id"]), columns=["config"]).column(0)[0].as_py())
            entry["config_key"] = config_key(config)
        sweep_name = body["name"].rsplit("-", 1)[0]
        body["name"] = manifest_name(sweep_name, [e["run_id"] for e in body["runs"]])
        (results / "manifests" / f"{manifest['_file']}.json").unlink()
        (results / "manifests" / f"{body['name']}.json").write_text(json.dumps(body, indent=1))
    os.unlink(results / "mlflow.db")  # the mirror as the old code made it: runs tagged with the old ids
    shutil.rmtree(results / "mlartifacts")
    tracker = Tracker(results)
    for old_id in ids:
        tracker.sync(old_id)
    return ids


@pytest.fixture(scope="module")
def dirs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    base = tmp_path_factory.mktemp("migrate")
    current = base / "current"
    out = sweep(current, *SELECTION)
    assert out.returncode == 0, out.stdout + out.stderr
    assert len(run_files(current)) == 2
    original = snapshot(current)
    manifests = sorted(p.name for p in (current / "manifests").glob("*.json"))
    old = base / "old"
    shutil.copytree(current, old)
    ids = make_old(old)
    return {"base": base, "current": current, "old": old, "original": original, "ids": ids, "manifests": manifests}


def fresh(dirs: dict[str, Any], name: str, mlflow: bool = True) -> Path:
    target = dirs["base"] / name
    if target.exists():
        shutil.rmtree(target)
    shutil.copytree(dirs["old"], target)
    if not mlflow:  # a directory swept with mlflow=false: no mirror to update
        for item in ("mlflow.db", "mlartifacts", "tracking"):
            path = target / item
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    return target


def assert_migrated(dirs: dict[str, Any], results: Path, mlflow: bool = True) -> None:
    """The directory is the original one again: same ids, same data, same manifest."""
    assert same(snapshot(results), dirs["original"])
    assert sorted(p.name for p in (results / "manifests").glob("*.json")) == dirs["manifests"]
    manifest = read_manifests(results)[0]
    assert {r["run_id"] for r in manifest["runs"]} == set(dirs["ids"].values())
    for entry in manifest["runs"]:
        config = json.loads(pq.read_table(run_path(results, entry["run_id"]), columns=["config"]).column(0)[0].as_py())
        assert entry["config_key"] == config_key(config)
    assert not any(p.name.startswith(".migrating-") for p in runs_dir(results).iterdir())
    if mlflow:
        assert mlflow_tags(results) == sorted(dirs["ids"].values())
        assert sorted(p.stem for p in (results / "tracking").glob("*.json")) == sorted(dirs["ids"].values())


# ------------------------------------------------------------------ the migrations themselves
def test_migrations_map_4ec25b0_specs_to_current_ones_exactly() -> None:
    """Every built-in algo spec the planner produced before c0db801 (5 learners, 3 presets, both
    protocols) migrates to the spec the current planner produces, and back."""
    for key, pair in SPECS.items():
        old = {"algo": pair["4ec25b0"], "budget": 0 if key.endswith("/random") else 2048}
        new, applied = migrate_config(old)
        assert applied == [LEARNER_TARGET] and new["algo"] == pair["current"], key
        assert unmigrate_config(new, applied) == old
        assert migrate_config(new) == (new, [])  # current: nothing applies


def test_a_submitted_run_loses_implementation_and_nothing_else() -> None:
    old = {"algo": {"name": "submitted", "label": "Mine", "implementation": "submitted"}, "budget": 0, "provenance": {"submitter": "me"}}
    new, applied = migrate_config(old)
    assert [m.name for m in applied] == ["submitted-no-implementation"] and new["algo"] == {"name": "submitted", "label": "Mine"}
    assert MIGRATIONS[-1].commit == "40d6126" and unmigrate_config(new, applied) == old


def test_only_vocabulary_may_change() -> None:
    touches = frozenset({"algo.implementation", "algo.target"})
    old = {"algo": {"implementation": "ppo", "hparams": {"n_steps": 2048}}, "beta": 0.1}
    assert vocabulary_only(old, {"algo": {"target": "x.Y", "hparams": {"n_steps": 2048}}, "beta": 0.1}, touches) is None
    assert "algo.hparams.n_steps" in vocabulary_only(old, {"algo": {"target": "x.Y", "hparams": {"n_steps": 2049}}, "beta": 0.1}, touches)
    assert "beta" in vocabulary_only(old, {"algo": {"target": "x.Y", "hparams": {"n_steps": 2048}}, "beta": 1}, touches)
    assert "non-text" in vocabulary_only(old, {"algo": {"implementation": 3, "hparams": {"n_steps": 2048}}, "beta": 0.1}, touches)
    with pytest.raises(MigrationError, match="does not build"):  # a spec the current code would refuse
        migrate_config({"algo": {"name": "ppo", "label": "PPO", "implementation": "ppo", "n_envs": 0}, "budget": 1})


# ------------------------------------------------------------------ the command on a real directory
def test_old_directory_is_planned_again_then_migrated_counts(dirs: dict[str, Any]) -> None:
    old = fresh(dirs, "main")
    before = sweep(old, *SELECTION, "dry_run=true", "mlflow=false")
    assert before.returncode == 0 and "(0 done, 2 to run)" in before.stderr  # the problem
    # that dry run recorded its plan under the current ids: the migrated manifest takes its place
    out = cli(str(old))
    assert out.returncode == 0, out.stdout + out.stderr
    assert "2 migrated" in out.stdout and "learner-target" in out.stdout
    assert_migrated(dirs, old)
    after = sweep(old, *SELECTION, "dry_run=true", "mlflow=false")
    assert after.returncode == 0 and "(2 done, 0 to run)" in after.stderr, after.stderr
    from leaderboard.build import load
    from leaderboard.runs.aggregate import aggregate

    runs, planned, skipped = load(old)
    board = aggregate(runs, planned)
    assert len(board.superseded) == 0 and len(board.missing) == 0 and not skipped and len(runs) == 2
    journal = read_journal(old)
    assert sorted(e["old"] for e in journal if e["event"] == "done") == sorted(dirs["ids"])
    state = files_state(old)
    again = cli(str(old))
    assert again.returncode == 0 and "nothing to do" in again.stdout and "2 current" in again.stdout
    assert files_state(old) == state  # idempotent: not one file touched


def test_dry_run_writes_nothing(dirs: dict[str, Any]) -> None:
    old = fresh(dirs, "dry")
    state = files_state(old)
    out = cli(str(old), "--dry-run")
    assert out.returncode == 0, out.stderr
    assert "2 to migrate" in out.stdout and "nothing was written" in out.stdout
    for old_id, new_id in dirs["ids"].items():
        assert old_id in out.stdout and new_id in out.stdout
    assert files_state(old) == state and not (old / "migrations").exists()


def test_a_killed_migration_resumes_cleanly_at_every_step(dirs: dict[str, Any]) -> None:
    """Stopped after each change on disk in turn (no MLflow: a directory swept with mlflow=false),
    the next migration finishes it: the original directory, nothing lost, nothing twice."""
    steps: list[str] = []
    migrate(fresh(dirs, "count", mlflow=False), on_step=steps.append, progress=False)
    assert len(steps) > 15

    class Killed(BaseException):
        pass

    for k in range(len(steps)):
        results = fresh(dirs, "kill", mlflow=False)

        def stop(what: str, left: list[int] = [k]) -> None:  # noqa: B006 - the default is the shared countdown
            if left[0] == 0:
                raise Killed(what)
            left[0] -= 1

        with pytest.raises(Killed):
            migrate(results, on_step=stop, progress=False)
        report = migrate(results, progress=False)
        assert not any(m.status in ("left", "duplicate") for m in report.moves), (k, steps[k])
        assert_migrated(dirs, results, mlflow=False)


@pytest.mark.parametrize("after", ["mlflow: deleted", "mlflow: mirrored", "removed runs/"])
def test_sigkill_with_the_mlflow_mirror_then_resume(dirs: dict[str, Any], after: str) -> None:
    """A real SIGKILL of the migration process, around the MLflow step of the first run."""
    results = fresh(dirs, "sigkill")
    code = ("import os, signal, sys; from runners.migrate import migrate\n"
            f"def step(what):\n    if what.startswith({after!r}): os.kill(os.getpid(), signal.SIGKILL)\n"
            f"migrate({str(results)!r}, on_step=step, progress=False)\n")
    killed = subprocess.run([sys.executable, "-c", code], cwd=REPO, check=False, capture_output=True, text=True, timeout=600)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    out = cli(str(results))
    assert out.returncode == 0, out.stdout + out.stderr
    assert_migrated(dirs, results)


def test_a_run_done_again_at_the_current_code_is_a_duplicate(dirs: dict[str, Any]) -> None:
    results = fresh(dirs, "dup", mlflow=False)
    rerun = sweep(results, *[a if not a.startswith("algo=") else "algo=random" for a in SELECTION], "mlflow=false")
    assert rerun.returncode == 0, rerun.stderr
    random_new = next(n for o, n in dirs["ids"].items() if json.loads(
        pq.read_table(run_path(results, o), columns=["config"]).column(0)[0].as_py())["algo"]["name"] == "random")
    random_old = next(o for o, n in dirs["ids"].items() if n == random_new)
    kept = pq.read_table(run_path(results, random_old))
    redone = pq.read_table(run_path(results, random_new))
    report = migrate(results, progress=False)
    status = {m.old_id: m.status for m in report.moves}
    assert status[random_old] == "duplicate" and status[random_new] == "current"
    assert sorted(s for s in status.values()) == ["current", "duplicate", "migrated"]
    assert same_table(pq.read_table(run_path(results, random_old)), kept)  # left as it was
    assert same_table(pq.read_table(run_path(results, random_new)), redone)  # never overwritten
    assert (runs_dir(results) / random_old).is_dir()
    out = cli(str(results), "--dry-run")
    assert "duplicate" in out.stdout and random_old in out.stdout


def test_refuses_while_a_sweep_holds_run_locks_and_bad_input(dirs: dict[str, Any], tmp_path: Path) -> None:
    from morality_gym.results.recording import RunLock

    results = fresh(dirs, "locked-in-a-directory-whose-path-is-longer-than-a-terminal-line", mlflow=False)
    lock = RunLock(results, "0123456789abcdef")
    assert lock.acquire()
    try:
        state = files_state(results)
        out = cli(str(results))
        assert out.returncode == 2 and out.stderr.count("\n") == 1, out.stderr
        assert "a sweep is running here" in out.stderr and "0123456789abcdef" in out.stderr
        assert files_state(results) == state
        with pytest.raises(MigrateError):
            migrate(results, progress=False)
        dry = cli(str(results), "--dry-run")  # a look is allowed, with a warning
        assert dry.returncode == 0
        warning = next(line for line in dry.stderr.splitlines() if line.startswith("warning:"))
        assert "a sweep is running here" in warning and warning.endswith("then migrate")  # one line, however long the path
    finally:
        lock.release()
    missing = cli(str(tmp_path / "nope"))
    assert missing.returncode == 2 and "no such directory" in missing.stderr
    (tmp_path / "empty").mkdir()
    empty = cli(str(tmp_path / "empty"))
    assert empty.returncode == 2 and "not a results directory" in empty.stderr


def test_a_run_that_does_not_hash_to_its_id_is_left_alone(dirs: dict[str, Any]) -> None:
    results = fresh(dirs, "edited", mlflow=False)
    old_id = next(iter(dirs["ids"]))
    table = pq.read_table(run_path(results, old_id))
    config = json.loads(table.column("config")[0].as_py())
    config["beta"] = 0.2  # edited by hand: the id no longer says what the run is
    pq.write_table(_set(table, "config", json.dumps(config, sort_keys=True)), run_path(results, old_id))
    report = migrate(results, progress=False)
    move = next(m for m in report.moves if m.old_id == old_id)
    assert move.status == "left" and "does not hash to its run id" in move.reason
    assert run_path(results, old_id).is_file() and (runs_dir(results) / old_id).is_dir()
    assert report.count("migrated") == 1
