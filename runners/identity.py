"""Content hashes that identify runs and configurations (light: readers of results import this).

A run's id is the SHA-256 of its resolved configuration (canonical JSON); the *configuration key*
is the same hash without what varies inside one Table 1 cell (env, scenario, variant, seed), so
every run of one cell and one configuration shares it. :mod:`runners.plan` builds the configs;
the leaderboard recomputes the key from each run's recorded config.
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


def run_identity(config: dict[str, Any]) -> str:
    """The id a run's recorded config stands for: :func:`run_id_of` without the provenance (a
    sweep's configs have none, so for them this is :func:`run_id_of` itself)."""
    return run_id_of({k: v for k, v in config.items() if k != PROVENANCE_KEY})
