"""Content hashes that identify runs and configurations (light: readers of results import this).

A run's id is the SHA-256 of its resolved configuration (canonical JSON); the *configuration key*
is the same hash without what varies inside one Table 1 cell (env, scenario, variant, seed), so
every run of one cell and one configuration shares it. :mod:`runners.plan.runs` builds the configs of a
sweep, ``leaderboard.submit`` and ``leaderboard.llm`` those of submitted runs (which record their
provenance beside what they are); this module alone says what a run's id and configuration key are,
and the leaderboard recomputes the key from each run's recorded config (:func:`configuration_key`).
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

#: What varies inside one Table 1 cell (every variant of the scenario, every seed) and so is left
#: out of the configuration key.
PER_RUN_KEYS = ("env_id", "scenario", "variant", "seed")


def run_id_of(config: dict[str, Any]) -> str:
    """The content hash identifying a run (16 hex digits of SHA-256 over canonical JSON)."""
    canonical = json.dumps(config, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(canonical.encode()).hexdigest()[:16]


def config_key(config: dict[str, Any]) -> str:
    """The hash of a run config without :data:`PER_RUN_KEYS`: one value per configuration of a cell."""
    return run_id_of({k: v for k, v in config.items() if k not in PER_RUN_KEYS})


#: The part of a submitted run's config that says who submitted it and from where: recorded, but not
#: part of what the run is, so left out of its id (``leaderboard.submit`` writes it).
PROVENANCE_KEY = "provenance"


#: ``algo`` name in the config of a run whose policy was trained elsewhere and submitted
#: (``python -m leaderboard.submit``, ``python -m leaderboard.llm``): no learner class made it.
SUBMITTED_ALGO = "submitted"


def run_identity(config: dict[str, Any]) -> str:
    """The id a run's recorded config stands for: :func:`run_id_of` without the provenance (a
    sweep's configs have none, so for them this is :func:`run_id_of` itself)."""
    return run_id_of({k: v for k, v in config.items() if k != PROVENANCE_KEY})


def configuration_key(config: dict[str, Any]) -> str:
    """The configuration key a run's recorded config stands for: :func:`config_key` without the
    provenance, so that a submission resumed by someone else, or from another directory, is still
    one configuration (for a sweep's configs this is :func:`config_key` itself)."""
    return config_key({k: v for k, v in config.items() if k != PROVENANCE_KEY})
