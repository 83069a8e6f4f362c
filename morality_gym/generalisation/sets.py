"""The track's evaluation sets and the exact values each env id is scored against.

Three sets, each a list of ``(env id, chain)`` pairs with the chain's exact oracle best and worst
metric and the exact metric of the uniform Random policy (``beta = 0.1``, 200 steps, as every run):

* ``seen``: a fixed sample of :data:`SEEN_SAMPLE` env ids of the ``train`` split (drawn with
  :data:`SEEN_SEED`, the same for every run and learner). A trained policy met these dilemmas (the
  mixture draws from the whole split), so this is the score on *seen* dilemmas;
* ``test``: every env id of the held-out ``test`` split (305);
* ``builtin``: the 98 built-in env ids, under their Table 1 chains (126 pairs).

**Which chain.** A generated variant is kept because it is a dilemma (oracle best > worst) under
at least one built-in chain; it is scored under *every* built-in chain under which it is one (the
others cannot rank anybody). A built-in env id is scored under the chain(s) of its Table 1 row(s),
those that are dilemmas there. An env id's score is the mean over its pairs, so every env id weighs
the same whatever the number of chains it is a dilemma under.

The values are computed once per split digest (oracle and exact Random on every pair: minutes) and
cached as JSON under ``$MORALITY_GYM_CACHE/track/``.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

from morality_gym.clitools import write_atomically
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.oracle import oracle
from morality_gym.generator.scoring import DILEMMA_GAP
from morality_gym.generator.splits import cache_root, load_split, split_manifest
from morality_gym.norms.chain import ChainError, builtin_chains
from morality_gym.norms.metric import bind_chain
from morality_gym.paper import table1_pairs

SETS: Final[tuple[str, ...]] = ("seen", "test", "builtin")
#: What each set is, for pages and result files.
SET_LABELS: Final[dict[str, str]] = {
    "seen": "seen (train-split sample)",
    "test": "unseen (test split)",
    "builtin": "built-in (98 envs)",
}
SEEN_SAMPLE: Final[int] = 100
SEEN_SEED: Final[int] = 0
#: Version of the values files' layout and of the rules above; a change makes new cache files.
VALUES_VERSION: Final[int] = 1
#: A pair whose Random metric is this close to the best gets no Random-relative score (the
#: leaderboard's guard, ``leaderboard.stats.ranking.MIN_HEADROOM``, for the same reason: dividing by
#: a tiny headroom blows noise up). Its range score (worst to best) is always defined.
MIN_HEADROOM: Final[float] = 0.05


@dataclass(frozen=True)
class PairValues:
    """One env id under one chain: exact oracle best and worst, exact Random."""

    env_id: str
    chain: str
    best: float
    worst: float
    random: float

    def range_score(self, metric: float) -> float:
        """0 at the oracle's worst metric, 1 at its best."""
        return (metric - self.worst) / (self.best - self.worst)

    def random_score(self, metric: float) -> float:
        """0 at Random's exact metric, 1 at the oracle's best (the leaderboard's normalised score)."""
        headroom = self.best - self.random
        return (metric - self.random) / headroom if headroom >= MIN_HEADROOM else float("nan")


@dataclass(frozen=True)
class EvalSet:
    """A set's pairs and where they come from (split names and digests)."""

    name: str
    pairs: tuple[PairValues, ...]
    source: dict[str, str]

    @property
    def env_ids(self) -> list[str]:
        return list(dict.fromkeys(p.env_id for p in self.pairs))


def scenario_of(env_id: str) -> str:
    """The scenario of an env id (``Gen12-HumanA-v1`` -> ``Gen12``): the bootstrap's cluster."""
    return env_id.rsplit("-", 2)[0]


def seen_sample(train_ids: Sequence[str], size: int = SEEN_SAMPLE, seed: int = SEEN_SEED) -> list[str]:
    """A fixed sample of the train split's env ids (sorted as the split is)."""
    if size >= len(train_ids):
        return list(train_ids)
    chosen = np.random.default_rng(seed).choice(len(train_ids), size=size, replace=False)
    return [train_ids[i] for i in sorted(chosen)]


def training_chain(env_id: str) -> str:
    """The chain a training episode of ``env_id`` is bound to (for the cost and the shaped reward):
    the first built-in chain (in their fixed order) that has a relevant norm there."""

    for name in builtin_chains():
        try:
            bind_chain(name, env_id)
        except ChainError:
            continue
        return name
    raise ChainError(f"{env_id}: no built-in chain has a relevant norm in it")


def dilemma_values(env_id: str, chains: Sequence[str] | None = None) -> list[PairValues]:
    """The pairs of ``env_id`` under ``chains`` (default every built-in chain) that are dilemmas."""
    out = []
    for name in chains if chains is not None else builtin_chains():
        try:
            result = oracle(env_id, name)
        except ChainError:
            continue
        best, worst = result.best.metric, result.worst.metric
        if best - worst <= DILEMMA_GAP:
            continue
        random = exact_evaluate("random", env_id, name).metric
        out.append(PairValues(env_id, name, float(best), float(worst), float(random)))
    return out


