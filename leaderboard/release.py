"""Results releases: a finished sweep frozen into a few checksummed files that live in the repository.

Why: the paper-budget Table 1 costs hours of CPU. A release lets every clone show it (``make
leaderboard`` with no runs of one's own) and lets a user put a new agent beside the baselines
without recomputing them: the leaderboard reads a release exactly as it reads a results directory
(:mod:`leaderboard.runs.sources`, through :mod:`leaderboard.runs.releases`), and a user's runs of the same protocol, preset and chain land in the
same cells, rankings and pages.

A release is ``releases/<name>/``::

    release.json      name, title, created, commit, machine, the sweeps (command, protocol, preset,
                      first start / last finish, wall span, compute per learner), config keys, the run
                      schema version, how updates were thinned, and {file: sha256, bytes} of every file
    runs.parquet      every run row, all columns of the run schema (model paths dropped: no models)
    learn.parquet     every learn-time evaluation row
    updates.parquet   the per-update diagnostics, every ``stride``-th update and each run's last
    manifests/*.json  the sweep manifests (planned runs: a missing run stays visible as missing)
    table1.{csv,md,tex}
    gifs/*.gif        one evaluation-episode GIF per (learner, scenario)
    logs/*.eval       the Inspect logs of language-model runs (their transcripts), where the runs'
                      provenance names a log file that exists; release.json counts those it lacks

Files are written into a temporary directory beside the target and renamed into place, so an
interrupted ``create`` leaves no half release. :func:`verify` recomputes every checksum: a damaged or
edited release is refused with one line naming the first file that fails.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from leaderboard.runs.aggregate import LLM_POLICY_KIND, safe_name
from leaderboard.runs.releases import (  # noqa: F401 - re-exported: the reading side, defined once there
    LEARN,
    MANIFEST,
    MIXED,
    RELEASE_FORMAT,
    RELEASES_DIR,
    RUNS,
    TABLES,
    UPDATES,
    Release,
    ReleaseError,
    find_releases,
    load,
    read_manifest,
    resolve,
    sha256,
    verify,
)
from leaderboard.web.leftovers import building_in
from morality_gym.clitools import OneLineParser, UserError, add_debug_flag, public_mode, run_cli, writing
from morality_gym.results.identity import config_key
from morality_gym.results.manifest import manifests_dir, read_manifests
from morality_gym.results.schema import SCHEMA_VERSION, compute_seconds, learn_path, read_runs, run_files, updates_path

#: Default thinning of the per-update diagnostics: every 8th update and each run's last keeps a
#: 1M-step PPO-Lag/CPO run's 488 updates as 62 rows (the curves' shape, a release under 25 MB).
DEFAULT_UPDATE_STRIDE = 8
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")


# ---------------------------------------------------------------------------------------- creating
def runs_commit(runs: pd.DataFrame) -> str:
    """The commit the runs were made at (their ``git_commit`` when all agree), else ``mixed:...``."""
    commits = sorted({str(c) for c in runs.get("git_commit", pd.Series(dtype=str)).dropna()})
    if len(commits) == 1:
        return commits[0]
    return MIXED + ",".join(c[:7] for c in commits) if commits else "unknown"


def machine() -> dict[str, Any]:
    """What the release was computed on: CPU model, cores, memory, OS, Python."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    memory = None
    try:
        memory = round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1)
    except (ValueError, OSError, AttributeError):
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "memory_gib": memory, "os": platform.platform(),
            "python": platform.python_version(), "hostnames": []}


