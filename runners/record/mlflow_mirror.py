"""Mirror finished runs into MLflow, idempotently, from their Parquet files.

The Parquet files are the source of truth; MLflow is a browsable mirror. Only a sweep's parent
process logs, after each run finishes and again at the end of every sweep for anything not yet
mirrored (runs finished while the parent was killed, runs that came back from SLURM). A marker
file ``<results>/tracking/<run_id>.json`` records the MLflow run id; MLflow runs carry the run id
as a tag, so a mirror interrupted half-way is found and replaced rather than duplicated: the
interrupted MLflow run is marked ``KILLED`` and deleted, so the store keeps exactly one active run
per result file and no run left ``RUNNING``.

Two sweeps may share a results directory (started at the same time by accident, or one per
protocol). Their parents then both write to MLflow, so every write (opening the store, which
creates the SQLite schema on first use, and each run's mirror, from the marker check to the
marker write) holds an exclusive lock on ``<results>/tracking/.lock``: MLflow's schema set-up
never races and a run is never mirrored twice. A tracking server that does not answer is found
before the sweep starts (:func:`check_reachable`), in seconds, instead of after minutes of retries.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import math
import os
import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

from morality_gym.clitools import disk_full_error, is_disk_full, write_atomically
from morality_gym.results.quarantine import read_table_or_quarantine
from morality_gym.results.schema import MF_PREFIX, UPDATE_COLUMNS, learn_path, run_path, updates_path

EXPERIMENT = "morality-gym"
_METRICS = ("metric", "metric_stderr", "exact_metric", "mean_return", "mean_cost", "mean_length", "truncation_rate", "goal_rate", "wall_time_s", "cpu_time_s", "total_steps")


def tracking_uri(results_dir: str | Path) -> str:
    """``MLFLOW_TRACKING_URI`` if set, else an embedded SQLite store under ``results_dir``."""
    return os.environ.get("MLFLOW_TRACKING_URI") or f"sqlite:///{Path(results_dir).resolve() / 'mlflow.db'}"


def marker_path(results_dir: str | Path, run_id: str) -> Path:
    return Path(results_dir) / "tracking" / f"{run_id}.json"


class TrackingError(RuntimeError):
    """The MLflow store cannot be used; the message says which and how to fix or avoid it."""


#: How long the up-front check waits for a tracking server.
CONNECT_TIMEOUT_S = 5.0
#: MLflow's HTTP client retries for minutes by default; a mirror that fails is retried by the next
#: sweep anyway, so a sweep waits less (a user's own setting of these variables wins).
HTTP_DEFAULTS = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "2", "MLFLOW_HTTP_REQUEST_TIMEOUT": "30"}
_FIX = "start the server or correct MLFLOW_TRACKING_URI, or run the sweep without MLflow: mlflow=false"


def check_reachable(results_dir: str | Path, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """Raise :class:`TrackingError` unless the tracking store can be reached/written, in seconds."""
    uri = tracking_uri(results_dir)
    parsed = urlparse(uri)
    if parsed.scheme in ("http", "https"):
        host = parsed.hostname
        port = parsed.port or (443 if parsed.scheme == "https" else 80)
        if not host:
            raise TrackingError(f"MLFLOW_TRACKING_URI={uri}: no host in the URI; {_FIX}")
        try:
            with socket.create_connection((host, port), timeout=timeout):
                pass
        except OSError as exc:
            reason = exc.strerror or type(exc).__name__
            raise TrackingError(f"MLFLOW_TRACKING_URI={uri}: no tracking server answers at {host}:{port} "
                                f"({reason}); {_FIX}") from exc
    elif parsed.scheme in ("sqlite", "file", ""):
        raw = parsed.path if parsed.scheme else uri
        target = Path(raw)
        directory = target.parent if parsed.scheme == "sqlite" else target
        probe = directory
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        if not os.access(probe, os.W_OK):
            raise TrackingError(f"MLflow store {uri}: {probe} is not writable; {_FIX}")


@contextlib.contextmanager
def tracking_lock(results_dir: str | Path) -> Iterator[None]:
    """Exclusive access to the MLflow mirror of one results directory (see the module docstring)."""
    directory = Path(results_dir) / "tracking"
    directory.mkdir(parents=True, exist_ok=True)
    with open(directory / ".lock", "a+") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _flatten(prefix: str, value: Any, out: dict[str, str]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), v, out)
    else:
        out[prefix] = json.dumps(value) if isinstance(value, (list, tuple)) else str(value)


def _is_number(value: Any) -> bool:
    """Present and not NaN (NaN marks a value a row had no way to measure)."""
    return value is not None and not (isinstance(value, float) and math.isnan(value))


#: A metric as ``(key, value, step)``; :meth:`Tracker._log` makes MLflow's entities of them.
MetricPoint = tuple[str, float, int]


def _row_metrics(row: dict[str, Any]) -> list[MetricPoint]:
    """The run's summary metrics and moral-foundation scores, all at the run's last step."""
    step = int(row.get("total_steps") or 0)
    metrics = [(k, float(row[k]), step) for k in _METRICS if row.get(k) is not None]
    metrics += [(k, float(v), step) for k, v in row.items() if k.startswith(MF_PREFIX) and v is not None]
    return metrics


class Tracker:
    """Logs runs of one results directory to MLflow."""

    def __init__(self, results_dir: str | Path) -> None:
        # MLflow waits: importing runners.record.mlflow_mirror must not load it
        from mlflow.tracking import MlflowClient

        logging.getLogger("mlflow").setLevel(logging.WARNING)
        logging.getLogger("alembic").setLevel(logging.WARNING)
        for key, value in HTTP_DEFAULTS.items():
            os.environ.setdefault(key, value)
        self.results_dir = Path(results_dir).resolve()
        self.results_dir.mkdir(parents=True, exist_ok=True)
        uri = tracking_uri(self.results_dir)
        try:
            with tracking_lock(self.results_dir):
                self.client = MlflowClient(uri)
                exp = self.client.get_experiment_by_name(EXPERIMENT)
                if exp is None:
                    self.experiment_id = self.client.create_experiment(
                        EXPERIMENT, artifact_location=(self.results_dir / "mlartifacts").as_uri())
                else:
                    self.experiment_id = exp.experiment_id
        except Exception as exc:  # SQLAlchemy, HTTP and MLflow errors alike
            if is_disk_full(exc):  # SQLite: "database or disk is full"
                raise disk_full_error(self.results_dir / "mlflow.db", exc) from exc
            first = str(exc).strip().splitlines()[0][:300] if str(exc).strip() else ""
            raise TrackingError(f"cannot open the MLflow store {uri} ({type(exc).__name__}: {first}); {_FIX}") from exc

    def sync(self, run_id: str) -> str | None:
        """Mirror one finished run (no-op if already mirrored); returns the MLflow run id."""
        with tracking_lock(self.results_dir):
            return self._sync_locked(run_id)

    def _sync_locked(self, run_id: str) -> str | None:
        """Mirror ``run_id`` under the tracking lock, in the order that makes a crash harmless:
        the marker is written last, so a run without one is mirrored again from scratch (the
        half-mirrored MLflow run of an interrupted attempt is deleted first)."""
        marker = marker_path(self.results_dir, run_id)
        if marker.is_file():
            return json.loads(marker.read_text())["mlflow_run_id"]
        path = run_path(self.results_dir, run_id)
        table = read_table_or_quarantine(self.results_dir, path)
        if table is None:
            return None
        row = table.to_pylist()[0]
        for old in self.client.search_runs([self.experiment_id], filter_string=f"tags.run_id = '{run_id}'"):
            # an interrupted earlier mirror: ended as KILLED (else it stays RUNNING for good, and a
            # search of every run, deleted ones too, shows it as a run in progress), then set aside
            if old.info.status == "RUNNING":
                self.client.set_terminated(old.info.run_id, "KILLED")
            self.client.delete_run(old.info.run_id)
        mid = self._create_run(row)
        params: dict[str, str] = {}
        _flatten("", json.loads(row["config"]), params)
        metrics = _row_metrics(row) + self._learn_metrics(run_id) + self._update_metrics(run_id)
        self._log(mid, params, metrics, row)
        self._log_artifacts(mid, path, row)
        self.client.set_terminated(mid, "FINISHED" if row["status"] == "ok" else "FAILED")
        self._write_marker(marker, mid)
        return mid

    def _create_run(self, row: dict[str, Any]) -> str:
        """An MLflow run tagged with the run's identity; returns its MLflow id."""
        tags = {k: str(row[k]) for k in ("run_id", "env_id", "scenario", "variant", "chain", "algo", "learner", "protocol", "preset", "seed", "status")}
        if row.get("engine"):  # absent in rows written before the column existed
            tags["engine"] = str(row["engine"])
        run = self.client.create_run(self.experiment_id, tags=tags, run_name=f"{row['learner']} {row['env_id']} {row['chain']} s{row['seed']}")
        return run.info.run_id

    def _learn_metrics(self, run_id: str) -> list[MetricPoint]:
        """The learning curve, one ``learn/<key>`` metric per evaluation step."""
        learn = read_table_or_quarantine(self.results_dir, learn_path(self.results_dir, run_id))
        if learn is None:
            return []
        return [(f"learn/{key}", float(r[key]), int(r["step"]))
                for r in learn.to_pylist()
                for key in ("metric", "exact_metric", "mean_return", "mean_cost", "mean_length")
                if _is_number(r.get(key))]

    def _update_metrics(self, run_id: str) -> list[MetricPoint]:
        """Per-update diagnostics of PPO-Lag / CPO, over environment steps (``update/<key>``)."""
        updates = read_table_or_quarantine(self.results_dir, updates_path(self.results_dir, run_id))
        if updates is None:
            return []
        numeric = [c for c in UPDATE_COLUMNS if c not in ("schema_version", "run_id", "update", "timesteps")]
        return [(f"update/{key}", float(r[key]), int(r["timesteps"]))
                for r in updates.to_pylist()
                for key in numeric
                if _is_number(r.get(key))]

    def _log(self, mid: str, params: dict[str, str], points: list[MetricPoint], row: dict[str, Any]) -> None:
        """Params, metrics and the error in batches under MLflow's per-call limits."""
        from mlflow.entities import Metric, Param, RunTag  # MLflow waits: importing this module must not load it

        items = list(params.items())
        for i in range(0, max(1, len(items)), 100):
            self.client.log_batch(mid, params=[Param(k, v[:6000]) for k, v in items[i : i + 100]])
        metrics = [Metric(key, value, 0, step) for key, value, step in points]
        for i in range(0, len(metrics), 900):
            self.client.log_batch(mid, metrics=metrics[i : i + 900])
        if row.get("error"):
            self.client.log_batch(mid, tags=[RunTag("error", str(row["error"])[:5000])])

    def _log_artifacts(self, mid: str, path: Path, row: dict[str, Any]) -> None:
        """The run's Parquet row, its GIF and its model (with the model's JSON sidecar)."""
        self.client.log_artifact(mid, str(path))
        for key in ("gif_path", "model_path"):
            artifact = self.results_dir / row[key] if row.get(key) else None
            if artifact is None or not artifact.is_file():
                continue
            self.client.log_artifact(mid, str(artifact))
            sidecar = artifact.with_suffix(".json")
            if key == "model_path" and sidecar.is_file():
                self.client.log_artifact(mid, str(sidecar))

    def _write_marker(self, marker: Path, mid: str) -> None:
        """Atomically (write then rename): a marker is either whole or absent."""
        body = {"mlflow_run_id": mid, "experiment_id": self.experiment_id, "tracking_uri": tracking_uri(self.results_dir)}
        write_atomically(marker, lambda fh: fh.write(json.dumps(body).encode("utf-8")))
