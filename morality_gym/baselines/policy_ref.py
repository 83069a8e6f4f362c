"""Policies named on a command line: ``random``, a saved model, or an importable ``module:attr``.

``eval``, ``play`` and ``python -m leaderboard.submit`` take a policy *reference* (a string) and
need the same three things from it: the policy object the evaluators accept (:class:`morality_gym.evaluation.policies.PolicyAdapter`),
the file whose bytes define it (so a submission can be hashed and re-submitted idempotently), and a
one-line error naming what is wrong when it cannot be used. This module is that one place. It sits
with the baselines because a saved model is loaded by :mod:`morality_gym.baselines.io`; code below
that layer (:func:`morality_gym.evaluation.gif.record_episode`, the evaluators) takes the resolved
policy object, ``load_policy(ref).policy``.

Accepted references:

* ``random`` - uniform random actions;
* ``path/to/file.py:attr`` - ``attr`` (dots allowed: ``Agent.act``) of a Python file, loaded under
  a private module name (the file need not be on ``sys.path``);
* ``package.module:attr`` - ``attr`` of an importable module;
* a saved model (``model.zip``, ``model.json`` or the name without suffix, as ``Learner.save``
  writes them).

The attribute may be a callable ``obs -> action`` or ``obs -> 6 action probabilities``, a table
(``dict`` from ``tuple(obs)`` to probabilities) or an SB3 model: whatever ``PolicyAdapter`` takes.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import re
import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from morality_gym.baselines.compact_policy import CompactObservationPolicy
from morality_gym.baselines.io import check_model_env, load_model, read_metadata
from morality_gym.baselines.policy_files import directory_files, files_digest, watching
from morality_gym.clitools import UserError, did_you_mean, sigints
from morality_gym.envs.registry import state_graph
from morality_gym.envs.trolley import InvalidActionError
from morality_gym.evaluation.policies import PolicyAdapter, PolicyFailure, ended_by

RANDOM = "random"
#: ``module.path:attr.path`` (identifiers only) - told apart from a file path by its shape.
_MODULE_REF = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_][\w.]*$")
_HELP = ("a policy is 'random', a saved model (model.zip), 'path/to/file.py:function' or 'package.module:function' "
         "(a callable obs -> action or 6 probabilities)")


class PolicyError(UserError):
    """A policy reference that cannot be used: the message names the reference and the fix."""


@dataclass(frozen=True)
class LoadedPolicy:
    """A resolved policy reference.

    ``policy`` is what the evaluators take; ``kind`` is ``random``, ``model`` or ``callable``;
    ``files`` are the files whose bytes define the policy (empty for ``random``).
    """

    ref: str
    kind: str
    policy: Any
    files: tuple[Path, ...] = ()
    #: The directory the files are named relative to (:mod:`.policy_files`); None: by bare name.
    root: Path | None = None

    def sha256(self) -> str:
        """SHA-256 over the defining files' names and bytes (of the reference itself for ``random``).

        A changed policy file, helper module or data file gives another hash, which is how a
        re-submission of a changed policy is told from a repeated one.
        """
        if not self.files:
            return hashlib.sha256(self.ref.encode()).hexdigest()
        return files_digest(self.files, self.root)

    def with_files(self, extra: Iterable[Path]) -> LoadedPolicy:
        """This policy with ``extra`` files counted too (the entry file first, the others sorted)."""
        first = self.files[:1]
        rest = sorted({Path(p).resolve() for p in (*self.files[1:], *extra)} - set(first))
        return replace(self, files=(*first, *rest))

    def with_directory(self, directory: Path) -> LoadedPolicy:
        """This policy with every file of a declared ``directory`` counted, named relative to it."""
        root = Path(directory).resolve()
        first = self.files[:1]
        rest = [p for p in directory_files(root) if p not in first]
        return replace(self, files=(*first, *rest), root=root)


def _import_file(path: Path) -> Any:
    """Execute a Python file as a module of its own (name derived from its absolute path)."""
    resolved = path.resolve()
    name = "_morality_gym_policy_" + hashlib.sha256(str(resolved).encode()).hexdigest()[:12]
    spec = importlib.util.spec_from_file_location(name, resolved)
    if spec is None or spec.loader is None:
        raise PolicyError(f"policy {path}: cannot be loaded as a Python file; {_HELP}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickling look the module up by name
    before = sigints()
    try:
        spec.loader.exec_module(module)
    except Exception as exc:
        sys.modules.pop(name, None)
        raise PolicyError(f"policy file {path} failed to import ({type(exc).__name__}: {exc}); fix the file") from exc
    except (SystemExit, KeyboardInterrupt) as exc:
        sys.modules.pop(name, None)
        if isinstance(exc, KeyboardInterrupt) and sigints() != before:
            raise  # a real Ctrl-C
        raise PolicyError(f"policy file {path} {ended_by(exc)} while it was imported; a policy file must define the "
                          "policy, not run a program (put a script's part under if __name__ == '__main__':)") from exc
    return module


def _attribute(module: Any, attr: str, where: str) -> Any:
    obj = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            names = [n for n in dir(obj) if not n.startswith("_")]
            hint = did_you_mean(part, names, n=3, quote=False)
            raise PolicyError(f"policy {where}: {attr!r} not found{hint}; it must name a callable obs -> action")
        obj = getattr(obj, part)
    return obj


def _check_object(obj: Any, ref: str) -> None:
    if isinstance(obj, (Mapping, np.ndarray)) or callable(obj) or hasattr(obj, "predict"):
        return
    raise PolicyError(f"policy {ref}: is a {type(obj).__name__}, not a callable obs -> action (or 6 probabilities), "
                      "a table or an SB3 model")


def _load_callable(ref: str) -> LoadedPolicy:
    target, attr = ref.rsplit(":", 1)
    if target.endswith(".py"):
        path = Path(target).expanduser()
        if not path.is_file():
            raise PolicyError(f"policy {ref}: no file {target}; {_HELP}")
        root = path.resolve().parent
        with watching(root) as seen:
            obj = _attribute(_import_file(path), attr, ref)
        files: tuple[Path, ...] = (path.resolve(),)
    else:
        root = _package_root(target)
        before = sigints()
        with watching(root or Path.cwd()) as seen:
            try:
                module = importlib.import_module(target)
            except ImportError as exc:
                raise PolicyError(f"policy {ref}: cannot import module {target!r} ({exc}); put it on PYTHONPATH "
                                  "or give the file: path/to/file.py:function") from exc
            except Exception as exc:
                raise PolicyError(f"policy {ref}: module {target!r} failed to import ({type(exc).__name__}: {exc})") from exc
            except (SystemExit, KeyboardInterrupt) as exc:
                if isinstance(exc, KeyboardInterrupt) and sigints() != before:
                    raise
                raise PolicyError(f"policy {ref}: module {target!r} {ended_by(exc)} while it was imported; a policy "
                                  "module must define the policy, not run a program") from exc
        obj = _attribute(module, attr, ref)
        source = getattr(module, "__file__", None)
        files = (Path(source).resolve(),) if source else ()
        if root is None:
            seen = set()  # no package directory found: the module's own file only
    _check_object(obj, ref)
    return LoadedPolicy(ref=ref, kind="callable", policy=obj, files=files, root=root).with_files(seen)


def _package_root(target: str) -> Path | None:
    """The directory of ``target``'s top-level package (or of the top-level module itself), without
    importing it; None when it cannot be found (an import error then says why)."""
    try:
        spec = importlib.util.find_spec(target.split(".")[0])
    except (ImportError, ValueError):
        return None
    if spec is None:
        return None
    if spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations))).resolve()
    return Path(spec.origin).resolve().parent if spec.origin and spec.origin not in ("built-in", "frozen") else None


def _load_model(ref: str, env_ids: Sequence[str], allow_other_env: bool) -> LoadedPolicy:
    path = Path(ref).expanduser()
    if path.is_dir():  # a run's artifact directory (results/runs/<run_id>/) holds model.{zip,json}
        path = path / "model"
    policy = load_model(path)
    if env_ids and read_metadata(path).get("obs_type") == "compact":  # a track fleet's model: see compact_policy
        policy = CompactObservationPolicy(policy, env_ids)
    for env_id in env_ids:
        check_model_env(path, policy, env_id, allow_other_env)
    base = path.with_suffix("") if path.suffix in (".zip", ".json") else path
    files = tuple(p.resolve() for p in (base.with_suffix(".zip"), base.with_suffix(".json")) if p.is_file())
    return LoadedPolicy(ref=ref, kind="model", policy=policy, files=files)


def _is_model_path(ref: str) -> bool:
    path = Path(ref).expanduser()
    if path.is_dir():
        return (path / "model.json").is_file()
    base = path.with_suffix("") if path.suffix in (".zip", ".json") else path
    return base.with_suffix(".json").is_file() or base.with_suffix(".zip").is_file()


def load_policy(ref: Any, env_ids: Sequence[str] = (), allow_other_env: bool = False) -> LoadedPolicy:
    """Resolve ``ref`` (module docstring); a policy object is passed through as a ``callable``.

    ``env_ids``: the envs the policy will run on; a saved model is checked against them (it is
    refused on another env than its own unless ``allow_other_env``, as ``eval`` does).
    """
    if not isinstance(ref, (str, Path)):
        if ref is None:
            return LoadedPolicy(ref=RANDOM, kind="random", policy=RANDOM)
        _check_object(ref, repr(ref))
        return LoadedPolicy(ref=getattr(ref, "__qualname__", type(ref).__name__), kind="callable", policy=ref)
    text = str(ref).strip()
    if text == RANDOM:
        return LoadedPolicy(ref=RANDOM, kind="random", policy=RANDOM)
    if not text:
        raise PolicyError(f"empty policy reference; {_HELP}")
    callable_form = ":" in text and (text.rsplit(":", 1)[0].endswith(".py") or bool(_MODULE_REF.match(text)))
    if callable_form and not Path(text).expanduser().exists():  # checked first: my_rule.py:act is no model
        return _load_callable(text)
    if _is_model_path(text):
        return _load_model(text, env_ids, allow_other_env)
    raise PolicyError(f"policy {text!r} does not exist as a saved model and is not of the form file.py:function or "
                      f"module:function; {_HELP}")


def _cause(exc: BaseException) -> BaseException:
    """The policy's own exception: :class:`~morality_gym.evaluation.policies.PolicyFailure` wraps
    it (the messages here name the policy and the env themselves)."""
    return exc.__cause__ if isinstance(exc, PolicyFailure) and exc.__cause__ is not None else exc


def _described(cause: BaseException) -> str:
    """``KeyError: 'x'``, or ``called sys.exit(0)`` for a policy that tried to end the program."""
    if isinstance(cause, (SystemExit, KeyboardInterrupt)):
        return ended_by(cause)
    return f"{type(cause).__name__}: {cause}"


def in_context(exc: BaseException, ref: str, where: str) -> PolicyError:
    """A failure of the policy ``ref`` during an evaluation (``where``: env, seed) as one line."""
    return PolicyError(f"policy {ref} failed while evaluating {where}: {exc}")


def probe(loaded: LoadedPolicy, env_id: str) -> None:
    """Ask the policy for the first observation of ``env_id``: a policy that raises or returns no
    valid action fails here, with its reference in the message, before any result is written."""
    obs = np.asarray(state_graph(env_id).tables().obs[:1], dtype=np.float64)
    try:
        PolicyAdapter(loaded.policy).probabilities(obs, np.zeros(1, dtype=np.int64))
    except InvalidActionError as exc:
        raise InvalidActionError(f"policy {loaded.ref} on {env_id}: {exc}") from exc
    except Exception as exc:  # noqa: BLE001 - re-raised as PolicyError, from the policy's own exception
        cause = _cause(exc)
        raise PolicyError(f"policy {loaded.ref} failed on the first observation of {env_id} "
                          f"({_described(cause)}); it must map an observation to an action or 6 probabilities") from cause


def is_stationary(loaded: LoadedPolicy, env_id: str) -> bool:
    """Whether the policy's action probabilities are a fixed function of the observation on ``env_id``.

    Exact evaluation assumes it. ``random`` and saved models are (their probabilities are computed
    from the observation alone). A callable is asked for every reachable state's observation
    twice, the second time in reverse order: a policy that samples its answer, counts its calls or
    keeps a memory answers differently (almost surely) and is evaluated by Monte Carlo only.
    """
    if loaded.kind in ("random", "model"):
        return True

    tables = state_graph(env_id).tables()
    ids = np.arange(tables.n_states)
    adapter = PolicyAdapter(loaded.policy)
    try:
        first = adapter.probabilities(tables.obs, ids)
        second = adapter.probabilities(tables.obs[::-1], ids[::-1])[::-1]
    except InvalidActionError as exc:
        raise InvalidActionError(f"policy {loaded.ref} on {env_id}: {exc}") from exc
    except Exception as exc:  # noqa: BLE001 - re-raised as PolicyError, from the policy's own exception
        cause = _cause(exc)
        raise PolicyError(f"policy {loaded.ref} failed on a reachable state of {env_id} "
                          f"({_described(cause)}); it must answer every observation") from cause
    return bool(np.array_equal(first, second))


__all__ = ["RANDOM", "LoadedPolicy", "PolicyError", "in_context", "is_stationary", "load_policy", "probe"]
