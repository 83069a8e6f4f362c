"""Check a learner's hyper-parameters before anything runs.

A typo or an impossible value in a sweep's configuration used to pass validation and fail every
run of the sweep at model construction (on SLURM: a whole job array burnt). Here every
hyper-parameter is checked against what will consume it, without building an environment:

* the key must be a parameter of the algorithm class's constructor (``inspect.signature``, so a
  parameter added to a class is accepted without touching this module), and not one the runner
  sets itself (``seed``, ``device``, ``policy_kwargs``, ...); an unknown key gets a did-you-mean;
* the value must have the type the constructor's annotation asks for (``Literal`` choices
  included) and lie in the range that makes sense for it (:data:`RANGES`, by parameter name:
  ``learning_rate > 0``, ``batch_size >= 2``, ``0 <= gamma <= 1``, ...);
* the spec fields outside ``hparams`` (``net_arch``, ``n_envs``, ``cost_scale``, ``return_bounds``)
  are checked by :func:`validate_learner`.

Left to the algorithm (it raises when the model is built): constraints between several values,
e.g. SB3's ``n_steps * n_envs > 1``. Entry point for configuration layers:
:func:`validate_hparams` (one algorithm's ``hparams`` mapping) and :func:`validate_learner`.
"""

from __future__ import annotations

import inspect
import math
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cache
from typing import Any

from morality_gym.baselines.specs import LearnerSpec, SpecError
from morality_gym.baselines.targets import TargetError, resolve
from morality_gym.clitools import did_you_mean


class HyperParameterError(SpecError):
    """A hyper-parameter that cannot work; the message names the learner, the key and the fix."""


#: Constructor parameters the runner sets itself (a value in ``hparams`` would clash or be ignored).
RESERVED = frozenset({"policy", "env", "seed", "device", "verbose", "policy_kwargs", "tensorboard_log",
                      "_init_setup_model", "rollout_buffer_class", "rollout_buffer_kwargs", "monitor_wrapper"})


@dataclass(frozen=True)
class Range:
    """``low <= value <= high`` (``*_open``: strict), with the reason a user reads when it fails."""

    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    high_open: bool = False

    def holds(self, value: float) -> bool:
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def describe(self) -> str:
        parts = []
        if self.low != -math.inf:
            parts.append(f"{'>' if self.low_open else '>='} {self.low:g}")
        if self.high != math.inf:
            parts.append(f"{'<' if self.high_open else '<='} {self.high:g}")
        return " and ".join(parts)


_POSITIVE = Range(0.0, low_open=True)
_NON_NEGATIVE = Range(0.0)
_AT_LEAST_ONE = Range(1.0)
_UNIT = Range(0.0, 1.0)

#: Sane values by parameter name (any algorithm that has the parameter).
RANGES: dict[str, Range] = {
    "n_steps": _AT_LEAST_ONE,
    "steps_per_rollout": _AT_LEAST_ONE,
    "batch_size": Range(2.0),  # advantages are normalised per minibatch: one sample has no spread
    "n_epochs": _AT_LEAST_ONE,
    "n_critic_updates": _AT_LEAST_ONE,
    "cg_max_steps": _AT_LEAST_ONE,
    "line_search_max_iter": _AT_LEAST_ONE,
    "ep_cost_window": _AT_LEAST_ONE,
    "stats_window_size": _AT_LEAST_ONE,
    "sde_sample_freq": Range(-1.0),
    "learning_rate": _POSITIVE,
    "critic_learning_rate": _POSITIVE,
    "clip_range": _POSITIVE,
    "clip_range_vf": _POSITIVE,
    "max_grad_norm": _POSITIVE,
    "target_kl": _POSITIVE,
    "lagrange_lr": _POSITIVE,
    "cg_damping": _NON_NEGATIVE,
    "ent_coef": _NON_NEGATIVE,
    "vf_coef": _NON_NEGATIVE,
    "critic_l2_coef": _NON_NEGATIVE,
    "cost_limit": _NON_NEGATIVE,
    "lagrange_init": _NON_NEGATIVE,
    "lagrange_upper_bound": _POSITIVE,
    "gamma": _UNIT,
    "gae_lambda": _UNIT,
    "cost_gamma": _UNIT,
    "cost_gae_lambda": _UNIT,
    "line_search_shrinking_factor": Range(0.0, 1.0, low_open=True, high_open=True),
}


