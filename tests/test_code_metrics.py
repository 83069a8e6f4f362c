"""benchmarks.code_metrics counts what issues 23 and 50 say it counts."""

from __future__ import annotations

from pathlib import Path

from benchmarks.code_metrics import LIST_ABOVE, inner_imports, inner_own_imports, listing, markdown, measure

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


OWN = '''
def lazy():
    import torch  # a heavy optional package: not the project's own
    from pkg import mod  # the project's own
    from . import sibling  # relative: always the project's own
    import pkg.mod as m2, json
    return torch, mod, sibling, m2, json
'''


def test_own_imports_and_functions_above_fifteen_are_counted(tmp_path: Path) -> None:
    (tmp_path / "pkg").mkdir()
    path = tmp_path / "pkg" / "own.py"
    # 1 + one per if: LIST_ABOVE ifs make the first figure above LIST_ABOVE
    branches = "".join(f"    if x == {i}:\n        return {i}\n" for i in range(LIST_ABOVE))
    path.write_text(OWN + f"\n\ndef very_branchy(x):\n{branches}    return -1\n")
    assert inner_imports(path) == 4 and inner_own_imports(path, ("pkg",)) == 3
    m = measure(tmp_path, ("pkg",))
    assert m.inner_own_imports == 3
    assert m.listed == ((LIST_ABOVE + 1, "pkg/own.py::very_branchy"),)
    assert listing(m).split() == [str(LIST_ABOVE + 1), "pkg/own.py::very_branchy"]
    table = markdown([m])
    assert f"functions above {LIST_ABOVE} | 1 |" in table and "of the project's own modules | 3 |" in table
