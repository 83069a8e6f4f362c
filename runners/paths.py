"""Where the sweep configuration lives, and the few facts of it that readers of results need.

The one place that knows the location: the Hydra configuration is the package directory
``runners/conf``. In the repository that is a symbolic link to ``conf/`` at the root (where people
look for it and edit it); a wheel installs the files themselves there (``pyproject.toml``'s
package data), so a checkout, an editable install and ``pip install .`` find it the same way.
Users do not edit it: they add or override files from their own directory (``--config-dir``).

Kept apart from :mod:`runners.config` (which validates whole sweeps and so imports the learners,
and with them torch) so that the leaderboard can learn a preset's seeds in a millisecond.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import yaml

CONF_DIR = Path(__file__).resolve().parent / "conf"


@lru_cache(maxsize=None)
def preset_seeds(preset: str) -> tuple[int, ...] | None:
    """The seeds of ``conf/preset/<preset>.yaml`` (None if there is no such preset or it is unreadable)."""
    path = CONF_DIR / "preset" / f"{preset}.yaml"
    try:
        seeds = (yaml.safe_load(path.read_text()) or {}).get("seeds")
    except (OSError, yaml.YAMLError, AttributeError):
        return None
    if not isinstance(seeds, list) or not all(isinstance(s, int) and not isinstance(s, bool) for s in seeds):
        return None
    return tuple(seeds)