def algorithm_class(target: str) -> type:
    """The class a learner's ``_target_`` names (imported; :class:`TargetError` if it cannot be)."""
    return resolve(target)


@cache
def accepted_hparams(target: str) -> dict[str, inspect.Parameter]:
    """The constructor parameters a sweep may set for the class at ``target``.

    An SB3 algorithm (the baselines', or any user's) takes its ``hparams`` as constructor
    arguments, so its signature is the list; a self-driving learner class (the random baseline)
    takes none.
    """
    # torch waits: importing morality_gym.baselines.hparams must not load it
    from stable_baselines3.common.base_class import BaseAlgorithm

    cls = algorithm_class(target)
    if not issubclass(cls, BaseAlgorithm):
        return {}
    accepted: dict[str, inspect.Parameter] = {}
    for klass in cls.__mro__:  # a subclass's ``**kwargs`` passes the rest on to its base class
        if "__init__" not in vars(klass):
            continue
        try:
            signature = inspect.signature(klass.__init__, eval_str=True)
        except (NameError, TypeError):  # an annotation that cannot be evaluated: keep them as strings
            signature = inspect.signature(klass.__init__)
        for name, p in signature.parameters.items():
            if name not in RESERVED and name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
                accepted.setdefault(name, p)
        if not any(p.kind is p.VAR_KEYWORD for p in signature.parameters.values()) or klass is BaseAlgorithm:
            break
    return accepted


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _kinds(annotation: Any) -> tuple[set[str], tuple[Any, ...]]:
    """What an annotation accepts: a set of kinds among bool/int/float/str/none/other, and Literal choices."""
    if annotation is inspect.Parameter.empty or isinstance(annotation, str):
        return {"other"}, ()
    origin = typing.get_origin(annotation)
    if origin is typing.Literal:
        return {"literal"}, typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        kinds: set[str] = set()
        choices: tuple[Any, ...] = ()
        for arg in typing.get_args(annotation):
            k, c = _kinds(arg)
            kinds |= k
            choices += c
        return kinds, choices
    if annotation is type(None):
        return {"none"}, ()
    if annotation in (bool, int, float, str):
        return {annotation.__name__}, ()
    if origin is not None and getattr(origin, "__name__", "") == "Callable" or annotation is Callable:
        return {"callable"}, ()
    return {"other"}, ()


def _type_problem(value: Any, parameter: inspect.Parameter) -> str | None:
    """Why ``value`` does not fit the parameter's annotation (None if it fits or cannot be judged)."""
    kinds, choices = _kinds(parameter.annotation)
    if "other" in kinds:
        return None
    if value is None:
        return None if "none" in kinds else "must not be null"
    if "literal" in kinds and value in choices:
        return None
    if isinstance(value, bool):  # before the numbers: YAML's true is an int to Python
        return None if "bool" in kinds else "expected a number, got true/false"
    if _fits_scalar(value, kinds):
        return "must be a finite number" if isinstance(value, float) and not math.isfinite(value) else None
    return f"expected {_expected(kinds, choices)}, got {value!r}"


def _expected(kinds: set[str], choices: tuple[Any, ...]) -> str:
    """What an annotation of ``kinds`` (and literal ``choices``) accepts, in words."""
    expected = [k for k in ("bool", "int", "float", "str") if k in kinds]
    if "literal" in kinds:
        expected.append("one of " + ", ".join(repr(c) for c in choices))
    return " or ".join(expected) or "another value"


