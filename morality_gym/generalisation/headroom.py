"""Splits v2: the pairs of the published splits that leave the Random policy real headroom under a chain.

A generated variant is kept in a v1 split because it is a dilemma under some built-in chain (oracle
best > worst). Many such dilemmas cannot rank learners: random wandering rarely reaches a lever or a
bystander, so Random already scores within a few hundredths of the best, and every learner, good
or bad, scores about the same. A v2 split keeps, per chain of the track
(:data:`~morality_gym.generalisation.sets.TRACK_CHAINS`), the env ids of the v1 split whose
*headroom* under that chain, oracle best - exact Random, is at least :data:`THRESHOLD`:

* the same files, seeds and held-out rule: a v2 split is a selection of (env id, chain) pairs of
  its v1 split (``train`` or ``test``), whose files ``load_split`` generates and checks as before;
* its own manifest, ``morality_gym/data/splits/<split>-v2.json``: the v1 split's digest, the
  threshold, per chain the kept env ids, what was dropped and why, the headroom distribution it
  was chosen from, and the SHA-256 of the selection (:func:`selection_digest`), which a result
  records;
* exact, so anyone can check it: the values are the oracle's and the exact evaluator's
  (:func:`~morality_gym.generalisation.sets.dilemma_values`); :func:`publish` recomputes them.

The threshold is chosen from the measured distribution (docs/how-to/generalisation-track.md).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np

from morality_gym.generalisation.selection import THRESHOLD, VERSION, manifest_path, selection_digest
from morality_gym.generalisation.sets import TRACK_CHAINS, PairValues, chain_values
from morality_gym.generator.splits import SPLITS_DIR, load_split, split_manifest

#: Quantiles of the headroom distribution a manifest records.
QUANTILES: Final[tuple[float, ...]] = (0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0)
#: Thresholds whose share of pairs below a manifest records (to show where the chosen one falls).
CUTS: Final[tuple[float, ...]] = (0.02, 0.05, 0.1, 0.15, 0.2, 0.3)
#: Left edges of the histogram a manifest records (the last bin ends at 1).
BINS: Final[tuple[float, ...]] = (0.0, 0.01, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.7)


def headroom_summary(values: Sequence[PairValues]) -> dict[str, Any]:
    """The distribution of best - Random over ``values``: quantiles, and the share under each cut."""
    headroom = np.array([p.best - p.random for p in values], dtype=float)
    if headroom.size == 0:
        return {"pairs": 0}
    counts, _ = np.histogram(headroom, [*BINS, np.inf])
    return {"pairs": int(headroom.size),
            "quantiles": {f"{q:g}": round(float(np.quantile(headroom, q)), 4) for q in QUANTILES},
            "below": {f"{c:g}": round(float((headroom < c).mean()), 4) for c in CUTS},
            "histogram": {f"{edge:g}": int(n) for edge, n in zip(BINS, counts)}}


def select(values: Sequence[PairValues], threshold: float) -> list[str]:
    """The env ids whose headroom is at least ``threshold`` (a pair per env id: one chain's values).
    Rounded to 9 decimals first: exact values carry float noise, and 0.1 must mean 0.1."""
    return [p.env_id for p in values if round(p.best - p.random, 9) >= threshold]


def manifest_record(split: str, env_ids: Sequence[str], values: dict[str, list[PairValues]],
                    threshold: float) -> dict[str, Any]:
    """The v2 manifest of v1 split ``split`` from each chain's values over its ``env_ids``."""
    base = split_manifest(split)
    pairs = {chain: select(values[chain], threshold) for chain in values}
    chains: dict[str, Any] = {}
    for chain, chain_values_ in values.items():
        chains[chain] = {"env_ids": len(env_ids), "dilemmas": len(chain_values_), "kept": len(pairs[chain]),
                         "dropped": {"not_a_dilemma": len(env_ids) - len(chain_values_),
                                     "below_threshold": len(chain_values_) - len(pairs[chain])},
                         "headroom": headroom_summary(chain_values_)}
    return {"split": f"{split}-v{VERSION}", "version": VERSION, "base": split, "base_digest": base.digest,
            "seeds": list(base.seeds), "seeds_tried": len(base.seed_range), "threshold": threshold,
            "chains": chains, "digest": selection_digest(base.digest, threshold, pairs), "pairs": pairs}


def manifest_text(record: dict[str, Any]) -> str:
    """A v2 manifest as committed: the summary first, then one chain's env ids a line."""
    head = {k: v for k, v in record.items() if k != "pairs"}
    text = json.dumps(head, indent=1)[:-2]
    pairs = ",\n".join(f"  {json.dumps(chain)}: {json.dumps(ids)}" for chain, ids in record["pairs"].items())
    return text + f',\n "pairs": {{\n{pairs}\n }}\n}}\n'


def publish(threshold: float = THRESHOLD, directory: Path = SPLITS_DIR, cache_dir: Path | None = None,
            progress: Callable[[str], None] | None = None) -> list[Path]:
    """Compute every track chain's exact values on both v1 splits (cached, minutes the first time)
    and write their v2 manifests."""
    written = []
    for split in ("train", "test"):
        env_ids = load_split(split, cache_dir)
        values = {chain: chain_values(split, env_ids, chain, cache_dir, progress) for chain in TRACK_CHAINS}
        path = manifest_path(split, directory)
        path.write_text(manifest_text(manifest_record(split, env_ids, values, threshold)))
        written.append(path)
    return written
