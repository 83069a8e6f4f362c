"""A realistic synthetic results frame for the statistics (tests and the ``stats`` benchmark).

The paper's 14 Table 1 rows with every variant of their scenario, five learners, any seeds and
protocols, learn-time curves and reference values. The per-norm values follow a per-learner
level plus noise and the metric is the chain's real metric of them (as in
:mod:`tests.leaderboard_data`), so relevant norms, ``mf_`` columns and metrics are consistent the
way real runs are. Everything is drawn from generators seeded by the run's identity, so the frame
is the same on every call. Frames are built in memory (no files): the statistics take frames.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from functools import cache
from typing import Any

import numpy as np
import pandas as pd

from morality_gym.results.schema import MF_PREFIX

LEARNERS = ("CPO", "PPO", "PPO Lag", "PPO Shaped", "Random")
#: (level of the top relevant norm, of the others) per learner, roughly the paper's picture.
LEVELS = {"CPO": (0.80, 0.70), "PPO": (0.30, 0.65), "PPO Lag": (0.40, 0.60), "PPO Shaped": (0.95, 0.80),
          "Random": (0.55, 0.55)}
#: Random (exact) and Oracle best of the paper's rows, means over variants (compute_reference with
#: beta 0.1 and max_steps 200, rounded): the real references, so the headroom guard meets the real case.
REFERENCES = {
    ("DualProcess", "Push2OrSwitch"): (0.546, 0.970),
    ("DualProcess", "PushOrSwitch"): (0.469, 0.965),
    ("DualProcess", "PushStandard"): (0.508, 0.933),
    ("DualProcessAgentHarm", "Push3SelfSacrifice"): (0.514, 0.977),
    ("DualProcessAgentHarm", "PushOrSwitchSelfSacrifice"): (0.949, 0.997),
    ("DualProcessAgentHarm", "PushSelfSacrifice"): (0.839, 0.977),
    ("Utility", "Push2OrSwitch"): (0.531, 0.994),
    ("Utility", "PushOrSwitch"): (0.270, 0.982),
    ("Utility", "Switch2Trolley4Track"): (0.109, 0.981),
    ("Utility", "Switch5"): (0.150, 0.996),
    ("Utility", "Switch7"): (0.054, 0.989),
    ("Utility", "SwitchStandard"): (0.280, 0.976),
    ("UtilityAgentHarm", "PushOrSwitchSelfSacrifice"): (0.795, 0.974),
    ("UtilityAgentHarm", "SwitchSelfSacrifice"): (0.280, 0.921),
}
LEARN_STEPS = tuple(range(0, 1_000_001, 50_000))


def _rng(*key: Any) -> np.random.Generator:
    return np.random.default_rng(zlib.crc32("|".join(map(str, key)).encode()))


@cache
def _bound(chain: str, env_id: str) -> Any:
    from morality_gym.norms.metric import bind_chain

    return bind_chain(chain, env_id, 0.1)


def reference_frame() -> pd.DataFrame:
    """:data:`REFERENCES` as the frame the ranking takes (chain, scenario, random, best)."""
    return pd.DataFrame([{"chain": c, "scenario": s, "random": r, "best": b} for (c, s), (r, b) in REFERENCES.items()])


def synthetic_runs(
    seeds: Sequence[int] = (41, 42, 43),
    protocols: Sequence[str] = ("paper",),
    learners: Sequence[str] = LEARNERS,
    preset: str = "paper",
    learn: bool = True,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(runs, learn)``: run rows with the schema's columns the statistics use, and learn-time evaluations.

    Learners' evaluation steps differ slightly (CPO and PPO Lag evaluate 1,024 steps later, as
    rollout boundaries make real runs do), so the curves exercise the grid alignment.
    """
    from morality_gym.envs.registry import env_ids, parse_env_id
    from morality_gym.paper import table1

    runs: list[dict[str, Any]] = []
    curves: list[dict[str, Any]] = []
    for row in table1():
        for env_id in env_ids(row.scenario):
            variant = parse_env_id(env_id)[1]
            bound = _bound(row.chain, env_id)
            relevant = list(bound.relevant)
            for protocol in protocols:
                for learner in learners:
                    top, rest = LEVELS[learner]
                    for seed in seeds:
                        run_id = f"{protocol}-{row.chain}-{env_id}-{learner}-{seed}".replace(" ", "_")
                        rng = _rng(run_id)
                        functions = {}
                        for norm in bound.chain.norm_names:
                            level = top if relevant and norm == relevant[0] else rest
                            functions[norm] = round(float(np.clip(level + rng.normal(0, 0.12), 0, 1)), 2)
                        metric = float(bound.metric(functions))
                        runs.append({
                            "run_id": run_id, "status": "ok", "env_id": env_id, "scenario": row.scenario,
                            "variant": variant, "chain": row.chain, "learner": learner, "protocol": protocol,
                            "preset": preset, "seed": seed, "beta": 0.1, "max_steps": 200,
                            "relevant_norms": relevant, "metric": metric, "exact_metric": metric,
                            "mean_return": float(60 - 40 * top + rng.normal(0, 15)),
                            "mean_cost": float(max(0.0, 0.1 * (1 - metric) + rng.normal(0, 0.01))),
                        } | {f"{MF_PREFIX}{n}": v for n, v in functions.items()})
                        if not learn:
                            continue
                        offset = 1024 if learner in ("CPO", "PPO Lag") else 0
                        start = 0.5 + rng.normal(0, 0.03)
                        for step in LEARN_STEPS:
                            progress = 1 - np.exp(-step / 250_000)
                            value = float(np.clip(start + (metric - start) * progress + rng.normal(0, 0.02), 0, 1))
                            curves.append({"run_id": run_id, "step": step + (offset if step else 0), "metric": value,
                                           "exact_metric": value, "mean_return": 0.0, "mean_cost": 0.0})
    return pd.DataFrame(runs), pd.DataFrame(curves)
