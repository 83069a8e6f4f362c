"""The build caches' values as JSON: data that is read back, never code that is run.

Why not pickle: the caches live under ``<out>/cache``, and ``<out>`` is by default inside the
results directory, which users copy from clusters and colleagues. ``pickle.load`` of a crafted file
runs whatever the file says (``os.system`` included), so a cached value is written as plain JSON
with a few tags (a tuple, a path, a NumPy scalar, a data frame, one of the :data:`DATACLASSES`
below) and read back by a decoder that builds only those types. Anything else in a file is
an error, and the cache entry is computed afresh.

A value that does not survive the trip exactly (a frame with a dtype the encoder cannot restore,
an unknown object) is not cached at all: :func:`encode_exact` says so, and the build computes it
again next time rather than reusing something that differs from what it computed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from leaderboard.outputs.paper_figures import FigureSet
from leaderboard.outputs.stats_figures import StatFigures
from leaderboard.runs.display_order import Group
from leaderboard.stats import LeaderboardStats

#: The only classes a cache file may name: the values the build's cached stages return.
DATACLASSES: dict[str, type] = {cls.__name__: cls for cls in (LeaderboardStats, FigureSet, StatFigures, Group)}

#: NumPy scalar kinds a cache holds: booleans and numbers (an object or string scalar is not data we restore).
NUMERIC_KINDS = "biufc"


class CacheFormatError(ValueError):
    """A cache file that is not one this module wrote (damaged, hand-made or from another version)."""


class NotEncodable(TypeError):
    """A value this codec cannot restore exactly, so it is not cached."""


def _float(value: float) -> Any:
    """A float as JSON: finite ones as they are (``json`` writes them exactly), the rest tagged."""
    return value if math.isfinite(value) else {"float": repr(value)}


def encode(value: Any) -> Any:
    """``value`` as JSON-ready data; :class:`NotEncodable` for a type the decoder would not rebuild.

    JSON's own types go as they are (exact types only: a subclass of ``int`` or ``dict`` may
    behave differently and is not restored); everything else is a one-key tagged object."""
    if value is None or isinstance(value, (bool, str)) or type(value) is int:
        return value
    if type(value) is float:
        return _float(value)
    if isinstance(value, np.generic):
        return _encode_numpy_scalar(value)
    if isinstance(value, list):
        return [encode(v) for v in value]
    return _encode_tagged(value)


def _encode_numpy_scalar(value: np.generic) -> dict[str, Any]:
    if value.dtype.kind not in NUMERIC_KINDS:
        raise NotEncodable(f"a NumPy {value.dtype} scalar is not cached")
    return {"np": value.dtype.str, "v": encode(value.item())}


def _encode_tagged(value: Any) -> dict[str, Any]:
    """A tuple, dict, path, data frame or one of the :data:`DATACLASSES` as its tagged object."""
    if type(value) is tuple:
        return {"tuple": [encode(v) for v in value]}
    if type(value) is dict:
        return {"dict": [[encode(k), encode(v)] for k, v in value.items()]}
    if isinstance(value, Path):
        return {"path": str(value)}
    if isinstance(value, pd.DataFrame):
        return {"frame": _encode_frame(value)}
    if dataclasses.is_dataclass(value) and DATACLASSES.get(type(value).__name__) is type(value):
        return {"dataclass": type(value).__name__,
                "fields": {f.name: encode(getattr(value, f.name)) for f in dataclasses.fields(value)}}
    raise NotEncodable(f"a {type(value).__module__}.{type(value).__qualname__} is not cached")


def _encode_frame(frame: pd.DataFrame) -> dict[str, Any]:
    return {"columns": _encode_index(frame.columns),
            "dtypes": [str(t) for t in frame.dtypes],
            "data": [[encode(v) for v in _values(frame.iloc[:, i])] for i in range(frame.shape[1])],
            "index": _encode_index(frame.index)}


def _encode_index(index: pd.Index) -> dict[str, Any]:
    if isinstance(index, pd.RangeIndex):
        return {"range": [index.start, index.stop, index.step], "name": encode(index.name)}
    return {"dtype": str(index.dtype), "name": encode(index.name), "values": [encode(v) for v in index.tolist()]}


def _decode_index(spec: Any) -> pd.Index:
    if not isinstance(spec, dict):
        raise CacheFormatError("a frame without an index in a cache file")
    if "range" in spec:
        start, stop, step = (int(v) for v in _list(spec["range"]))
        return pd.RangeIndex(start, stop, step, name=decode(spec["name"]))
    return pd.Index([decode(v) for v in _list(spec["values"])], dtype=_text(spec["dtype"]), name=decode(spec["name"]))


def _values(column: pd.Series) -> list[Any]:
    """A column's values as they are stored: Python scalars of a typed column, the objects themselves of an object one."""
    return list(column.to_numpy()) if column.dtype == object else column.tolist()


def decode(data: Any) -> Any:
    """The value :func:`encode` made ``data`` from; :class:`CacheFormatError` for anything else."""
    if data is None or isinstance(data, (bool, str, int, float)):
        return data
    if isinstance(data, list):
        return [decode(v) for v in data]
    if not isinstance(data, dict) or len(data) not in (1, 2):
        raise CacheFormatError(f"unexpected {type(data).__name__} in a cache file")
    tag = next(iter(data))
    keys, decoder = _TAGGED.get(tag, (0, None))
    if decoder is None or len(data) != keys:
        raise CacheFormatError(f"unknown tag {tag!r} in a cache file")
    try:
        return decoder(data)
    except CacheFormatError:
        raise
    except (TypeError, ValueError, KeyError) as exc:
        raise CacheFormatError(f"a damaged {tag!r} entry in a cache file ({exc})") from exc


