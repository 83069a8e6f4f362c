"""Frozen dataclasses as OmegaConf/Hydra schemas, and one-line messages for what they refuse.

The configuration's types are the runtime classes themselves (:class:`~.specs.LearnerSpec`,
:class:`~.specs.ProtocolSpec`, the sweep's ``runners.compose.schema``): frozen, so that a resolved run can
never be changed after it was hashed. OmegaConf turns a frozen dataclass into a *read-only* node,
which Hydra cannot override, so :func:`schema` hands OmegaConf a writable copy of the class with
the same fields, types and defaults (generated, not a second class to keep in step), and
:func:`build` turns a merged node back into the frozen class, whose ``__post_init__`` checks the
values a type cannot (ranges, choices).

:func:`explain` rewrites OmegaConf's multi-line errors ("Key 'n_env' not in 'LearnerSpec'" /
"full_key: ..." / "object_type=...") into one line that names the key, where it came from, the
closest valid key and the valid keys; the sweep and the library's loaders both use it.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from functools import cache
from typing import Any

from morality_gym.clitools import did_you_mean


def _writable_type(tp: Any) -> Any:
    """``tp`` with every frozen dataclass replaced by its writable schema and abstract containers
    (``Mapping``, ``tuple[...]``) spelt the way OmegaConf understands them."""
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return schema(tp)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is None:
        return tp
    if origin in (Mapping, dict, typing.Mapping):
        key, value = args or (str, Any)
        return typing.Dict[key, _writable_type(value)]  # noqa: UP006 - OmegaConf reads typing's generics
    if origin in (list, typing.List):  # noqa: UP006
        return typing.List[_writable_type(args[0])]  # noqa: UP006
    if origin is tuple:
        return typing.Tuple[tuple(_writable_type(a) for a in args)]  # noqa: UP006
    if origin in (typing.Union, types.UnionType):
        return typing.Union[tuple(_writable_type(a) for a in args)]  # noqa: UP007 - built from a tuple
    return tp


@cache
def schema(cls: type) -> type:
    """A writable dataclass with ``cls``'s fields, types and defaults (OmegaConf's schema for it).

    It keeps ``cls``'s name, so that OmegaConf's messages name the class the user knows."""
    hints = typing.get_type_hints(cls)
    fields = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        if f.default is not dataclasses.MISSING:
            spec: Any = dataclasses.field(default=_writable_value(f.default))
        elif f.default_factory is not dataclasses.MISSING:
            factory = f.default_factory
            spec = dataclasses.field(default_factory=lambda factory=factory: _writable_value(factory()))
        else:
            spec = dataclasses.field()
        fields.append((f.name, _writable_type(hints[f.name]), spec))
    return dataclasses.make_dataclass(cls.__name__, fields, namespace={"__doc__": cls.__doc__, "__module__": cls.__module__})


def _writable_value(value: Any) -> Any:
    """A default value as OmegaConf may hold it writable: a frozen dataclass instance becomes an
    instance of its schema."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return schema(type(value))(**{f.name: _writable_value(getattr(value, f.name)) for f in dataclasses.fields(value)})
    return value


def _omegaconf() -> Any:
    """The ``omegaconf`` package, imported when first needed, in this one place: it costs ~80 ms,
    and readers of presets (the leaderboard's ``--help``) import this module without using it."""
    import omegaconf  # OmegaConf waits (see the docstring)

    return omegaconf


class TypedConfigError(ValueError):
    """A value or key the schema refuses; the message is one line (see :func:`explain`)."""


def valid_keys(cls: type) -> list[str]:
    return [f.name for f in dataclasses.fields(cls) if f.init]


def hint(word: str, choices: list[str]) -> str:
    return did_you_mean(word, choices)


