"""Sweep manifests: the runs a sweep planned, so readers can tell missing runs from absent ones.

``<results_dir>/manifests/<name>.json``::

    {"name": ..., "created_at": ISO-8601, "command": "...", "preset": ..., "protocol": ...,
     "runs": [{"run_id", "env_id", "scenario", "variant", "chain", "algo", "learner",
               "protocol", "preset", "seed"}, ...]}

A sweep writes (or rewrites) its manifest before dispatching anything. The aggregator reads every
manifest and reports planned runs without a result (missing) and runs whose status is "failed".
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

MANIFEST_KEYS = ("run_id", "env_id", "scenario", "variant", "chain", "algo", "learner", "protocol", "preset", "seed")


def manifests_dir(results_dir: str | Path) -> Path:
    return Path(results_dir) / "manifests"


def write_manifest(results_dir: str | Path, name: str, runs: Sequence[Mapping[str, Any]], **meta: Any) -> Path:
    """Write the manifest atomically (temporary file + rename)."""
    directory = manifests_dir(results_dir)
    directory.mkdir(parents=True, exist_ok=True)
    body = {
        "name": name,
        "created_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        **meta,
        "runs": [{k: r[k] for k in MANIFEST_KEYS} for r in runs],
    }
    path = directory / f"{name}.json"
    fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=directory)
    with os.fdopen(fd, "w") as fh:
        json.dump(body, fh, indent=1)
    os.replace(tmp, path)
    return path


def read_manifests(results_dir: str | Path) -> list[dict[str, Any]]:
    """Every manifest under ``results_dir`` (sorted by file name)."""
    return [json.loads(p.read_text()) for p in sorted(manifests_dir(results_dir).glob("*.json"))]


def planned_runs(results_dir: str | Path) -> dict[str, dict[str, Any]]:
    """All planned runs of all manifests, by run id."""
    out: dict[str, dict[str, Any]] = {}
    for manifest in read_manifests(results_dir):
        for run in manifest["runs"]:
            out[run["run_id"]] = run
    return out