def _decode_numpy_scalar(data: dict[str, Any]) -> np.generic:
    dtype = np.dtype(_text(data["np"]))
    if dtype.kind not in NUMERIC_KINDS:
        raise CacheFormatError(f"a NumPy scalar of dtype {dtype} in a cache file")
    return dtype.type(decode(data["v"]))


def _decode_dataclass(data: dict[str, Any]) -> Any:
    """One of :data:`DATACLASSES`, by name: the only classes a cache file may make the decoder build."""
    cls = DATACLASSES.get(_text(data["dataclass"]))
    if cls is None:
        raise CacheFormatError(f"unknown class {data['dataclass']!r} in a cache file")
    fields = data["fields"]
    if not isinstance(fields, dict):
        raise CacheFormatError("a dataclass without fields in a cache file")
    return cls(**{str(k): decode(v) for k, v in fields.items()})


#: Each tag :func:`encode` writes: how many keys its object has, and how it is read back.
_TAGGED: dict[str, tuple[int, Callable[[dict[str, Any]], Any]]] = {
    "float": (1, lambda data: float(_text(data["float"], ("nan", "inf", "-inf")))),
    "np": (2, _decode_numpy_scalar),
    "tuple": (1, lambda data: tuple(decode(v) for v in _list(data["tuple"]))),
    "dict": (1, lambda data: {decode(k): decode(v) for k, v in (_pair(p) for p in _list(data["dict"]))}),
    "path": (1, lambda data: Path(_text(data["path"]))),
    "frame": (1, lambda data: _decode_frame(data["frame"])),
    "dataclass": (2, _decode_dataclass),
}


def _text(value: Any, allowed: tuple[str, ...] | None = None) -> str:
    if not isinstance(value, str) or (allowed is not None and value not in allowed):
        raise CacheFormatError(f"unexpected {value!r} in a cache file")
    return value


def _list(value: Any) -> list[Any]:
    if not isinstance(value, list):
        raise CacheFormatError(f"expected a list in a cache file, got {type(value).__name__}")
    return value


def _pair(value: Any) -> tuple[Any, Any]:
    if not isinstance(value, list) or len(value) != 2:
        raise CacheFormatError("a damaged mapping entry in a cache file")
    return value[0], value[1]


def _decode_frame(data: Any) -> pd.DataFrame:
    if not isinstance(data, dict):
        raise CacheFormatError("a damaged frame in a cache file")
    columns = _decode_index(data["columns"])
    dtypes = [_text(t) for t in _list(data["dtypes"])]
    values = _list(data["data"])
    if not len(columns) == len(dtypes) == len(values):
        raise CacheFormatError("a frame whose columns, dtypes and data disagree in a cache file")
    index = _decode_index(data["index"])
    series = {}
    for i, (dtype, column) in enumerate(zip(dtypes, values, strict=True)):
        items = [decode(v) for v in _list(column)]
        if len(items) != len(index):
            raise CacheFormatError("a frame column of the wrong length in a cache file")
        if dtype == "object":
            array = np.empty(len(items), dtype=object)
            array[:] = items if items else []
            series[i] = pd.Series(array, index=index, dtype=object)
        else:
            series[i] = pd.Series(items, index=index, dtype=dtype)
    frame = pd.DataFrame(series, index=index)
    frame.columns = columns
    return frame


def same(a: Any, b: Any) -> bool:
    """Whether ``a`` and ``b`` are equal with the same types all the way down (NaN equals NaN).

    Stricter than ``==``: a cached value must be indistinguishable from the computed one, so
    ``1`` and ``1.0``, a list and a tuple, or ``float64`` and ``object`` columns count as different."""
    if type(a) is not type(b):
        return False
    if isinstance(a, pd.DataFrame):
        return _same_frame(a, b)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict):
        return list(a.keys()) == list(b.keys()) and all(same(k, l) and same(a[k], b[l]) for k, l in zip(a, b, strict=True))
    if dataclasses.is_dataclass(a):
        return all(same(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a))
    if isinstance(a, (float, np.floating)) and math.isnan(a):
        return bool(math.isnan(b))
    try:
        return bool(a == b)
    except (TypeError, ValueError):
        return False


def _same_frame(a: pd.DataFrame, b: pd.DataFrame) -> bool:
    """Same shape, labels, dtypes and values, column by column."""
    return (a.shape == b.shape and _same_index(a.columns, b.columns) and _same_index(a.index, b.index)
            and list(map(str, a.dtypes)) == list(map(str, b.dtypes))
            and all(same(list(a.iloc[:, i].to_numpy()), list(b.iloc[:, i].to_numpy())) for i in range(a.shape[1])))


def _same_index(a: pd.Index, b: pd.Index) -> bool:
    return (type(a) is type(b) and str(a.dtype) == str(b.dtype) and same(a.name, b.name)
            and same(list(a), list(b)))


def encode_exact(value: Any) -> Any:
    """:func:`encode` of ``value``, checked to decode to the very same value; :class:`NotEncodable` if not."""
    data = encode(value)
    try:
        ok = same(decode(data), value)
    except CacheFormatError as exc:
        raise NotEncodable(str(exc)) from exc
    if not ok:
        raise NotEncodable(f"a {type(value).__name__} does not come back exactly from its JSON form")
    return data
