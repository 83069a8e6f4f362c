"""Learner classes named by import path (an algo file's ``_target_``), so the set of learners is open.

A learner is whatever class its configuration names: an SB3 algorithm (``stable_baselines3.PPO``,
``sb3_contrib.TRPO``, this package's ``morality_gym.baselines.safe.CPO``, or a user's own subclass),
which :class:`~morality_gym.baselines.sb3_learner.SB3Learner` drives, or a
:class:`~morality_gym.baselines.learners.Learner` subclass that drives itself (the random
baseline). The five baselines are named this way too; no table of learners exists anywhere.

A user's class may live in a plain Python file outside any installed package: the directory that
holds it is put on ``sys.path`` *and* on ``PYTHONPATH`` (:func:`add_python_roots`), so the sweep's
worker processes and SLURM jobs (which inherit the environment) import it the same way. A saved
model records its class's path and, for a class outside the installed packages, the directory it
was imported from (:func:`import_root`), so it loads again in a fresh process.

This module imports nothing from the project: the specs (lowest layer of the baselines) use it.
"""

from __future__ import annotations

import importlib
import logging
import os
import sys
from collections.abc import Iterable
from pathlib import Path


class TargetError(ValueError):
    """A ``_target_`` that cannot be imported; the message names it and the fix."""


def resolve(target: str, where: str = "_target_", search: Iterable[str | Path] = ()) -> type:
    """The class at the dotted path ``target`` (``package.module.Class``).

    ``search``: directories to put on the import path first (a saved model's recorded root).
    Raises :class:`TargetError` with one line saying what is missing and how to make it importable.
    """
    if not isinstance(target, str) or "." not in target.strip("."):
        raise TargetError(f"{where}: expected the import path of a class, like stable_baselines3.PPO, got {target!r}")
    add_python_roots(search)
    from hydra.utils import get_class  # Hydra waits: importing morality_gym.baselines.targets must not load it

    hydra_log = logging.getLogger("hydra.utils")  # it logs the failure on three lines; ours says it on one
    level = hydra_log.level
    hydra_log.setLevel(logging.CRITICAL)
    try:
        cls = get_class(target)
    except Exception as exc:  # hydra wraps ImportError/AttributeError in its own kinds
        cause = exc.__cause__ or exc
        module = target.rsplit(".", 1)[0].split(".")[0]
        raise TargetError(
            f"{where}: cannot import {target!r} ({type(cause).__name__}: {str(cause).splitlines()[0] if str(cause) else ''}); "
            f"install the package that provides {module!r}, or put {module}.py in the config directory given with "
            "--config-dir/hydra.searchpath (or on PYTHONPATH)"
        ) from exc
    finally:
        hydra_log.setLevel(level)
    if not isinstance(cls, type):
        raise TargetError(f"{where}: {target!r} is not a class")
    return cls


def learner_trains(target: str) -> bool:
    """Whether the learner named by ``target`` trains at all (``False`` for the random baseline).

    A self-driving learner class says so with a class attribute ``trains = False``; SB3 algorithms
    train.
    """
    return bool(getattr(resolve(target), "trains", True))


def import_root(cls: type) -> str | None:
    """The directory a class's top-level module was imported from, if it is outside ``site-packages``
    and outside this project (so that a saved model of a user's class can be loaded elsewhere)."""
    module = sys.modules.get(cls.__module__)
    path = getattr(module, "__file__", None)
    if not path:
        return None
    root = Path(path).resolve().parent
    for _ in range(cls.__module__.count(".")):
        root = root.parent
    if "site-packages" in root.parts or "dist-packages" in root.parts:
        return None
    project = Path(__file__).resolve().parents[2]
    if root == project or root == Path(sys.prefix).resolve():
        return None
    return str(root)


def add_python_roots(directories: Iterable[str | Path]) -> None:
    """Make modules in ``directories`` importable here and in every process started from here."""
    added = [str(Path(d).expanduser().resolve()) for d in directories if d]
    if not added:
        return
    for directory in reversed(added):
        if directory not in sys.path:
            sys.path.insert(0, directory)
    current = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    merged = [*added, *(p for p in current if p not in added)]
    os.environ["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(merged))
    importlib.invalidate_caches()
