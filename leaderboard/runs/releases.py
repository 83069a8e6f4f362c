"""Reading results releases (``releases/<name>/``): verify every checksum, then read the tables.

The layout of a release and how one is made: :mod:`leaderboard.release` (``python -m
leaderboard.release create``). The leaderboard reads a release exactly as it reads a results
directory (:mod:`leaderboard.runs.sources`).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from morality_gym.results.schema import SCHEMA_VERSION

#: Where a checkout keeps its releases; the leaderboard shows every release found here by default.
RELEASES_DIR = Path(__file__).resolve().parents[2] / "releases"
MANIFEST = "release.json"
RUNS, LEARN, UPDATES = "runs.parquet", "learn.parquet", "updates.parquet"
TABLES = ("table1.csv", "table1.md", "table1.tex")
#: Bump when the layout above changes meaning (a reader refuses releases of another version).
RELEASE_FORMAT = 1
#: How a manifest's ``commit`` starts when its runs were made at several commits (``mixed:657de81,9c3783b``).
MIXED = "mixed:"
_CHUNK = 1 << 20


class ReleaseError(ValueError):
    """A release that cannot be read or created; the message is one line naming the file."""


# ---------------------------------------------------------------------------------------- checksums
def sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def load_manifest(path: Path, what: str = "release manifest") -> dict[str, Any]:
    """The JSON manifest at ``path`` with its ``files`` table (every kind of release checks its
    own format on top); damage is a one-line :class:`ReleaseError`."""
    try:
        body = json.loads(path.read_text())
    except OSError as exc:
        raise ReleaseError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from exc
    except ValueError as exc:
        raise ReleaseError(f"{path}: not valid JSON ({exc}); the release is damaged") from exc
    if not isinstance(body, dict) or not isinstance(body.get("files"), dict):
        raise ReleaseError(f"{path}: no 'files' table; not a {what}")
    return body


def read_manifest(release: Path) -> dict[str, Any]:
    """``release.json`` of ``release``, checked for the fields a reader relies on."""
    path = release / MANIFEST
    body = load_manifest(path)
    if body.get("format") != RELEASE_FORMAT:
        raise ReleaseError(f"{path}: release format {body.get('format')!r}, this code reads format {RELEASE_FORMAT}")
    if body.get("schema_version") != SCHEMA_VERSION:
        raise ReleaseError(f"{path}: run schema version {body.get('schema_version')!r}, this code reads "
                           f"{SCHEMA_VERSION} (python -m runners.migrate explains upgrades)")
    return body


def verify(release: Path) -> dict[str, Any]:
    """The manifest of ``release`` after checking every listed file's size and SHA-256.

    Raises :class:`ReleaseError` naming the first file that is missing or differs, so a damaged
    download or a hand edit never shows as published numbers.
    """
    body = read_manifest(release)
    check_files(release, body, MANIFEST)
    return body


def check_files(release: Path, body: dict[str, Any], manifest: str) -> None:
    """Check every file ``body['files']`` lists (size and SHA-256, inside ``release``); the track
    release (:mod:`leaderboard.track_release`) checks its files by the same rule."""
    root = release.resolve()
    for name, entry in sorted(body["files"].items()):
        path = (release / name).resolve()
        if not path.is_relative_to(root):
            raise ReleaseError(f"{release / manifest}: file entry {name!r} points outside the release")
        if not path.is_file():
            raise ReleaseError(f"release {body.get('name')}: {release / name} is missing (listed in {manifest})")
        if path.stat().st_size != entry.get("bytes") or sha256(path) != entry.get("sha256"):
            raise ReleaseError(f"release {body.get('name')}: {release / name} fails its checksum (damaged or edited; "
                               f"restore it, e.g. git checkout -- {release / name})")


# ---------------------------------------------------------------------------------------- reading
@dataclass
class Release:
    """A verified release, read: its manifest and tables (:func:`load`)."""

    path: Path
    manifest: dict[str, Any]
    runs: pd.DataFrame
    learn: pd.DataFrame
    updates: pd.DataFrame

    @property
    def name(self) -> str:
        return str(self.manifest["name"])

    @property
    def commits(self) -> tuple[str, ...]:
        """The short commits the release's runs were made at: one, or several for a sweep resumed
        after the code moved on (the manifest's ``mixed:657de81,9c3783b``). Every page names them
        all, rather than one that made only some runs."""
        commit = str(self.manifest.get("commit") or "unknown")
        if commit.startswith(MIXED):
            return tuple(commit[len(MIXED):].split(","))
        return (commit[:7],)

    @property
    def commit_word(self) -> str:
        """``commit`` or ``commits``, for the label and the index page."""
        return "commits" if len(self.commits) > 1 else "commit"

    @property
    def label(self) -> str:
        """``release <name> (commit abc1234, 2026-11-26)``: how pages name where numbers come from."""
        created = str(self.manifest.get("created", ""))[:10]
        return f"release {self.name} ({self.commit_word} {', '.join(self.commits)}, {created})"


def load(release: Path) -> Release:
    """Verify, then read, the release at ``release``."""
    body = verify(release)
    try:
        runs = pq.read_table(release / RUNS).to_pandas()
        learn = pq.read_table(release / LEARN).to_pandas() if (release / LEARN).is_file() else pd.DataFrame()
        updates = pq.read_table(release / UPDATES).to_pandas() if (release / UPDATES).is_file() else pd.DataFrame()
    except (pa.ArrowException, OSError) as exc:
        raise ReleaseError(f"release {body['name']}: cannot read its tables ({exc})") from exc
    return Release(release, body, runs, learn, updates)


def find_releases(root: Path = RELEASES_DIR) -> list[Path]:
    """Every release directory under ``root`` (a folder holding ``release.json``), by name."""
    if not root.is_dir():
        return []
    return sorted(p for p in root.iterdir() if (p / MANIFEST).is_file())


def resolve(items: Sequence[str]) -> list[Release]:
    """The releases a command line names (``--release DIR``, or ``all``: every release in
    :data:`RELEASES_DIR`), each verified and read, in order, once each."""
    paths: list[Path] = []
    for item in items:
        paths.extend(find_releases() if item == "all" else [Path(item)])
    out = []
    for path in dict.fromkeys(paths):
        if not (path / MANIFEST).is_file():
            known = ", ".join(p.name for p in find_releases()) or "none in releases/"
            raise ReleaseError(f"--release {path}: no {MANIFEST} there (releases: {known})")
        out.append(load(path))
    return out