def sweeps_summary(results: Path, runs: pd.DataFrame) -> list[dict[str, Any]]:
    """Per launched sweep manifest: its command, protocol, preset, planned runs, and of its runs with
    a result: first start, last finish, the wall span between them and compute per learner in
    core-seconds (:func:`morality_gym.results.schema.compute_seconds`: CPU time where the runs recorded
    it, else wall time), with how many runs recorded CPU time, and the CPU cost per run per 1M steps
    of each learner (:func:`cpu_rate_per_learner`)."""
    out = []
    for manifest in read_manifests(results):
        if manifest.get("dry_run"):
            continue
        ids = {r["run_id"] for r in manifest.get("runs", []) if isinstance(r, dict) and "run_id" in r}
        mine = runs.loc[runs["run_id"].isin(ids)]
        started = pd.to_datetime(mine["started_at"], errors="coerce", utc=True).dropna()
        finished = pd.to_datetime(mine["finished_at"], errors="coerce", utc=True).dropna()
        compute = {str(k): round(float(v), 1)
                   for k, v in compute_seconds(mine).groupby(mine["learner"]).sum().items()}
        cpu_known = int(mine["cpu_time_s"].notna().sum()) if "cpu_time_s" in mine else 0
        out.append({
            "manifest": manifest.get("_file") or manifest.get("name"), "command": manifest.get("command"),
            "protocol": manifest.get("protocol"), "preset": manifest.get("preset"), "planned": len(ids),
            "with_result": len(mine), "ok": int((mine["status"] == "ok").sum()),
            "first_start": started.min().isoformat() if len(started) else None,
            "last_finish": finished.max().isoformat() if len(finished) else None,
            "wall_span_s": round((finished.max() - started.min()).total_seconds(), 1) if len(started) and len(finished) else None,
            "compute_s_per_learner": compute,
            "runs_with_cpu_time": cpu_known,
            "cpu_s_per_run_per_1m_steps": cpu_rate_per_learner(mine),
        })
    return out


def cpu_rate_per_learner(runs: pd.DataFrame) -> dict[str, float]:
    """Core-seconds per run per million training steps, per learner, from the runs that recorded their
    CPU time: the cost figure that does not depend on what else shared the machine (a run's wall time
    does, and ``compute_s_per_learner`` falls back on it for runs made before CPU time was recorded).
    Learners that do not train (Random: no steps) are left out."""
    if "cpu_time_s" not in runs or "total_steps" not in runs:
        return {}
    timed = runs.loc[runs["cpu_time_s"].notna() & (runs["total_steps"].fillna(0) > 0)]
    by = timed.groupby("learner")
    return {str(k): round(float(v), 2) for k, v in (by["cpu_time_s"].sum() / by["total_steps"].sum() * 1e6).items()}


def _concat_side_files(paths: Sequence[Path]) -> pa.Table | None:
    tables = [pq.read_table(p) for p in paths if p.is_file()]
    if not tables:
        return None
    return pa.concat_tables(tables, promote_options="permissive")


def thin_updates(table: pa.Table | None, stride: int) -> pa.Table | None:
    """Every ``stride``-th update of each run (updates 1, 1 + stride, ...) and each run's last."""
    if table is None or stride <= 1:
        return table
    frame = table.to_pandas()
    last = frame.groupby("run_id")["update"].transform("max")
    keep = ((frame["update"] - 1) % stride == 0) | (frame["update"] == last)
    return pa.Table.from_pandas(frame.loc[keep].reset_index(drop=True), schema=table.schema, preserve_index=False)


def choose_gifs(runs: pd.DataFrame, results: Path) -> dict[str, str]:
    """run id -> release GIF name: per (protocol, preset, learner, scenario) the first run (chain,
    variant, seed order) whose GIF exists in the results directory."""
    chosen: dict[str, str] = {}
    taken: set[tuple[str, ...]] = set()
    candidates = runs.loc[(runs["status"] == "ok") & runs["gif_path"].notna()]
    for record in candidates.sort_values(["chain", "variant", "seed", "run_id"]).to_dict("records"):
        key = (str(record["protocol"]), str(record["preset"]), str(record["learner"]), str(record["scenario"]))
        if key in taken or not (results / str(record["gif_path"])).is_file():
            continue
        taken.add(key)
        chosen[str(record["run_id"])] = "gifs/" + safe_name("__".join(key)) + ".gif"
    return chosen


def llm_logs(runs: pd.DataFrame) -> dict[str, Path]:
    """Release name -> file of the Inspect logs that language-model runs name in their provenance.

    Why: a language-model run's row holds its metric and costs, but what the model read and answered
    is in the Inspect log (``config.provenance.log``), a path on the machine that ran it. A release
    carries those that exist, so a clone can open the transcripts (``inspect view``); logs are
    data, only ever read by Inspect when a user asks."""
    out: dict[str, Path] = {}
    taken: dict[str, Path] = {}
    for path in sorted(set(_llm_log_paths(runs))):
        if not path.is_file():
            continue
        name = f"logs/{safe_name(path.name)}"
        if name in taken and taken[name] != path:  # the same file name in two folders
            name = f"logs/{len(taken)}-{safe_name(path.name)}"
        taken[name] = path
        out[name] = path
    return out


