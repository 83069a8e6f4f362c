"""Issue 46, item 1: building a leaderboard never runs code found in the results directory.

The build's caches under ``<out>/cache`` (by default inside the results directory, which users copy
from clusters and colleagues) used to be pickles, and ``pickle.load`` of a crafted one runs what it
says. They are JSON now, decoded into plain data and the build's own result types only.
"""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from leaderboard.outputs.paper_figures import FigureSet
from leaderboard.runs.display_order import Group
from leaderboard.web.cache_codec import CacheFormatError, NotEncodable, decode, encode_exact
from leaderboard.web.content_cache import cached_outputs
from tests.leaderboard_data import REPO, make_results


class _Marker:
    """Unpickling this creates a file: the side effect a crafted cache would have."""

    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self) -> tuple[object, tuple[str]]:
        return (os.system, (f"touch {self.path}",))


def _build(results: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "leaderboard.build", "--results", str(results), "--out", str(out),
                           "--site", str(out / "site")], cwd=REPO, capture_output=True, text=True, timeout=600,
                          check=False)


def test_a_crafted_cache_in_the_results_directory_runs_nothing(tmp_path: Path) -> None:
    results = tmp_path / "results"
    make_results(results)
    out = results / "leaderboard"
    assert _build(results, out).returncode == 0
    cache = out / "cache"
    written = sorted(p.name for p in cache.iterdir())
    marker = tmp_path / "ran"
    payload = pickle.dumps({"key": "x", "value": _Marker(str(marker)), "files": {}})
    # the old names and the new ones, each crafted: none may be unpickled
    for stem in ("statistics", "figures", "stat_figures"):
        (cache / f"{stem}.pickle").write_bytes(payload)
        (cache / f"{stem}.json").write_bytes(payload)
    proc = _build(results, out)
    assert proc.returncode == 0, proc.stderr
    assert not marker.exists(), "the build ran code from a cache file"
    assert not any(n.endswith(".pickle") for n in written), written
    line = next(x for x in proc.stdout.splitlines() if x.startswith("cache: "))
    assert "statistics reused" not in line and "statistics, " not in line, line  # recomputed, not trusted
    third = _build(results, out)  # and the JSON it wrote instead is reused
    assert third.returncode == 0
    assert next(x for x in third.stdout.splitlines() if x.startswith("cache: ")).startswith(
        "cache: statistics, figures, statistics figures reused")


def test_a_cache_naming_a_foreign_class_is_not_decoded() -> None:
    for hostile in ({"dataclass": "Popen", "fields": {"args": "touch x"}},
                    {"np": "|O", "v": "x"},
                    {"float": "__import__('os')"},
                    {"frame": {"columns": [], "dtypes": [], "data": [], "index": "nope"}},
                    {"pickle": "gASV"}):
        with pytest.raises(CacheFormatError):
            decode(hostile)


def test_values_come_back_exactly_or_are_not_cached(tmp_path: Path) -> None:
    frame = pd.DataFrame({"a": [1.5, float("nan"), 2.0], "b": ["x", None, "z"], "c": [[1, 2], (3,), np.float64(0.1)],
                          "d": np.array([1, 2, 3], dtype=np.int64), "e": [True, False, True]})
    value = FigureSet(bars={(Group("a", "smoke"), "chain"): Path("f/x.svg")}, learn_errors={"r": "why"})
    for item in (frame, value, {"k": (1, 2.5, float("inf"))}):
        data = json.loads(json.dumps(encode_exact(item), allow_nan=False))
        back = decode(data)
        if isinstance(item, pd.DataFrame):
            pd.testing.assert_frame_equal(back, item)
            assert type(back.loc[2, "c"]) is np.float64 and type(back.loc[1, "c"]) is tuple
        else:
            assert back == item
    with pytest.raises(NotEncodable):
        encode_exact(pd.DataFrame({"t": pd.to_datetime(["2026-01-01"])}))
    # a value that cannot be cached is computed every time, and an older entry does not stand in for it
    path = tmp_path / "entry.json"
    calls = []

    def produce() -> object:
        calls.append(1)
        return object()

    assert cached_outputs(path, "k", produce, lambda _: [])[1] is False
    assert cached_outputs(path, "k", produce, lambda _: [])[1] is False
    assert len(calls) == 2 and not path.exists()