def explain(exc: BaseException, where: str = "", schemas: Mapping[str, type] | None = None) -> str:
    """One line for an OmegaConf/Hydra error: the key (full path), ``where`` it came from, what is
    wrong, and for an unknown key the closest valid key and the valid keys.

    ``schemas`` maps an OmegaConf ``object_type`` name to its class, for the list of valid keys.
    """
    errors = _omegaconf().errors
    cause: BaseException | None = exc
    while cause is not None and not isinstance(cause, errors.OmegaConfBaseException):
        cause = cause.__cause__ or cause.__context__
    if cause is None:
        return " ".join(str(exc).split())
    full_key = str(getattr(cause, "full_key", "") or "")
    msg = str(cause).splitlines()[0].strip() if str(cause) else type(cause).__name__
    prefix = f"{full_key}" + (f" ({where})" if where else "")
    if isinstance(cause, errors.ConfigKeyError) or "not in" in msg or "is not in struct" in msg:
        key = str(getattr(cause, "key", None) or full_key.rsplit(".", 1)[-1])
        keys = _schema_keys(getattr(cause, "object_type", None), schemas)
        valid = f"; valid keys: {', '.join(keys)}" if keys else ""
        return f"{prefix}: unknown key {key!r}{hint(key, keys)}{valid}"
    msg = msg.replace("Value '", "value '")
    return f"{prefix}: {msg}"


def _schema_keys(object_type: Any, schemas: Mapping[str, type] | None) -> list[str]:
    """The valid keys of the node an unknown key was set on: its dataclass's, else the schema's of that name."""
    cls = None
    if object_type is not None and dataclasses.is_dataclass(object_type):
        cls = object_type
    if cls is None and schemas and object_type is not None:
        cls = schemas.get(getattr(object_type, "__name__", str(object_type)))
    return valid_keys(cls) if cls is not None else []


def merge(cls: type, *layers: Any, where: str = "") -> Any:
    """The layers (mappings, lowest first) merged over ``cls``'s schema: an OmegaConf node, typed."""
    omegaconf = _omegaconf()
    node = omegaconf.OmegaConf.structured(schema(cls))
    try:
        for layer in layers:
            if layer:
                node = omegaconf.OmegaConf.merge(node, layer)
    except omegaconf.errors.OmegaConfBaseException as exc:
        raise TypedConfigError(explain(exc, where)) from exc
    return node


def build(cls: type, node: Any, where: str = "", **extra: Any) -> Any:
    """The frozen ``cls`` from a merged node (its ``__post_init__`` checks the values); a required
    field left unset is named."""
    omegaconf = _omegaconf()
    try:
        values = omegaconf.OmegaConf.to_container(node, resolve=True, throw_on_missing=True)
    except omegaconf.errors.MissingMandatoryValue as exc:
        key = str(getattr(exc, "full_key", "") or "?")
        raise TypedConfigError(f"{key}{f' ({where})' if where else ''}: required, and not set") from exc
    assert isinstance(values, dict)
    return from_plain(cls, {**values, **extra})


def from_plain(cls: type, values: Mapping[str, Any]) -> Any:
    """``cls(**values)`` with lists turned into the tuples its fields declare (recursively for
    nested dataclasses), so that a value read from YAML equals the value written in Python."""
    hints = typing.get_type_hints(cls)
    out = {}
    for key, value in values.items():
        tp = hints.get(key)
        out[key] = _coerce(tp, value)
    return cls(**out)


def _coerce(tp: Any, value: Any) -> Any:
    if value is None or tp is None:
        return value
    if dataclasses.is_dataclass(tp) and isinstance(tp, type) and isinstance(value, Mapping):
        return from_plain(tp, value)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is tuple and isinstance(value, (list, tuple)):
        return tuple(value)
    if origin in (typing.Union, types.UnionType):
        for arg in args:
            if arg is not type(None):
                return _coerce(arg, value)
    if origin in (Mapping, dict) and isinstance(value, Mapping) and len(args) == 2:
        return {k: _coerce(args[1], v) for k, v in value.items()}
    return value