def _llm_log_paths(runs: pd.DataFrame) -> list[Path]:
    """The log paths the provenance of language-model runs names (existing or not)."""
    paths = []
    for config in runs.get("config", pd.Series(dtype=object)).dropna():
        try:
            body = json.loads(config)
        except ValueError:
            continue
        policy, prov = body.get("policy") or {}, body.get("provenance") or {}
        if isinstance(policy, dict) and policy.get("kind") == LLM_POLICY_KIND and isinstance(prov, dict) and prov.get("log"):
            paths.append(Path(str(prov["log"])))
    return paths


def write_tables(results: Path, out: Path) -> None:
    """``table1.{csv,md,tex}`` of the results, as ``python -m leaderboard.build`` writes them.

    The build runs in a folder inside ``out`` (the release's own ``.<name>.create-*`` folder),
    not in ``/tmp``: a ``kill -9`` of ``release create`` left a ``/tmp/release-build-*`` of up to
    2 MB that nothing removed, while the release's folder is removed by the next ``create``."""
    with tempfile.TemporaryDirectory(prefix=".tables-", dir=out) as tmp:
        cmd = [sys.executable, "-m", "leaderboard.build", "--results", str(results), "--out", tmp,
               "--site", str(Path(tmp) / "site")]
        done = subprocess.run(cmd, check=False, capture_output=True, text=True)
        if done.returncode != 0:
            raise ReleaseError(f"building Table 1 of {results} failed: {(done.stderr or done.stdout).strip()[-300:]}")
        for name in TABLES:
            shutil.copy2(Path(tmp) / name, out / name)


def create(results: Path, name: str, root: Path = RELEASES_DIR, title: str = "", stride: int = DEFAULT_UPDATE_STRIDE,
           tables: bool = True) -> Path:
    """Freeze the runs of ``results`` into ``root/name``; returns the release directory.

    Refuses an existing release of that name (a release is immutable: publish a new name) and a
    results directory without runs. Failed runs are kept (they are part of what happened); the
    leaderboard reports them as it reports a results directory's.
    """
    if not _NAME.match(name):
        raise ReleaseError(f"release name {name!r}: use letters, digits, '.', '_' or '-' (at most 64), e.g. paper-table1-v1")
    target = root / name
    if target.exists():
        raise ReleaseError(f"{target} exists; a release is never rewritten: choose another name")
    if not run_files(results):
        raise ReleaseError(f"{results} holds no runs ({results / 'runs'}/*.parquet): nothing to release")
    runs = read_runs(results)
    with building_in(root, lambda entry: ".create-" in entry), writing(target):
        return _create(results, runs, name, root, title, stride, tables)


def publish(root: Path, name: str, manifest: str, fill: Callable[[Path], dict[str, Any]]) -> Path:
    """Make release ``root/name`` whole or not at all: ``fill`` writes the contents into a hidden
    ``.<name>.create-*`` folder and returns the manifest body, written last as ``manifest``; the
    folder gets the umask's mode and is renamed into place (a killed run's leftovers are removed by
    :mod:`leaderboard.web.leftovers`, which knows that prefix)."""
    target = root / name
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.create-", dir=root))
    try:
        body = fill(tmp)
        (tmp / manifest).write_text(json.dumps(body, indent=1, sort_keys=True) + "\n")
        tmp.chmod(public_mode(directory=True))  # mkdtemp's 0700 would make a committed release unreadable to others
        os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target


def _create(results: Path, runs: pd.DataFrame, name: str, root: Path, title: str, stride: int, tables: bool) -> Path:
    """:func:`create` once the release's root is held (a kill's leftovers removed: :mod:`leaderboard.web.leftovers`)."""

    def fill(tmp: Path) -> dict[str, Any]:
        _write_contents(tmp, results, runs, stride, tables)
        return _manifest(tmp, results, runs, name, title, stride)

    return publish(root, name, MANIFEST, fill)


