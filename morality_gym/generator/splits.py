"""Fixed splits of generated dilemmas: ``train`` and a held-out ``test``, named by seed ranges.

A split is the dilemmas the generator keeps from a fixed range of seeds (:data:`SPLIT_SEEDS`). Its
scenario files are not shipped (they regenerate from the seeds); what is shipped is its manifest,
``morality_gym/data/splits/<name>.json``: the seed range, the grammar version, the size cap, the
rejected seeds by reason, the SHA-256 of every kept file and their digest
(:func:`~morality_gym.generator.pipeline.files_digest`). A result names its split by name and
digest, and anyone can regenerate the files and check them against the manifest
(``python -m morality_gym generate --split test --out DIR``).

:func:`load_split` generates a split once into a cache directory, checks it against the manifest,
registers its env ids with Gymnasium (as :func:`~morality_gym.add_scenario_dir` does for any
user's directory) and returns them: with ``obs_type="grid"`` they all share one observation shape.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, TextIO

from morality_gym.envs.registration import add_scenario_dir
from morality_gym.generator.grammar import GRAMMAR_VERSION, NAME_PREFIX
from morality_gym.generator.pipeline import Progress, RunReport, files_digest, generate, sha256_bytes
from morality_gym.world.bounds_cache import CACHE_FOLDER

SPLITS_DIR: Final[Path] = Path(__file__).resolve().parent.parent / "data" / "splits"
#: The published splits: first and last seed, both included. The test seeds are far from the
#: train seeds so that no range of a later, larger train split reaches them.
SPLIT_SEEDS: Final[dict[str, tuple[int, int]]] = {"train": (0, 999), "test": (1_000_000, 1_000_199)}
#: Where :func:`load_split` keeps generated splits (default ``~/.cache/morality-gym``).
CACHE_ENV: Final[str] = "MORALITY_GYM_CACHE"


class SplitError(ValueError):
    """An unknown split, or generated files that do not match a split's manifest."""


@dataclass(frozen=True)
class SplitManifest:
    """A split's published record (module docstring)."""

    name: str
    seeds: tuple[int, int]
    grammar_version: int
    max_states: int
    digest: str
    files: dict[str, str]
    rejected: dict[str, list[int]]
    source: str

    @property
    def seed_range(self) -> range:
        return range(self.seeds[0], self.seeds[1] + 1)

    @property
    def count(self) -> int:
        return len(self.files)


def split_names() -> list[str]:
    return list(SPLIT_SEEDS)


def manifest_record(name: str, index: dict[str, Any]) -> dict[str, Any]:
    """The manifest of split ``name`` from the ``index.json`` of generating its seeds."""
    return {"split": name, **{k: v for k, v in index.items() if k not in ("tried",)}}


def manifest_text(record: dict[str, Any]) -> str:
    """A manifest as committed: one file a line, each reason's rejected seeds on one line."""
    lines = ["{"]
    for key, value in record.items():
        if key == "files":
            body = ",\n".join(f"  {json.dumps(name)}: {json.dumps(digest)}" for name, digest in value.items())
            lines.append(f' "files": {{\n{body}\n }},')
        elif key == "rejected":
            body = ",\n".join(f"  {json.dumps(reason)}: {json.dumps(seeds)}" for reason, seeds in value.items())
            lines.append(f' "rejected": {{\n{body}\n }},')
        else:
            lines.append(f" {json.dumps(key)}: {json.dumps(value)},")
    lines[-1] = lines[-1].removesuffix(",")
    return "\n".join(lines) + "\n}\n"


def publish_split(name: str, directory: Path = SPLITS_DIR, workers: int = 1) -> Path:
    """Generate split ``name``'s seeds and write its manifest (after a change of the grammar, which
    makes every split a new one: bump ``GRAMMAR_VERSION`` first). Takes minutes for ``train``."""
    first, last = SPLIT_SEEDS[name]
    with tempfile.TemporaryDirectory(prefix=f"morality-gym-split-{name}-") as tmp:
        report = generate(range(first, last + 1), tmp, pictures=False, with_values=False, workers=workers,
                          progress=ProgressLine(f"publishing split {name}"))
    path = directory / f"{name}.json"
    path.write_text(manifest_text(manifest_record(name, report.index)))
    return path


def _read_manifest(path: Path) -> SplitManifest:
    try:
        raw = json.loads(path.read_text())
        return SplitManifest(raw["split"], tuple(raw["seeds"]), raw["grammar_version"], raw["max_states"],
                             raw["digest"], dict(raw["files"]), {k: list(v) for k, v in raw["rejected"].items()},
                             str(path))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SplitError(f"{path}: not a split manifest ({exc}). Fix: regenerate it with "
                         "python -m morality_gym generate --split NAME") from exc