def _fits_scalar(value: Any, kinds: set[str]) -> bool:
    """An int where an int or float is accepted, a float where a float is, a string where a string is."""
    if isinstance(value, int):
        return bool(kinds & {"int", "float"})
    if isinstance(value, float):
        return "float" in kinds
    return isinstance(value, str) and "str" in kinds


def validate_hparams(algo_name: str, target: str, hparams: Mapping[str, Any]) -> None:
    """Raise :class:`HyperParameterError` for the first hyper-parameter that cannot work.

    ``algo_name`` is only used in the message (``ppo_shaped``, ``cpo``, ...); ``target`` names the
    class whose constructor receives ``hparams``.
    """
    where = f"learner {algo_name!r}"
    try:
        accepted = accepted_hparams(target)
    except TargetError as exc:
        raise HyperParameterError(f"{where}: {exc}") from exc
    for key, value in hparams.items():
        if key in RESERVED:
            raise HyperParameterError(f"{where}: hparams.{key} is set by the runner, not by the configuration; remove it")
        if key not in accepted:
            if not accepted:
                raise HyperParameterError(f"{where}: hparams.{key}: {target} takes no hyper-parameters; remove it")
            hint = did_you_mean(key, accepted)
            cls = algorithm_class(target).__name__
            raise HyperParameterError(f"{where}: hparams.{key} is not a hyper-parameter of {cls}{hint}; "
                                      f"valid: {', '.join(sorted(accepted))}")
        problem = _type_problem(value, accepted[key])
        if problem is None and _is_number(value) and key in RANGES:
            if not math.isfinite(float(value)):
                problem = "must be a finite number"
            elif not RANGES[key].holds(float(value)):
                problem = f"must be {RANGES[key].describe()}"
        if problem is not None:
            default = accepted[key].default
            like = f" (default {default!r})" if default is not inspect.Parameter.empty else ""
            raise HyperParameterError(f"{where}: hparams.{key}={value!r}: {problem}{like}")


def validate_learner(spec: LearnerSpec) -> None:
    """Check the spec's own fields (network, reward and cost settings), then its ``hparams``.

    The checklist is the tuple below, one check per field in the order of the config file, each a
    function with its own message: the first problem found is the one reported.
    """
    for problem in (_net_arch_problem(spec.net_arch), _cost_scale_problem(spec.cost_scale),
                    _return_bounds_problem(spec.return_bounds)):
        if problem is not None:
            raise HyperParameterError(f"learner {spec.name!r}: {problem}")
    validate_hparams(spec.name, spec.target, spec.hparams)


def _shown(value: Any) -> str:
    """A list-like setting as the user wrote it (a list), anything else as its repr."""
    return str(list(value)) if isinstance(value, (tuple, list)) else repr(value)


def _net_arch_problem(arch: Any) -> str | None:
    """``net_arch``: a non-empty list of layer sizes, each an integer >= 1."""
    if isinstance(arch, (tuple, list)) and arch and all(isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in arch):
        return None
    return f"net_arch={_shown(arch)}: expected a non-empty list of layer sizes, each an integer >= 1 (e.g. [64, 64])"


def _cost_scale_problem(scale: Any) -> str | None:
    """``cost_scale``: a finite number >= 0."""
    if _is_number(scale) and math.isfinite(scale) and scale >= 0:
        return None
    return f"cost_scale={scale!r}: must be a finite number >= 0"


def _return_bounds_problem(bounds: Any) -> str | None:
    """``return_bounds``: ``[low, high]``, two finite numbers, low < high."""
    if (isinstance(bounds, (tuple, list)) and len(bounds) == 2 and all(_is_number(b) and math.isfinite(b) for b in bounds)
            and bounds[0] < bounds[1]):
        return None
    return f"return_bounds={_shown(bounds)}: expected [low, high] with low < high"
