"""benchmarks.code_metrics counts what issue 23's table says it counts."""

from __future__ import annotations

from pathlib import Path

from benchmarks.code_metrics import inner_imports, markdown, measure

SOURCE = '''
import os


def plain():
    return os.sep


def branchy(x):
    import json  # one inside a function
    if x > 1:
        return 1
    for i in range(x):
        if i:
            def inner():
                from math import pi  # nested: still counted once
                return pi
            return inner
    return 0


class Thing:
    def method(self, y):
        return 1 if y else 2
'''


def test_measure_counts_functions_complexity_and_inner_imports(tmp_path: Path) -> None:
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "mod.py").write_text(SOURCE)
    m = measure(tmp_path, ("pkg",))
    # radon: plain 1, branchy 1 + if + for + if = 4, inner 1, method 1 + conditional expression = 2
    assert m.highest == 4 and m.highest_name.endswith("::branchy")
    assert m.above_threshold == 0
    assert m.inner_imports == 2 == inner_imports(tmp_path / "pkg" / "mod.py")
    assert m.inner_imports_by_package == {"pkg": 2}
    assert "imports inside functions | 2 |" in markdown([m])
