"""Loading saved learners: a model file plus its JSON sidecar naming the algorithm and the env.

``Learner.save`` writes ``<name>.zip`` (SB3's format) and ``<name>.json`` (what it is: the import
path of its class as ``target``, env id, chain, seed, spec; for a user's class from a plain file,
the directory to import it from as ``import_root``). Loading imports the recorded class, so any
learner, built-in or a user's, loads with no table of learners, a PPO-Lag model is never silently
loaded as plain PPO, and to know which env the model was trained on: a policy
evaluated on another env than its own gives a number about nothing in particular, so
:func:`check_model_env` refuses that unless the caller explicitly allows it *and* the observation
sizes agree (a different size could not even be fed to the network). Every way a model file can
be unusable (sidecar missing or unreadable, zip damaged, wrong env) raises :class:`ModelError`
with the file and the fix.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from morality_gym.baselines.learners import Learner
from morality_gym.baselines.specs import LEGACY_IMPLEMENTATIONS as _LEGACY_TARGETS  # old sidecars' ``implementation``
from morality_gym.baselines.targets import TargetError, resolve
from morality_gym.envs.registry import canonical_env_id, state_graph


class ModelError(ValueError):
    """A saved model cannot be used as asked; the message names the file and the fix."""


def _paths(path: str | Path) -> tuple[Path, Path]:
    """(``.zip``, ``.json``) of a model given by either file or by the name without suffix."""
    path = Path(path)
    base = path.with_suffix("") if path.suffix in (".zip", ".json") else path
    return base.with_suffix(".zip"), base.with_suffix(".json")


def read_metadata(path: str | Path) -> dict[str, Any]:
    """The sidecar of a saved model (``model.json`` next to ``model.zip``)."""
    zip_path, sidecar = _paths(path)
    if not sidecar.is_file():
        raise ModelError(
            f"{path}: no metadata file {sidecar.name} next to it; a model is saved by Learner.save as "
            f"{zip_path.name} + {sidecar.name}: copy both files (the .json says which algorithm and env it was trained on)"
        )
    try:
        meta = json.loads(sidecar.read_text())
    except (OSError, ValueError) as exc:
        raise ModelError(f"{sidecar}: unreadable model metadata ({type(exc).__name__}: {exc}); "
                         "restore the file saved by Learner.save or retrain the run") from exc
    if isinstance(meta, dict) and "target" not in meta and meta.get("implementation") in _LEGACY_TARGETS:
        meta["target"] = _LEGACY_TARGETS[meta["implementation"]]
    if not isinstance(meta, dict) or not isinstance(meta.get("target"), str):
        raise ModelError(f"{sidecar}: no 'target' (the import path of the model's class); "
                         "this is not a sidecar written by Learner.save")
    return meta


def model_class(path: str | Path, meta: dict[str, Any]) -> type:
    """The class recorded in a sidecar, imported (from its recorded ``import_root`` if need be)."""
    roots = [meta["import_root"]] if isinstance(meta.get("import_root"), str) else []
    try:
        return resolve(meta["target"], where=f"{_paths(path)[1]}: target", search=roots)
    except TargetError as exc:
        raise ModelError(str(exc)) from exc


def load_model(path: str | Path) -> Any:
    """The policy saved at ``path``: ``"random"``, an SB3 model of its recorded class, or what a
    self-driving learner class's ``load_policy`` returns."""
    meta = read_metadata(path)
    cls = model_class(path, meta)
    zip_path, _ = _paths(path)
    if isinstance(cls, type) and issubclass(cls, Learner):
        return cls.load_policy(zip_path, meta)
    if not zip_path.is_file():
        raise ModelError(f"{zip_path}: missing, but {zip_path.with_suffix('.json').name} says it is a {cls.__name__} model; "
                         "restore the .zip saved with it or retrain the run")
    try:
        return cls.load(zip_path, device="cpu")
    except Exception as exc:  # zipfile, torch and pickle each raise their own kinds
        raise ModelError(f"{zip_path}: cannot be loaded as a {cls.__name__} model ({type(exc).__name__}: {exc}); "
                         "the file is damaged or was not saved by Learner.save: restore it or retrain the run") from exc


def observation_size(policy: Any) -> int | None:
    """The flat observation size an SB3 model expects (None for ``"random"`` and other policies)."""
    space = getattr(policy, "observation_space", None)
    shape = getattr(space, "shape", None)
    return int(shape[0]) if shape else None


def check_model_env(path: str | Path, policy: Any, env_id: str, allow_other_env: bool = False) -> None:
    """Refuse to evaluate a model on another env than the one it was trained on.

    ``allow_other_env`` lets a model trained on one variant be evaluated on another (a
    generalisation test), but only when the observation sizes agree; a random "model" fits any env.
    """
    meta = read_metadata(path)
    if isinstance(policy, str) and policy == "random":
        return

    trained = str(meta.get("env_id", ""))
    wanted = canonical_env_id(env_id)
    try:
        trained = canonical_env_id(trained)
    except (KeyError, TypeError):
        pass  # an env this installation does not know: compared by name below
    if trained == wanted:
        return
    expected = observation_size(policy)
    actual = int(state_graph(wanted).obs[0].shape[0])
    if expected is not None and expected != actual:
        raise ModelError(f"{path}: trained on {trained} (observation size {expected}); {wanted} has observation size "
                         f"{actual}, so the model cannot be evaluated there: evaluate it on {trained}")
    if not allow_other_env:
        raise ModelError(f"{path}: trained on {trained}, not on {wanted}; evaluate it on its own env (e.g. --scenario "
                         f"{trained.split('-')[0]} --variant {trained.split('-')[1] if trained.count('-') >= 2 else '?'}), "
                         "or pass --allow-other-env to evaluate it on another variant on purpose")
