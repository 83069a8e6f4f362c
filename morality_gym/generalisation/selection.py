"""A v2 split's manifest: which (env id, chain) pairs of a v1 split it keeps, checked before use.

:mod:`~morality_gym.generalisation.headroom` explains v2 splits and publishes them; this module
only reads their manifests (``morality_gym/data/splits/<split>-v2.json``), so that the track's sets
(:mod:`~morality_gym.generalisation.sets`) can select from them without importing the publisher.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from morality_gym.generator.splits import SPLITS_DIR, SplitError, split_manifest

#: The least oracle best - Random a v2 pair leaves (chosen from the v1 distribution: see
#: docs/how-to/generalisation-track.md).
THRESHOLD: Final[float] = 0.1
VERSION: Final[int] = 2


@dataclass(frozen=True)
class HeadroomSplit:
    """A v2 split's manifest (module docstring)."""

    name: str
    base: str
    base_digest: str
    threshold: float
    pairs: dict[str, list[str]]  # chain -> kept env ids, in the v1 split's order
    digest: str
    source: str

    def env_ids(self, chain: str) -> list[str]:
        if chain not in self.pairs:
            raise SplitError(f"{self.source}: no pairs of chain {chain!r}; it has {', '.join(self.pairs)}")
        return list(self.pairs[chain])


def manifest_path(split: str, directory: Path = SPLITS_DIR) -> Path:
    return directory / f"{split}-v{VERSION}.json"


def selection_digest(base_digest: str, threshold: float, pairs: dict[str, list[str]]) -> str:
    """SHA-256 of the selection: the v1 split's digest, the threshold and one ``chain env_id`` line a pair."""
    lines = [f"base {base_digest}", f"threshold {threshold!r}"]
    lines += [f"{chain} {env_id}" for chain in sorted(pairs) for env_id in sorted(pairs[chain])]
    return hashlib.sha256(("\n".join(lines) + "\n").encode()).hexdigest()


def read_manifest(split: str, directory: Path = SPLITS_DIR) -> HeadroomSplit:
    """The v2 manifest of v1 split ``split``, checked: its base is the published split and its digest
    is that of the selection it lists (an edited list is refused, not used)."""
    path = manifest_path(split, directory)
    try:
        raw = json.loads(path.read_text())
        found = HeadroomSplit(raw["split"], raw["base"], raw["base_digest"], float(raw["threshold"]),
                              {c: list(ids) for c, ids in raw["pairs"].items()}, raw["digest"], str(path))
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise SplitError(f"{path}: not a v{VERSION} split manifest ({exc!r}). Fix: republish it with "
                         "morality_gym.generalisation.headroom.publish") from exc
    base = split_manifest(split)
    if found.base != split or found.base_digest != base.digest:
        raise SplitError(f"{path}: selects from split {found.base} of digest {found.base_digest[:16]}..., the published "
                         f"{split} has {base.digest[:16]}.... Fix: republish it")
    if selection_digest(found.base_digest, found.threshold, found.pairs) != found.digest:
        raise SplitError(f"{path}: its pairs do not give its digest {found.digest[:16]}...: edited. Fix: restore it "
                         "(git checkout) or republish it")
    return found
