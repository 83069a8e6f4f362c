"""The results contract between sweeps and everything that reads them (versioned).

Each run writes ``<results_dir>/runs/<run_id>.parquet``: one row with the columns below (fixed
names and types, whatever the chain), plus one ``mf_<norm>`` float column per norm of the run's
chain. Learn-time evaluations go to ``<results_dir>/runs/<run_id>.learn.parquet`` (one row per
evaluation), and the per-update diagnostics of PPO-Lag and CPO to
``<results_dir>/runs/<run_id>.updates.parquet`` (one row per policy update, :data:`UPDATE_FIELDS`).
Files are written to a temporary name and renamed, so a reader never sees half a file and a killed
run leaves no result behind.

Readers must select columns by name (never by position) and check ``schema_version``.
Bump :data:`SCHEMA_VERSION` on any incompatible change and document it in ``CHANGES`` below.

One rule for a file of another schema version (e.g. written by a newer morality-gym), whoever
reads it (:func:`version_problem`): it is no result. The leaderboard build leaves it out and lists
it under "Unreadable files"; a sweep moves it to ``runs/.quarantine/`` (kept, never deleted, with
the reason in ``runs/.quarantine/index.jsonl``) and runs the run again, as it does with a damaged
file. To use such files, read them with the version of the code that wrote them.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from morality_gym.clitools import write_atomically
from morality_gym.results.consistency import run_row_problem

SCHEMA_VERSION = 1
CHANGES = {
    1: "first version; compatible additions: the `engine` column (2026-11-23; files written before it lack it, "
    "readers treat a missing value as the single engine) and the `cpu_time_s` column (2026-11-25; null in files "
    "written before it: their compute is known only by wall_time_s)",
}

#: Fixed columns of a run row (``mf_<norm>`` columns come on top, one per norm of the chain).
RUN_FIELDS: list[pa.Field] = [
    pa.field("schema_version", pa.int32()),
    pa.field("run_id", pa.string()),  # content hash of the resolved run config
    pa.field("status", pa.string()),  # "ok" | "failed"
    pa.field("error", pa.string()),  # one-line error of a failed run, else null
    pa.field("traceback", pa.string()),
    # identity and configuration
    pa.field("env_id", pa.string()),
    pa.field("scenario", pa.string()),
    pa.field("variant", pa.string()),
    pa.field("chain", pa.string()),  # chain name, e.g. DualProcess
    pa.field("algo", pa.string()),  # config name: random | ppo | ppo_shaped | ppo_lag | cpo
    pa.field("learner", pa.string()),  # paper label: Random | PPO | PPO Shaped | PPO Lag | CPO
    pa.field("protocol", pa.string()),  # paper | corrected
    pa.field("preset", pa.string()),  # smoke | quick | paper | ...
    pa.field("seed", pa.int64()),
    pa.field("budget", pa.int64()),  # configured training budget (steps)
    pa.field("total_steps", pa.int64()),  # environment steps actually trained
    pa.field("beta", pa.float64()),
    pa.field("max_steps", pa.int64()),
    pa.field("eval_episodes", pa.int64()),
    pa.field("relevant_norms", pa.list_(pa.string())),
    # final evaluation (stochastic policy, Monte Carlo, as the paper) and its exact value
    pa.field("metric", pa.float64()),
    pa.field("metric_stderr", pa.float64()),
    pa.field("exact_metric", pa.float64()),
    pa.field("mean_return", pa.float64()),
    pa.field("mean_cost", pa.float64()),  # minimal-mode cost, scale 1, reset per episode
    pa.field("mean_length", pa.float64()),
    pa.field("truncation_rate", pa.float64()),
    pa.field("goal_rate", pa.float64()),
    # provenance
    pa.field("wall_time_s", pa.float64()),  # wall clock; a fleet's run: its share of the fleet + its own evaluation
    # CPU seconds of the worker process (all threads), shared out like wall_time_s: the compute, even on a busy
    # machine; null in files written before the column existed
    pa.field("cpu_time_s", pa.float64()),
    pa.field("started_at", pa.string()),  # ISO 8601, UTC
    pa.field("finished_at", pa.string()),
    pa.field("hostname", pa.string()),
    pa.field("git_commit", pa.string()),
    pa.field("versions", pa.string()),  # JSON {package: version}
    pa.field("config", pa.string()),  # JSON of the resolved run config
    pa.field("model_path", pa.string()),  # relative to results_dir, null if none
    pa.field("gif_path", pa.string()),  # relative to results_dir, null if none
    # how the run was trained: "single", or "fleet:K" (trained with K-1 other runs, runners/execute/jobs.py);
    # null in files written before the column existed, and for runs that never started
    pa.field("engine", pa.string()),
]

LEARN_FIELDS: list[pa.Field] = [
    pa.field("schema_version", pa.int32()),
    pa.field("run_id", pa.string()),
    pa.field("step", pa.int64()),
    pa.field("metric", pa.float64()),
    pa.field("exact_metric", pa.float64()),
    pa.field("mean_return", pa.float64()),
    pa.field("mean_cost", pa.float64()),
    pa.field("mean_length", pa.float64()),
    pa.field("wall_time_s", pa.float64()),
]

#: Per-update diagnostics of the constrained learners (``runs/<run_id>.updates.parquet``). The names
#: are a contract. Columns that do not apply to a learner are null (``passes`` and
#: ``lagrange_multiplier`` for CPO; the CPO columns for PPO-Lag).
UPDATE_FIELDS: list[pa.Field] = [
    pa.field("schema_version", pa.int32()),
    pa.field("run_id", pa.string()),
    pa.field("update", pa.int64()),  # 1-based
    pa.field("timesteps", pa.int64()),  # environment steps so far (end of the update's rollout)
    pa.field("passes", pa.int64()),  # PPO-Lag: update-loop passes actually run
    pa.field("early_stopped", pa.bool_()),  # PPO-Lag: the KL rule ended the loop
    pa.field("kl", pa.float64()),  # the KL the rule tested, as configured (PPO-Lag: sum/mean; CPO: line search)
    pa.field("kl_mean", pa.float64()),  # mean KL(old || new) over the epoch's states after the update
    pa.field("lagrange_multiplier", pa.float64()),  # PPO-Lag, after its update
    pa.field("ep_cost", pa.float64()),  # the J_c used
    pa.field("ep_cost_episodes", pa.int64()),  # finished episodes J_c averaged over
    pa.field("actor_lr", pa.float64()),  # null for CPO (trust-region step)
    pa.field("critic_lr", pa.float64()),
    pa.field("cpo_case", pa.int64()),  # OmniSafe's numbering 0-4
    pa.field("accept_step", pa.int64()),  # 0 = no step accepted, else the 1-based backtracking step
    pa.field("line_search_tried", pa.int64()),
    pa.field("step_fraction", pa.float64()),
    pa.field("lambda_star", pa.float64()),
    pa.field("nu_star", pa.float64()),
    pa.field("A", pa.float64()),
    pa.field("B", pa.float64()),
    pa.field("q", pa.float64()),
    pa.field("r", pa.float64()),
    pa.field("s", pa.float64()),
    pa.field("c", pa.float64()),  # J_c - cost_limit
    pa.field("b_norm", pa.float64()),  # |grad of the cost surrogate|
    pa.field("full_step_norm", pa.float64()),
    pa.field("step_norm", pa.float64()),  # the step taken (0 when none accepted)
    pa.field("expected_reward_change", pa.float64()),
    pa.field("surrogate_reward_change", pa.float64()),
    pa.field("surrogate_cost_change", pa.float64()),
    pa.field("policy_loss", pa.float64()),
    pa.field("value_loss", pa.float64()),
    pa.field("cost_value_loss", pa.float64()),
    pa.field("entropy", pa.float64()),
    pa.field("clip_fraction", pa.float64()),
]
UPDATE_COLUMNS = [f.name for f in UPDATE_FIELDS]

RUN_COLUMNS = [f.name for f in RUN_FIELDS]
MF_PREFIX = "mf_"


def run_schema(norms: Iterable[str]) -> pa.Schema:
    """Schema of one run file for a chain with these norms."""
    return pa.schema(RUN_FIELDS + [pa.field(f"{MF_PREFIX}{n}", pa.float64()) for n in norms])


def learn_schema(norms: Iterable[str]) -> pa.Schema:
    return pa.schema(LEARN_FIELDS + [pa.field(f"{MF_PREFIX}{n}", pa.float64()) for n in norms])


def compute_seconds(runs: Any) -> Any:
    """Each run's compute in core-seconds: ``cpu_time_s`` where recorded, else ``wall_time_s``.

    Why a fallback: files written before ``cpu_time_s`` existed know only their wall time, which
    equals the compute on a machine that ran nothing else (one worker per core, one thread each) and
    overstates it otherwise. ``runs`` is a pandas DataFrame of run rows; a Series is returned."""
    wall = runs["wall_time_s"].astype(float)
    if "cpu_time_s" not in runs:
        return wall
    return runs["cpu_time_s"].astype(float).fillna(wall)


def runs_dir(results_dir: str | Path) -> Path:
    return Path(results_dir) / "runs"


def run_path(results_dir: str | Path, run_id: str) -> Path:
    return runs_dir(results_dir) / f"{run_id}.parquet"


def learn_path(results_dir: str | Path, run_id: str) -> Path:
    return runs_dir(results_dir) / f"{run_id}.learn.parquet"


def updates_path(results_dir: str | Path, run_id: str) -> Path:
    return runs_dir(results_dir) / f"{run_id}.updates.parquet"


def atomic_write_table(table: pa.Table, path: Path) -> None:
    """Write a Parquet file atomically (:func:`~morality_gym.clitools.write_atomically`): a kill or a
    full disk leaves the previous file or none, and a full disk is a
    :class:`~morality_gym.clitools.DiskFullError` naming ``path``."""
    write_atomically(path, lambda fh: pq.write_table(table, fh))


def write_run(results_dir: str | Path, row: Mapping[str, Any], norms: Iterable[str]) -> Path:
    """Validate one run row against the schema and write it atomically; returns the path."""
    norms = list(norms)
    schema = run_schema(norms)
    missing = [name for name in schema.names if name not in row]
    extra = [name for name in row if name not in schema.names]
    if missing or extra:
        raise ValueError(f"run row does not match schema v{SCHEMA_VERSION}: missing {missing}, unexpected {extra}")
    table = pa.Table.from_pylist([dict(row)], schema=schema)
    path = run_path(results_dir, str(row["run_id"]))
    atomic_write_table(table, path)
    return path


def write_learn(results_dir: str | Path, run_id: str, rows: list[Mapping[str, Any]], norms: Iterable[str]) -> Path:
    schema = learn_schema(norms)
    table = pa.Table.from_pylist([dict(r) for r in rows], schema=schema)
    path = learn_path(results_dir, run_id)
    atomic_write_table(table, path)
    return path


def write_updates(results_dir: str | Path, run_id: str, rows: list[Mapping[str, Any]]) -> Path:
    """The per-update diagnostics of one run; keys outside :data:`UPDATE_FIELDS` are an error (so a
    new diagnostic is added to the contract, not dropped on the way)."""
    table_rows = []
    for row in rows:
        extra = [key for key in row if key not in UPDATE_COLUMNS]
        if extra:
            raise ValueError(f"update row has columns outside schema v{SCHEMA_VERSION}: {extra}")
        table_rows.append({**{name: None for name in UPDATE_COLUMNS}, **row, "schema_version": SCHEMA_VERSION, "run_id": run_id})
    table = pa.Table.from_pylist(table_rows, schema=pa.schema(UPDATE_FIELDS))
    path = updates_path(results_dir, run_id)
    atomic_write_table(table, path)
    return path


def read_updates(results_dir: str | Path, run_id: str) -> Any:
    """One run's per-update diagnostics as a DataFrame (empty if the run has none)."""
    import pandas as pd  # pandas waits: importing morality_gym.results.schema must not load it

    path = updates_path(results_dir, run_id)
    if not path.is_file():
        return pd.DataFrame(columns=UPDATE_COLUMNS)
    return pq.read_table(path).to_pandas()


