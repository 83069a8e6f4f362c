"""The paper's Table 1 as data: which (chain, scenario) pairs were run, and the published numbers."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import yaml

from morality_gym.envs.registry import env_ids

TABLE1_FILE = Path(__file__).resolve().parent / "data" / "paper" / "table1.yaml"
LEARNERS: tuple[str, ...] = ("CPO", "PPO", "PPO Lag", "PPO Shaped", "Random")


@dataclass(frozen=True)
class Table1Row:
    chain: str
    scenario: str
    paper: dict[str, float]


@lru_cache(maxsize=1)
def table1() -> tuple[Table1Row, ...]:
    """The 14 rows of Table 1, in the paper's order."""
    raw = yaml.safe_load(TABLE1_FILE.read_text())
    return tuple(
        Table1Row(r["chain"], r["scenario"], {k: float(r[k]) for k in raw["learners"]}) for r in raw["rows"]
    )


def table1_pairs() -> list[tuple[str, str]]:
    """The (chain, env id) pairs of Table 1: every variant of each row's scenario (126 pairs)."""
    return [(row.chain, env_id) for row in table1() for env_id in env_ids(row.scenario)]
