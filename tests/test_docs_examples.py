"""Every code block of the documentation site and the README runs, so a stale example fails CI.

The collector reads the fenced blocks of ``README.md`` and ``docs/**/*.md`` (the generated pages
are made from the code and hold no examples):

* ```` ```python ```` blocks run by default, in order, one namespace per page (a later block may
  use what an earlier one defined), in a process of the page's own (examples register scenarios
  and set environment variables) with its working directory in a fresh temporary folder;
* ```` ```bash ```` (or ``sh``/``console``) blocks run when the line before the fence is
  ``<!-- run -->``: each line is a command run by bash in that page's folder, with the checkout
  importable and ``python`` being this interpreter;
* a python block titled with a file name (```` ```python title="my_rule.py" ````) is also written
  to that file in the page's folder, for the commands after it;
* a python or bash block whose fence carries ``title="Not run: REASON"`` (shown above the block on
  the site, so the reader sees it too) is skipped with that reason; every other bash block must
  be marked one way or the other, so no example is left unchecked by accident.

Other languages (yaml, text, ...) are data or output and are not run.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FENCE = re.compile(r"^(?P<indent>[ \t]*)(?P<ticks>`{3,})(?P<info>[^`\n]*)\n(?P<body>.*?)^(?P=indent)(?P=ticks)[ \t]*$",
                   re.MULTILINE | re.DOTALL)
NOT_RUN = re.compile(r'title="Not run: ([^"]+)"')
FILE_TITLE = re.compile(r'title="([\w.-]+\.py)"')
RUN_MARK = "<!-- run -->"
SHELLS = {"bash", "sh", "shell", "console"}


@dataclass(frozen=True)
class Block:
    page: str
    line: int
    lang: str
    code: str
    skip: str | None  # the reason, when marked not to run
    run: bool  # a shell block marked to run
    file: str | None = None  # a python block titled with a file name is also written to that file

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"


def pages() -> list[Path]:
    return [ROOT / "README.md", *sorted(p for p in (ROOT / "docs").rglob("*.md") if "_hooks" not in p.parts)]


def blocks(path: Path) -> list[Block]:
    text = path.read_text()
    out = []
    for m in FENCE.finditer(text):
        info = m.group("info").strip()
        lang = info.split()[0].lower() if info else ""
        if lang not in SHELLS | {"python", "py"}:
            continue
        line = text.count("\n", 0, m.start()) + 1
        before = text[: m.start()].rstrip("\n").rsplit("\n", 1)[-1].strip()
        skip = NOT_RUN.search(info)
        body = "\n".join(l[len(m.group("indent")):] for l in m.group("body").splitlines())
        named = FILE_TITLE.search(info)
        out.append(Block(str(path.relative_to(ROOT)), line, "python" if lang in ("python", "py") else "bash",
                         body, skip.group(1) if skip else None, before == RUN_MARK, named.group(1) if named else None))
    return out


ALL = [b for p in pages() for b in blocks(p)]
PAGES_WITH_CODE = sorted({b.page for b in ALL if b.skip is None and (b.lang == "python" or b.run)})
#: Pages whose examples train (a few thousand steps, tens of seconds): marked slow, like the learning tests.
TRAINS = {"docs/how-to/own-algorithm.md"}


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    env["MPLBACKEND"] = "Agg"
    env["MORALITY_GYM_DOCS_TEST"] = "1"
    return env


def _link_venv(folder: Path) -> None:
    """``folder/.venv``: the environment the Makefile makes, so that commands written for a fresh shell
    at the repository's root (``.venv/bin/python -m ...``, issue 36) run as written: the checkout's
    ``.venv`` if it has one, else this interpreter's virtual environment, else a ``bin/python`` link to it."""
    venv = ROOT / ".venv"
    if not venv.is_dir() and sys.prefix != sys.base_prefix:
        venv = Path(sys.prefix)
    if venv.is_dir():
        (folder / ".venv").symlink_to(venv, target_is_directory=True)
        return
    (folder / ".venv" / "bin").mkdir(parents=True)
    (folder / ".venv" / "bin" / "python").symlink_to(sys.executable)


def test_every_shell_block_is_marked() -> None:
    """A bash block either runs (``<!-- run -->`` above it) or says why not (``title="Not run: ..."``)."""
    unmarked = [b.where for b in ALL if b.lang == "bash" and not b.run and b.skip is None]
    assert not unmarked, f"mark these bash blocks <!-- run --> or title=\"Not run: REASON\": {unmarked}"
    assert len(PAGES_WITH_CODE) >= 8, PAGES_WITH_CODE


#: Runs a page's python blocks in order in one namespace, in a process of its own: examples register
#: scenarios, set MORALITY_GYM_SCENARIOS and write files, which must not leak into the other tests.
DRIVER = """
import json, sys
namespace = {"__name__": "__main__"}
for where, code in json.load(open(sys.argv[1])):
    print(f"--- {where}", flush=True)
    exec(compile(code, where, "exec"), namespace)
"""


@pytest.mark.parametrize("page", [pytest.param(p, marks=pytest.mark.slow) if p in TRAINS else p for p in PAGES_WITH_CODE])
def test_page_examples_run(page: str, tmp_path: Path) -> None:
    """The page's python blocks in one namespace, then its marked bash blocks, in its own folder."""
    runnable = [b for b in ALL if b.page == page and b.skip is None]
    for block in runnable:
        if block.file:  # e.g. my_rule.py, which the page's commands then name
            (tmp_path / block.file).write_text(block.code + "\n")
    python = [(b.where, b.code) for b in runnable if b.lang == "python"]
    if python:
        (tmp_path / ".blocks.json").write_text(json.dumps(python))
        proc = subprocess.run([sys.executable, "-c", DRIVER, ".blocks.json"], cwd=tmp_path, env=_env(),
                              capture_output=True, text=True, timeout=600, check=False)
        assert proc.returncode == 0, f"an example of {page} fails (the last --- line names it):\n{proc.stdout}\n{proc.stderr}"
    bash = [b for b in runnable if b.lang == "bash" and b.run]
    if bash:
        _link_venv(tmp_path)
    for block in bash:
        proc = subprocess.run(["bash", "-euo", "pipefail", "-c", block.code], cwd=tmp_path, env=_env(),
                              capture_output=True, text=True, timeout=300, check=False)
        assert proc.returncode == 0, f"the commands at {block.where} fail:\n{block.code}\n{proc.stdout}\n{proc.stderr}"


@pytest.mark.parametrize("block", [b for b in ALL if b.skip is not None], ids=lambda b: b.where)
def test_illustrations_say_why_they_are_not_run(block: Block) -> None:
    pytest.skip(f"{block.where}: {block.skip}")