def read_jsonl(path: str | Path) -> list[dict[str, Any]]:
    """The JSON objects of an append-only ``.jsonl`` log (quarantine index, migration journal).

    A missing file is empty; a torn or foreign line (a kill while appending) is skipped rather than
    failing the reader, because these logs are written line by line by processes that may die.
    """
    try:
        lines = Path(path).read_text().splitlines()
    except OSError:
        return []
    out = []
    for line in lines:
        try:
            entry = json.loads(line)
        except ValueError:
            continue
        if isinstance(entry, dict):
            out.append(entry)
    return out


def version_problem(table: pa.Table) -> str | None:
    """Why a table read from a results file is not of this code's schema (None when it is)."""
    if "schema_version" not in table.column_names:
        return "no schema_version column"
    versions = set(table.column("schema_version").to_pylist())
    if versions and versions != {SCHEMA_VERSION}:
        found = ", ".join(str(v) for v in sorted(versions, key=str))
        return f"schema version {found}, this code reads version {SCHEMA_VERSION}"
    return None


def run_files(results_dir: str | Path) -> list[Path]:
    """The main run files ``runs/<run_id>.parquet`` (not ``<run_id>.<kind>.parquet`` side files)."""
    return [p for p in sorted(runs_dir(results_dir).glob("*.parquet")) if "." not in p.stem]