def split_manifest(split: str | Path) -> SplitManifest:
    """The manifest of a published split (``"train"``, ``"test"``) or of a manifest file's path."""
    if str(split).endswith(".json"):
        return _read_manifest(Path(split))
    if split not in SPLIT_SEEDS:
        raise SplitError(f"unknown split {split!r}. Fix: use one of {', '.join(SPLIT_SEEDS)}, or a manifest's path")
    return _read_manifest(SPLITS_DIR / f"{split}.json")


def directory_hashes(directory: Path) -> dict[str, str]:
    """The SHA-256 of every generated scenario file in ``directory``, by file name."""
    return {path.name: sha256_bytes(path.read_bytes()) for path in sorted(directory.glob(f"{NAME_PREFIX}*.yaml"))}


def check_directory(directory: Path, manifest: SplitManifest) -> None:
    """Raise :class:`SplitError` naming the first file of ``directory`` that the manifest disagrees with."""
    hashes = directory_hashes(directory)
    for name in sorted(set(hashes) | set(manifest.files)):
        if hashes.get(name) != manifest.files.get(name):
            what = "is missing" if name not in hashes else "is not in the split" if name not in manifest.files \
                else "differs from the published file"
            raise SplitError(
                f"{directory / name}: {what} (split {manifest.name}, {manifest.source}); the directory's digest is "
                f"{files_digest(hashes)}, the split's {manifest.digest}. Fix: regenerate with grammar version "
                f"{manifest.grammar_version} (this code has version {GRAMMAR_VERSION})"
            )


def write_split(split: str | Path, out: str | Path, *, pictures: bool = False, with_values: bool = False,
                workers: int = 1, progress: Progress | None = None, bounds_cache: bool = False) -> RunReport:
    """Generate every seed of a split into ``out`` (over ``workers`` processes) and check the files
    against its manifest."""
    manifest = split_manifest(split)
    report = generate(manifest.seed_range, out, pictures=pictures, with_values=with_values,
                      max_states=manifest.max_states, workers=workers, progress=progress, bounds_cache=bounds_cache)
    check_directory(Path(out), manifest)
    return report


def default_workers() -> int:
    """The CPUs this process may run on (a split's first generation uses them all)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


class ProgressLine:
    """A generation's progress as a line on stderr every ``every`` seconds (and at the end): seeds
    done, dilemmas kept, time per seed and what is left. Minutes of work must not look like a hang."""

    def __init__(self, label: str, every: float = 10.0, stream: TextIO | None = None) -> None:
        self.label, self.every, self.stream = label, every, stream
        self._last = -every

    def __call__(self, done: int, total: int | None, kept: int, seconds: float) -> None:
        if seconds - self._last < self.every and done != total:
            return
        self._last = seconds
        line = f"{self.label}: {done}/{total if total is not None else '?'} seeds, {kept} kept, {seconds:.0f} s"
        if total and done:
            line += f", about {seconds / done * (total - done):.0f} s left"
        print(line, file=self.stream or sys.stderr, flush=True)


#: The folder under ``~/.cache`` (a plain name, not the package's: it is a directory).
_CACHE_FOLDER = "morality-gym"


def cache_root() -> Path:
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / _CACHE_FOLDER)


def _seed_of(env_id: str) -> int:
    return int(env_id.split("-", 1)[0].removeprefix(NAME_PREFIX))


def load_split(split: str | Path, cache_dir: str | Path | None = None, *, workers: int | None = None,
               progress: Progress | None = None) -> list[str]:
    """Register the env ids of a split (``"train"``, ``"test"`` or a manifest's path); returns them,
    in seed order.

    The first call generates the split into ``cache_dir`` (default ``$MORALITY_GYM_CACHE`` or
    ``~/.cache/morality-gym``, under ``splits/<name>-<digest>``) over ``workers`` processes
    (default: every CPU this process may use), with a progress line on stderr (``progress``
    replaces it): minutes. Later calls check the cached files against the manifest and load them:
    each file's bounds are checked against the spans measured when it was generated, kept in the
    directory's bounds cache by the file's SHA-256 (:mod:`~morality_gym.world.bounds_cache`), so
    seconds. Files that do not match the manifest raise :class:`SplitError`: a result on them would
    not be a result on the split.
    """
    manifest = split_manifest(split)
    root = Path(cache_dir) if cache_dir is not None else cache_root()
    directory = root / "splits" / f"{manifest.name}-{manifest.digest[:16]}"
    cached = directory.is_dir() and directory_hashes(directory) == manifest.files
    if not cached:
        partial = directory.with_name(directory.name + ".partial")
        shutil.rmtree(partial, ignore_errors=True)
        write_split(split, partial, workers=workers or default_workers(),
                    progress=progress or ProgressLine(f"generating split {manifest.name} into {directory}"),
                    bounds_cache=True)
        shutil.rmtree(directory, ignore_errors=True)
        partial.rename(directory)
    check_directory(directory, manifest)
    (directory / CACHE_FOLDER).mkdir(exist_ok=True)  # a directory generated before the cache existed gets one
    return sorted(add_scenario_dir(directory), key=_seed_of)
