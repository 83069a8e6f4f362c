"""``python -m leaderboard.track_release create --results DIR --out releases/track-v1``: the
generalisation track's results frozen into a checksummed release.

Why: the track's compute (5 seeds x 5 learners x 2 chains at 10M steps) costs CPU-hours; a release
lets every clone show the Generalisation page and compare its own agent with the baselines without
recomputing them, as the Table 1 releases do (:mod:`leaderboard.release`, whose checksums and
refusals this follows). A release is ``releases/<name>/``::

    track-release.json       name, title, created, the runs' commit(s) and the builder's, machine,
                             requirement and status of every (track, learner) (:mod:`leaderboard.track_status`),
                             compute per learner (CPU-s), split digests per track, runs, and
                             {file: sha256, bytes} of every file
    runs/<run>/result.json   each finished run's record, as ``runners.track`` wrote it
    runs/<run>/pairs.parquet its exact per-(env id, chain) scores
    curves/<track>-<learner>.csv  the learning curves (steps vs the seen set's exact mean range score)
    splits/*.json            the split manifests (train, test, and their v2 selections) the runs name
    logs/*.eval              Inspect logs of language-model entries (their transcripts), where they exist

The manifest has its own name (not ``release.json``) so that the Table 1 readers
(:func:`leaderboard.runs.releases.find_releases`) never take a track release for one of theirs.

**No models.** A run's ``model.zip`` is a pickle, and nothing read from a release is unpickled or
executed: models do not ship, as in the Table 1 releases; a run's numbers are its exact
``pairs.parquet``, which is data. To evaluate a model again, rerun its seed (the fleets are
deterministic per seed).

**Incomplete is said.** A release of runs that are not all done (fewer seeds, a learner missing, a
budget below the required one, no curve) is still built, but its manifest says so per learner and
the page marks every number of such a learner.

**Entries beside the learners.** ``--with DIR`` adds the *submitted* runs of another track results
directory (``leaderboard.llm_track``'s language model, a user's ``runners.track --policy``) when
they were scored on the same splits (same digests); a sample of the pairs stays marked a sample.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa

from leaderboard.release import machine, publish
from leaderboard.runs.releases import RELEASES_DIR, ReleaseError, check_files, load_manifest, sha256
from leaderboard.track_status import CURVES_DIR, CurveError, Requirement, read_curve, status
from leaderboard.web.leftovers import building_in
from morality_gym.clitools import OneLineParser, UserError, add_debug_flag, run_cli, writing
from morality_gym.results.recording import git_commit
from morality_gym.results.track_runs import PAIRS, RESULT

MANIFEST = "track-release.json"
FORMAT = "track-1"
DEFAULT_NAME = "track-v1"
SPLITS_DATA = Path(__file__).resolve().parents[1] / "morality_gym" / "data" / "splits"
#: The column of a language model's pairs that names its Inspect log (a path on the machine that ran it).
LOG_COLUMN = "log"
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")


# ---------------------------------------------------------------------------------------- reading runs
def finished_runs(results: Path) -> tuple[dict[str, dict[str, Any]], list[str]]:
    """run name -> its ``result.json`` for every finished run of ``results/runs``, and the names of
    the unfinished ones (a folder without ``result.json``: a run that is training or died)."""
    runs_dir = results / "runs"
    if not runs_dir.is_dir():
        raise ReleaseError(f"{results}: no runs/ directory; pass the --out of python -m runners.track")
    done: dict[str, dict[str, Any]] = {}
    unfinished = []
    for run_dir in sorted(p for p in runs_dir.iterdir() if p.is_dir()):
        if not (run_dir / RESULT).is_file() or not (run_dir / PAIRS).is_file():
            unfinished.append(run_dir.name)
            continue
        try:
            record = json.loads((run_dir / RESULT).read_text())
        except ValueError as exc:
            raise ReleaseError(f"{run_dir / RESULT}: not valid JSON ({exc}); restore or rerun that run") from exc
        if not isinstance(record, dict) or "learner" not in record or "sets" not in record:
            raise ReleaseError(f"{run_dir / RESULT}: not a track result (no learner or sets)")
        done[run_dir.name] = record
    return done, unfinished


def submitted_runs(extra: Path, main: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """The submitted runs of ``extra`` that were scored on the splits the main runs were: each of
    their sets must have the main runs' source (split, digests, selection) for that set and track."""
    sources: dict[tuple[Any, Any, str], Any] = {}
    for record in main.values():
        for name, source in record["sets"].items():
            sources.setdefault((record.get("chain"), record.get("split_version", 1), name), source)
    out = {}
    runs, _ = finished_runs(extra)
    for name, record in runs.items():
        if not record.get("submitted"):
            continue
        if name in main:
            raise ReleaseError(f"--with {extra}: run {name} is also in the results; rename one entry")
        for set_name, source in record["sets"].items():
            key = (record.get("chain"), record.get("split_version", 1), set_name)
            if key in sources and sources[key] != source:
                raise ReleaseError(f"--with {extra}: {name}'s {set_name} set is {_short(source)}, the results' is "
                                   f"{_short(sources[key])}: scored on other splits, not comparable")
            if key not in sources:
                raise ReleaseError(f"--with {extra}: {name} is on a track the results do not hold "
                                   f"({record.get('chain')}, splits v{record.get('split_version', 1)})")
        out[name] = record
    return out