def read_runs(results_dir: str | Path, skipped: list[dict[str, str]] | None = None) -> Any:
    """All run rows under ``results_dir`` as one pandas DataFrame (columns unified by name).

    A file that cannot be read, or is of another schema version, raises, unless ``skipped`` is
    given: then it is left out and reported there as ``{"file", "reason"}`` (the leaderboard builds
    from what is readable and lists the rest; it never moves files, see :mod:`morality_gym.results.quarantine`).
    """
    import pandas as pd  # pandas waits: importing morality_gym.results.schema must not load it

    tables = []
    for path in run_files(results_dir):
        try:
            table = read_small_table(path)
            problem = version_problem(table) or table_problem(table, path)
            if problem is not None:
                raise ValueError(problem)
        except (pa.ArrowException, OSError, ValueError, KeyError, IndexError) as exc:
            if skipped is None:
                raise ValueError(f"{path}: {exc}") from exc
            first = (str(exc).strip().splitlines() or [""])[0][:200]
            skipped.append({"file": str(path), "reason": f"{type(exc).__name__}: {first}"})
            continue
        tables.append(table)
    if not tables:
        return pd.DataFrame(columns=RUN_COLUMNS)
    return concat_tables(tables)


def table_problem(table: pa.Table, path: Path) -> str | None:
    """What in a main run file's one row disagrees with itself or with the file's name
    (:func:`morality_gym.results.consistency.run_row_problem`), or None."""
    if table.num_rows != 1:
        return None
    # only the columns the check reads (converting the whole row cost more than reading the file)
    row = {name: table.column(name)[0].as_py() for name in CONSISTENCY_COLUMNS if name in table.column_names}
    if row.get("status") == "ok":
        functions = {name[len(MF_PREFIX):]: table.column(name)[0].as_py()
                     for name in table.column_names if name.startswith(MF_PREFIX)}
    else:
        functions = {}
    return run_row_problem(row, functions, path)


