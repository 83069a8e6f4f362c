"""Sweep manifests: the runs a sweep planned, so readers can tell missing runs from absent ones.

``<results_dir>/manifests/<sweep>-<plan hash>.json``::

    {"name": ..., "created_at": ISO-8601 (latest launch), "first_created_at": ISO-8601,
     "dry_run": false, "command": "...", "preset": ..., "protocol": ..., "preset_seeds": [41, ...],
     "runs": [{"run_id", "env_id", "scenario", "variant", "chain", "algo", "learner",
               "protocol", "preset", "seed", "config_key", "chain_key"}, ...]}

The file name ends with a hash of the planned run ids (:func:`plan_hash`), so each distinct
selection keeps its own manifest: a second sweep into the same directory (other scenarios,
variants or seeds) adds a manifest instead of overwriting the first one's plan, and the runs the
first one planned stay reported as missing until they exist. Relaunching the same selection
rewrites its own manifest with the same plan (``created_at`` becomes the latest launch, which is
how readers tell which configuration is meant now). ``config_key`` identifies the run's
configuration apart from env and seed (:func:`morality_gym.results.identity.config_key`), ``chain_key`` what its
chain is (:attr:`morality_gym.norms.chain.MoralityChain.fingerprint`).

A dry run (``dry_run=true``) writes its manifest marked ``"dry_run": true``; readers ignore such
plans (nothing was launched, so nothing is missing), and a dry run never replaces the manifest of
a real launch of the same selection. The aggregator reads every other manifest and reports planned
runs without a result (missing) and runs whose status is "failed".
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from morality_gym.clitools import write_atomically

MANIFEST_KEYS = ("run_id", "env_id", "scenario", "variant", "chain", "algo", "learner", "protocol", "preset", "seed")
#: Written by current sweeps; manifests of earlier versions lack them.
OPTIONAL_KEYS = ("config_key", "chain_key")


def manifests_dir(results_dir: str | Path) -> Path:
    return Path(results_dir) / "manifests"


def plan_hash(run_ids: Iterable[str]) -> str:
    """10 hex digits of SHA-256 over the sorted planned run ids: the selection's identity."""
    return hashlib.sha256("\n".join(sorted(set(run_ids))).encode()).hexdigest()[:10]


def manifest_name(sweep_name: str, run_ids: Iterable[str]) -> str:
    """``<sweep name>-<plan hash>``: readable, and distinct for every distinct selection."""
    return f"{sweep_name}-{plan_hash(run_ids)}"


def _read(path: Path) -> dict[str, Any] | None:
    try:
        body = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return body if isinstance(body, dict) else None


def manifest_body(name: str, runs: Sequence[Mapping[str, Any]], existing: Mapping[str, Any] | None = None,
                  **meta: Any) -> dict[str, Any]:
    """A manifest's content (``existing``: the file it replaces, whose first creation time it keeps)."""
    now = datetime.now(UTC).isoformat(timespec="seconds")
    dry_run = bool(meta.pop("dry_run", False))
    return {
        "name": name,
        "created_at": now,
        "first_created_at": (existing or {}).get("first_created_at") or (existing or {}).get("created_at") or now,
        "dry_run": dry_run,
        **meta,
        "runs": [{k: r[k] for k in MANIFEST_KEYS} | {k: r[k] for k in OPTIONAL_KEYS if k in r} for r in runs],
    }


def write_manifest(results_dir: str | Path, name: str, runs: Sequence[Mapping[str, Any]], **meta: Any) -> Path:
    """Write the manifest atomically (temporary file + rename); see the module docstring.

    ``dry_run=True`` in ``meta`` marks a plan that was only listed; it never replaces the manifest
    of a real launch of the same name.
    """
    directory = manifests_dir(results_dir)
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{name}.json"
    dry_run = bool(meta.get("dry_run", False))
    existing = _read(path) if path.is_file() else None
    if dry_run and existing is not None and not existing.get("dry_run", False):
        return path  # the same selection was launched for real: keep that record
    body = manifest_body(name, runs, existing, **meta)
    text = json.dumps(body, indent=1)
    return write_atomically(path, lambda fh: fh.write(text.encode()))  # a kill or a full disk leaves no half manifest


def read_manifests(results_dir: str | Path, skipped: list[dict[str, str]] | None = None) -> list[dict[str, Any]]:
    """Every readable manifest under ``results_dir`` (sorted by file name).

    An unreadable one raises, unless ``skipped`` is given: then it is reported there.
    """
    out = []
    for path in sorted(manifests_dir(results_dir).glob("*.json")):
        body = _read(path)
        if body is None or not isinstance(body.get("runs"), list):
            if skipped is None:
                raise ValueError(f"{path}: not a readable sweep manifest")
            skipped.append({"file": str(path), "reason": "not a readable sweep manifest (JSON with a 'runs' list)"})
            continue
        out.append(body | {"_file": path.stem})
    return out


def planned_runs(results_dir: str | Path, include_dry_runs: bool = False,
                 skipped: list[dict[str, str]] | None = None) -> dict[str, dict[str, Any]]:
    """All runs planned by the (launched) manifests, by run id.

    Each entry also carries ``manifest`` (its name), ``planned_at`` (the manifest's latest launch)
    and ``preset_seeds`` (the preset's seeds, when the manifest records them); a run planned by
    several manifests keeps the most recent one.
    """
    out: dict[str, dict[str, Any]] = {}
    manifests = read_manifests(results_dir, skipped)
    manifests.sort(key=lambda m: (str(m.get("created_at", "")), str(m.get("_file", ""))))
    for manifest in manifests:
        if manifest.get("dry_run", False) and not include_dry_runs:
            continue
        extra = {"manifest": manifest.get("_file") or manifest.get("name"), "planned_at": str(manifest.get("created_at", "")),
                 "preset_seeds": manifest.get("preset_seeds")}
        for run in manifest["runs"]:
            if isinstance(run, dict) and "run_id" in run:
                out[run["run_id"]] = dict(run) | extra
    return out