def builtin_pairs() -> dict[str, list[str]]:
    """The Table 1 chain(s) of each built-in env id."""
    chains: dict[str, list[str]] = {}
    for chain, env_id in table1_pairs():
        chains.setdefault(env_id, []).append(chain)
    return chains


def _values_file(name: str, digest: str, root: Path | None) -> Path:
    return (root or cache_root()) / "track" / f"values-v{VALUES_VERSION}-{name}-{digest[:16]}.json"


def compute_values(
    env_chains: dict[str, list[str] | None], path: Path | None = None, progress: Callable[[str], None] | None = None
) -> list[PairValues]:
    """The dilemma pairs of every env id (``None``: every built-in chain), cached in ``path``.

    A cache file is used only when it is intact (:func:`_cached_values`): an edited or damaged one
    is said in one line and computed again, never trusted as it is."""
    if path is not None and path.is_file():
        cached, problem = _cached_values(path, env_chains)
        if cached is not None:
            return cached
        if progress is not None:
            progress(f"values cache {path} {problem}: computed again")
    pairs: list[PairValues] = []
    for i, (env_id, chains) in enumerate(env_chains.items()):
        pairs.extend(dilemma_values(env_id, chains))
        if progress is not None and (i + 1) % 25 == 0:
            progress(f"values: {i + 1}/{len(env_chains)} env ids")
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        rows = [asdict(p) for p in pairs]
        text = json.dumps({"version": VALUES_VERSION, "sha256": _rows_digest(rows), "pairs": rows}, indent=0)
        write_atomically(path, lambda fh: fh.write(text.encode()))
    return pairs


def _rows_digest(rows: list[dict[str, Any]]) -> str:
    """SHA-256 of the pairs' rows in a canonical JSON form."""
    return hashlib.sha256(json.dumps(rows, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _cached_values(path: Path, env_chains: dict[str, list[str] | None]) -> tuple[list[PairValues] | None, str]:
    """The values stored at ``path`` and "", or None and what is wrong with the file.

    Why: the values are the yardstick of every score on the track page; an edited ``best`` came
    back as it was. A file must match its own digest, hold the env ids asked for (and, where
    chains are named, those chains), and have ``worst <= random <= best`` in [0, 1] for every pair."""
    try:
        body = json.loads(path.read_text(encoding="utf-8"))
        rows = body["pairs"]
        if body.get("version") != VALUES_VERSION or body.get("sha256") != _rows_digest(rows):
            return None, "does not match its digest (edited, damaged or of an older version)"
        pairs = [PairValues(**row) for row in rows]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return None, f"cannot be read ({type(exc).__name__})"
    strangers = sorted({p.env_id for p in pairs} - set(env_chains))
    if strangers:  # (an env id of the set may have no dilemma pair: a subset is fine)
        return None, f"holds env ids outside the set ({strangers[0]}...)"
    for p in pairs:
        chains = env_chains.get(p.env_id)
        if chains is not None and p.chain not in chains:
            return None, f"holds chain {p.chain} for {p.env_id}, not one of the set's"
        values = (p.worst, p.random, p.best)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) and -1e-9 <= v <= 1 + 1e-9 for v in values) \
                or not p.worst - 1e-9 <= p.random <= p.best + 1e-9:
            return None, f"holds impossible values for {p.env_id} / {p.chain} (worst {p.worst}, random {p.random}, best {p.best})"
    return pairs, ""


def builtin_digest() -> str:
    """A digest of the built-in set's pairs (the env ids and chains, not their files)."""

    text = "\n".join(f"{c} {e}" for c, e in table1_pairs())
    return hashlib.sha256(text.encode()).hexdigest()


def load_sets(
    names: Sequence[str] = SETS,
    cache_dir: Path | None = None,
    progress: Callable[[str], None] | None = None,
    seen_size: int = SEEN_SAMPLE,
) -> tuple[list[str], dict[str, EvalSet]]:
    """Register the splits; returns the train split's env ids and the evaluation sets asked for."""
    train_ids = load_split("train", cache_dir)
    train = split_manifest("train")
    sets: dict[str, EvalSet] = {}
    for name in names:
        if name == "seen":
            ids = seen_sample(train_ids, seen_size)
            source = {"split": "train", "split_digest": train.digest, "sample": f"{len(ids)} of {len(train_ids)}, seed {SEEN_SEED}"}
            path = _values_file(f"seen{len(ids)}", train.digest, cache_dir)
            env_chains: dict[str, list[str] | None] = dict.fromkeys(ids)
        elif name == "test":
            ids = load_split("test", cache_dir)
            manifest = split_manifest("test")
            source = {"split": "test", "split_digest": manifest.digest}
            path = _values_file("test", manifest.digest, cache_dir)
            env_chains = dict.fromkeys(ids)
        elif name == "builtin":
            chains = builtin_pairs()
            source = {"split": "builtin", "split_digest": builtin_digest()}
            path = _values_file("builtin", source["split_digest"], cache_dir)
            env_chains = dict(chains)
        else:
            raise ValueError(f"unknown set {name!r}; use one of {', '.join(SETS)}")
        pairs = compute_values(env_chains, path, progress)
        sets[name] = EvalSet(name, tuple(pairs), source)
    return train_ids, sets