#: What :func:`table_problem` reads of a run row besides its ``mf_*`` columns.
CONSISTENCY_COLUMNS = ("run_id", "status", "metric", "exact_metric", "eval_episodes", "beta", "relevant_norms", "chain", "config")


def read_small_table(path: Path) -> pa.Table:
    """One small Parquet file, single-threaded: for a file of one row (or a few dozen) the thread
    pool and dataset machinery of ``pq.read_table`` cost more than the reading (~1 ms CPU a file)."""
    return pq.ParquetFile(path).read(use_threads=False, use_pandas_metadata=True)


def concat_tables(tables: list[pa.Table]) -> Any:
    """Tables of several files as one DataFrame, columns unified by name in order of appearance.

    Concatenated by Arrow and converted once: converting thousands of one-row tables and
    concatenating the frames took seconds (pandas reindexes each frame onto the union of columns).
    Tables whose types cannot be unified (an old file with an int where a float is now) take
    pandas' path, which upcasts as before."""
    import pandas as pd  # pandas waits: importing morality_gym.results.schema must not load it

    try:
        return pa.concat_tables(tables, promote_options="default").to_pandas()
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError):
        return pd.concat([t.to_pandas() for t in tables], ignore_index=True, sort=False)


def read_learn(results_dir: str | Path) -> Any:
    import pandas as pd  # pandas waits: importing morality_gym.results.schema must not load it

    tables = [read_small_table(p) for p in sorted(runs_dir(results_dir).glob("*.learn.parquet"))]
    return concat_tables(tables) if tables else pd.DataFrame(columns=[f.name for f in LEARN_FIELDS])
