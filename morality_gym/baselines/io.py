"""Loading saved learners: a model file plus its JSON sidecar naming the algorithm.

``Learner.save`` writes ``<name>.zip`` (SB3's format) and ``<name>.json`` (what it is: algorithm,
env id, chain, seed, spec). Loading reads the sidecar to pick the right class, so a PPO-Lag model
is never silently loaded as plain PPO.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def read_metadata(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    sidecar = path.with_suffix(".json")
    if not sidecar.is_file():
        raise FileNotFoundError(f"{path}: no metadata file {sidecar.name} next to it (saved by Learner.save)")
    return json.loads(sidecar.read_text())


def load_model(path: str | Path) -> Any:
    """The policy saved at ``path``: ``"random"`` or an SB3 model of the right class."""
    path = Path(path)
    meta = read_metadata(path)
    impl = meta.get("implementation")
    if impl == "random":
        return "random"
    zip_path = path.with_suffix(".zip")
    if impl == "ppo":
        from stable_baselines3 import PPO

        return PPO.load(zip_path, device="cpu")
    if impl == "ppo_lag":
        from morality_gym.baselines.safe import PPOLag

        return PPOLag.load(zip_path, device="cpu")
    if impl == "cpo":
        from morality_gym.baselines.safe import CPO

        return CPO.load(zip_path, device="cpu")
    raise ValueError(f"{path}: unknown implementation {impl!r} in its metadata")