def _write_contents(tmp: Path, results: Path, runs: pd.DataFrame, stride: int, tables: bool) -> None:
    """Everything but the manifest: chosen GIFs, runs (no model paths), side files, sweep manifests, tables."""
    gifs = choose_gifs(runs, results)
    (tmp / "gifs").mkdir()
    for run_id, rel in gifs.items():
        source = runs.loc[runs["run_id"] == run_id, "gif_path"].iloc[0]
        shutil.copy2(results / str(source), tmp / rel)
    released = runs.assign(model_path=None, gif_path=runs["run_id"].map(gifs))
    pq.write_table(pa.Table.from_pandas(released, preserve_index=False), tmp / RUNS, compression="zstd")
    ids = list(runs["run_id"])
    learn = _concat_side_files([learn_path(results, i) for i in ids])
    if learn is not None:
        pq.write_table(learn, tmp / LEARN, compression="zstd")
    updates = thin_updates(_concat_side_files([updates_path(results, i) for i in ids]), stride)
    if updates is not None:
        pq.write_table(updates, tmp / UPDATES, compression="zstd")
    logs = llm_logs(runs)
    if logs:
        (tmp / "logs").mkdir()
        for rel, source in logs.items():
            shutil.copy2(source, tmp / rel)
    (tmp / "manifests").mkdir()
    for manifest in sorted(manifests_dir(results).glob("*.json")):
        shutil.copy2(manifest, tmp / "manifests" / manifest.name)
    if tables:
        write_tables(results, tmp)


def _manifest(tmp: Path, results: Path, runs: pd.DataFrame, name: str, title: str, stride: int) -> dict[str, Any]:
    """The release manifest: provenance, counts, configurations and the hash of every file written."""
    configs = sorted({config_key(json.loads(c)) for c in runs["config"].dropna()})
    host = machine() | {"hostnames": sorted({str(h) for h in runs["hostname"].dropna()})}
    files = {str(p.relative_to(tmp)): {"sha256": sha256(p), "bytes": p.stat().st_size}
             for p in sorted(tmp.rglob("*")) if p.is_file()}
    return {
        "format": RELEASE_FORMAT, "name": name, "title": title or name,
        "created": datetime.now(UTC).isoformat(timespec="seconds"), "commit": runs_commit(runs),
        "schema_version": SCHEMA_VERSION, "machine": host, "runs": len(runs),
        "runs_ok": int((runs["status"] == "ok").sum()), "sweeps": sweeps_summary(results, runs),
        "config_keys": configs, "updates_stride": stride, "files": files,
        "llm_logs": _llm_log_counts(runs, files),
    }


def _llm_log_counts(runs: pd.DataFrame, files: dict[str, Any]) -> dict[str, int]:
    """How many Inspect logs the language-model runs name, and how many the release carries."""
    named = set(_llm_log_paths(runs))
    return {"named": len(named), "included": sum(1 for f in files if f.startswith("logs/"))}


# ---------------------------------------------------------------------------------------- command line
def build_parser() -> argparse.ArgumentParser:
    """The command's parser, apart from parsing: the docs' command-line reference is generated from it."""
    parser = OneLineParser(prog="python -m leaderboard.release", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    make = sub.add_parser("create", help="freeze a results directory into releases/<name>/")
    make.add_argument("--results", type=Path, required=True, help="the results directory of the sweep(s)")
    make.add_argument("--name", required=True, help="release name, e.g. paper-table1-v1")
    make.add_argument("--title", default="", help="one line shown on the leaderboard")
    make.add_argument("--root", type=Path, default=RELEASES_DIR, help=f"where releases live (default: {RELEASES_DIR})")
    make.add_argument("--update-stride", type=int, default=DEFAULT_UPDATE_STRIDE,
                      help=f"keep every Nth update's diagnostics and each run's last (default {DEFAULT_UPDATE_STRIDE})")
    check = sub.add_parser("verify", help="check every file of a release against its checksum")
    check.add_argument("release", type=Path)
    add_debug_flag(parser)
    return parser


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def run(args: argparse.Namespace) -> int:
    try:
        if args.command == "create":
            target = create(args.results, args.name, args.root, args.title, args.update_stride)
            body = verify(target)
            size = sum(e["bytes"] for e in body["files"].values())
            print(f"release {body['name']}: {body['runs']} runs ({body['runs_ok']} ok), {len(body['files'])} files, "
                  f"{size / 2**20:.1f} MiB in {target}")
        else:
            body = verify(args.release)
            print(f"release {body['name']}: {len(body['files'])} files, every checksum matches")
    except ReleaseError as exc:
        raise UserError(str(exc)) from exc
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    return run_cli(lambda: run(parse_args(argv)), (), argv)


if __name__ == "__main__":
    sys.exit(main())