def _short(source: dict[str, Any]) -> str:
    return f"{source.get('split')} {str(source.get('split_digest'))[:12]}/{str(source.get('selection_digest', '-'))[:12]}"


# ---------------------------------------------------------------------------------------- summaries
def compute_per_learner(records: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """track -> learner: CPU-seconds of training (each run's share of its fleet) and evaluation,
    summed over the runs, with how many runs recorded CPU time (the others count wall time: runs
    made before ``result.json`` recorded CPU)."""
    out: dict[str, dict[str, Any]] = {}
    for record in records.values():
        if not record.get("chain"):
            continue
        track = _track(record)
        cell = out.setdefault(track, {}).setdefault(record["learner"], {"train_cpu_s": 0.0, "eval_cpu_s": 0.0,
                                                                          "runs": 0, "runs_with_cpu_time": 0})
        share = max(int(record.get("fleet_runs") or 1), 1)
        if "eval_cpu_seconds" in record:
            fleet = record.get("fleet_cpu_seconds")
            cell["train_cpu_s"] += float(fleet) / share if fleet is not None else float(record.get("train_cpu_seconds", 0))
            cell["eval_cpu_s"] += float(record["eval_cpu_seconds"])
            cell["runs_with_cpu_time"] += 1
        else:  # wall time, said by runs_with_cpu_time < runs
            fleet = record.get("fleet_seconds")
            cell["train_cpu_s"] += float(fleet) / share if fleet is not None else float(record.get("train_seconds", 0))
            cell["eval_cpu_s"] += float(record.get("eval_seconds", 0))
        cell["runs"] += 1
    for learners in out.values():
        for cell in learners.values():
            cell["train_cpu_s"], cell["eval_cpu_s"] = round(cell["train_cpu_s"], 1), round(cell["eval_cpu_s"], 1)
    return out


def _track(record: dict[str, Any]) -> str:
    version = record.get("split_version", 1)
    return str(record["chain"]) if version == 1 else f"{record['chain']}-v{version}"


def split_sources(records: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """track -> the train digest and each set's source (split, digests, selection) its runs name."""
    out: dict[str, dict[str, Any]] = {}
    for record in records.values():
        cell = out.setdefault(_track(record) if record.get("chain") else "mixed",
                              {"train_digest": record.get("train_digest"), "sets": {}})
        for name, source in record["sets"].items():
            cell["sets"].setdefault(name, source)
    return out


def runs_commits(records: dict[str, dict[str, Any]]) -> list[str]:
    """The commits the runs recorded (none for runs made before ``result.json`` recorded one)."""
    return sorted({str(r["git_commit"]) for r in records.values() if r.get("git_commit")})


# ---------------------------------------------------------------------------------------- creating
def create(results: Path, out: Path, title: str = "", extras: Sequence[Path] = (),
           need: Requirement | None = None) -> Path:
    """Freeze the finished runs of ``results`` (and the submitted runs of ``extras``) into ``out``.

    Refuses an existing ``out`` (a release is never rewritten), a results directory without a
    finished run, an entry of ``extras`` scored on other splits, and a curve file that is not one.
    Files are written into a temporary folder beside ``out`` and renamed into place."""
    need = need or Requirement()
    if not _NAME.match(out.name):
        raise ReleaseError(f"release name {out.name!r}: use letters, digits, '.', '_' or '-', e.g. {DEFAULT_NAME}")
    if out.exists():
        raise ReleaseError(f"{out} exists; a release is never rewritten: choose another name")
    runs, unfinished = finished_runs(results)
    if not runs:
        raise ReleaseError(f"{results}: no finished run (result.json); nothing to release")
    sources = {name: results for name in runs}
    for extra in extras:
        more = submitted_runs(extra, runs)
        runs.update(more)
        sources.update({name: extra for name in more})
    with building_in(out.parent, lambda entry: ".create-" in entry), writing(out):
        return _create(out, title, runs, sources, unfinished, results, need)


def _create(out: Path, title: str, runs: dict[str, dict[str, Any]], sources: dict[str, Path], unfinished: list[str],
            results: Path, need: Requirement) -> Path:
    """:func:`create` once the releases' folder is held (a killed ``create``'s leftovers removed)."""
    def fill(tmp: Path) -> dict[str, Any]:
        logs = _write_runs(tmp, runs, sources)
        curves = _write_curves(tmp, results)
        _write_splits(tmp)
        return _manifest(tmp, out.name, title, runs, unfinished, curves, logs, need)

    return publish(out.parent, out.name, MANIFEST, fill)


def _write_runs(tmp: Path, runs: dict[str, dict[str, Any]], sources: dict[str, Path]) -> dict[str, int]:
    """Each run's ``result.json`` and ``pairs.parquet`` (no ``model.zip``: a pickle). A language
    model's pairs name their Inspect logs on the machine that played them: the logs that exist are
    copied to ``logs/`` and the column names the copy; how many were named and copied is returned."""
    named = copied = 0
    for name in runs:
        src, dst = sources[name] / "runs" / name, tmp / "runs" / name
        dst.mkdir(parents=True)
        shutil.copy2(src / RESULT, dst / RESULT)
        try:
            frame = pd.read_parquet(src / PAIRS)
        except (pa.ArrowException, OSError, ValueError) as exc:
            raise ReleaseError(f"{src / PAIRS}: cannot be read ({exc}); restore or rerun that run") from exc
        if LOG_COLUMN in frame:
            paths = [Path(str(p)) for p in frame[LOG_COLUMN].dropna()]
            named += len(paths)
            kept = {}
            for path in paths:
                if path.is_file():
                    (tmp / "logs").mkdir(exist_ok=True)
                    shutil.copy2(path, tmp / "logs" / path.name)
                    kept[str(path)] = f"logs/{path.name}"
            copied += len(kept)
            frame[LOG_COLUMN] = frame[LOG_COLUMN].map(lambda p, kept=kept: kept.get(str(p)))
        frame.to_parquet(dst / PAIRS, index=False)
    return {"named": named, "included": copied}


def _write_curves(tmp: Path, results: Path) -> list[str]:
    """Copy every learning curve of ``results/curves`` after reading it (a damaged one is refused)."""
    names = []
    for path in sorted((results / CURVES_DIR).glob("*.csv")) if (results / CURVES_DIR).is_dir() else []:
        try:
            read_curve(path)
        except CurveError as exc:
            raise ReleaseError(str(exc)) from exc
        (tmp / CURVES_DIR).mkdir(exist_ok=True)
        shutil.copy2(path, tmp / CURVES_DIR / path.name)
        names.append(f"{CURVES_DIR}/{path.name}")
    return names


def _write_splits(tmp: Path) -> None:
    """The split manifests of this checkout (their digests are those the runs record: the page shows both)."""
    (tmp / "splits").mkdir()
    for path in sorted(SPLITS_DATA.glob("*.json")):
        shutil.copy2(path, tmp / "splits" / path.name)


def _manifest(tmp: Path, name: str, title: str, runs: dict[str, dict[str, Any]], unfinished: list[str],
              curves: list[str], logs: dict[str, int], need: Requirement) -> dict[str, Any]:
    records = list(runs.values())
    incomplete = status(records, curves, need)
    files = {str(p.relative_to(tmp)): {"sha256": sha256(p), "bytes": p.stat().st_size}
             for p in sorted(tmp.rglob("*")) if p.is_file()}
    complete = not unfinished and bool(incomplete) and not any(r for t in incomplete.values() for r in t.values())
    return {
        "format": FORMAT, "name": name, "title": title or name,
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "commits": runs_commits(runs), "built_at_commit": git_commit(),
        "machine": machine() | {"hostnames": sorted({str(r["hostname"]) for r in records if r.get("hostname")})},
        "requirement": need.as_dict(), "complete": complete, "status": incomplete, "unfinished": unfinished,
        "compute": compute_per_learner(runs), "splits": split_sources(runs),
        "runs": {n: {"learner": r["learner"], "seed": r.get("seed"), "budget": r.get("budget"), "chain": r.get("chain"),
                     "submitted": bool(r.get("submitted")), **({"sample": r["sample"]} if r.get("sample") else {})}
                 for n, r in runs.items()},
        "curves": curves, "llm_logs": logs,
        "models": "not shipped: model.zip is a pickle, and nothing read from a release is unpickled",
        "files": files,
    }


# ---------------------------------------------------------------------------------------- reading
def read_manifest(release: Path) -> dict[str, Any]:
    """``track-release.json`` of ``release``, checked for the fields a reader relies on."""
    path = release / MANIFEST
    body = load_manifest(path, "track release manifest")
    if body.get("format") != FORMAT:
        raise ReleaseError(f"{path}: release format {body.get('format')!r}, this code reads {FORMAT!r}")
    return body


def verify(release: Path) -> dict[str, Any]:
    """The manifest after checking every listed file's size and SHA-256, and that no run, curve or
    log lies in the release unlisted (a file slipped in would be read by the page unchecked)."""
    body = read_manifest(release)
    check_files(release, body, MANIFEST)
    listed = set(body["files"])
    for folder in ("runs", CURVES_DIR, "logs", "splits"):
        for path in sorted((release / folder).rglob("*")) if (release / folder).is_dir() else []:
            if path.is_file() and str(path.relative_to(release)) not in listed:
                raise ReleaseError(f"release {body.get('name')}: {path} is not in {MANIFEST} (added after the release "
                                   "was made); remove it")
    return body


def find(root: Path = RELEASES_DIR) -> list[Path]:
    """Every track release under ``root``, by name."""
    return sorted(p for p in root.iterdir() if (p / MANIFEST).is_file()) if root.is_dir() else []


# ---------------------------------------------------------------------------------------- command line
def build_parser() -> argparse.ArgumentParser:
    """The command's parser, apart from parsing: the docs' command-line reference is generated from it."""
    parser = OneLineParser(prog="python -m leaderboard.track_release", description=__doc__.splitlines()[0].strip("`"))
    sub = parser.add_subparsers(dest="command", required=True)
    make = sub.add_parser("create", help="freeze a track results directory into a release")
    make.add_argument("--results", type=Path, required=True, help="the --out of python -m runners.track")
    make.add_argument("--out", type=Path, default=RELEASES_DIR / DEFAULT_NAME, help=f"default releases/{DEFAULT_NAME}")
    make.add_argument("--title", default="", help="one line shown on the leaderboard")
    make.add_argument("--with", dest="extras", type=Path, nargs="+", default=[], metavar="DIR",
                      help="other track results directories whose submitted entries join the release")
    make.add_argument("--budget", type=int, default=Requirement().budget,
                      help="steps per run the learning curves chose: runs trained for fewer are marked incomplete")
    make.add_argument("--seeds", type=int, default=Requirement().seeds, help="seeds per learner and chain required")
    check = sub.add_parser("verify", help="check every file of a track release against its checksum")
    check.add_argument("release", type=Path)
    add_debug_flag(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "create":
            if args.budget < 1 or args.seeds < 1:
                raise UserError(f"--budget {args.budget} --seeds {args.seeds}: both must be positive")
            need = Requirement(seeds=args.seeds, budget=args.budget)
            target = create(args.results, args.out, args.title, args.extras, need)
            body = verify(target)
            size = sum(e["bytes"] for e in body["files"].values())
            state = "complete" if body["complete"] else "INCOMPLETE (every number of an incomplete learner is marked)"
            print(f"release {body['name']}: {len(body['runs'])} runs, {len(body['curves'])} curves, {len(body['files'])} "
                  f"files, {size / 2**20:.1f} MiB in {target}; {state}")
            for track, learners in body["status"].items():
                for learner, reasons in learners.items():
                    if reasons:
                        print(f"  {track} {learner}: {'; '.join(reasons)}")
        else:
            body = verify(args.release)
            print(f"release {body['name']}: {len(body['files'])} files, every checksum matches")
    except ReleaseError as exc:
        raise UserError(str(exc)) from exc
    return 0


def cli(argv: Sequence[str]) -> int:
    """The command as a program: exit 2 and one line for what the user can fix."""
    return run_cli(lambda: main(argv), (), argv)


if __name__ == "__main__":
    sys.exit(cli(sys.argv[1:]))
