"""Run pages kept between builds in ``<out>/cache/pages``, keyed by a digest of what they show.

Why: a site has a page per run (thousands after a Table 1 sweep and a release) and a rebuild after
a sweep that changed little re-renders them all. A run page is a function of its template context
(plain data: texts, numbers, lists) and of the templates and filters that render it, so the key
is a digest of the context serialised as JSON plus the templates' and filters' source; a page is
rendered only when no page with that key was written before. Pages and per-run charts enter the
new site as hard links (a copy where links are not possible): linking costs no data written, and
deleting the previous site then frees no blocks.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from functools import lru_cache
from importlib import metadata
from pathlib import Path
from typing import Any

from leaderboard.outputs import tables as tables_module
from leaderboard.web import render as render_module
from leaderboard.web.content_cache import atomic_write, digest
from leaderboard.web.render import TEMPLATES
from morality_gym.clitools import public_mode


def link_or_copy(src: Path, dst: Path) -> None:
    """``dst`` as a hard link to ``src``, or a copy across file systems or where links are refused.

    Only for files that are replaced, never rewritten in place (:func:`atomic_write`): a linked
    file shares its bytes with the site."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)
    os.chmod(dst, public_mode())  # a cache written before mkstemp's 0600 was lifted still serves readable pages


@lru_cache(maxsize=1)
def templates_digest() -> str:
    """Every template, the filters (:mod:`leaderboard.web.render`, :mod:`leaderboard.outputs.tables`) and Jinja's version."""
    files = sorted(p for p in TEMPLATES.rglob("*") if p.is_file())
    return digest([metadata.version("jinja2"), metadata.version("markupsafe"),
                   Path(render_module.__file__).read_bytes(), Path(tables_module.__file__).read_bytes(),
                   *(f"{p.relative_to(TEMPLATES)}" for p in files), *(p.read_bytes() for p in files)])


def _plain(value: Any) -> Any:
    """JSON for the values a context holds besides JSON's own: numpy scalars, paths."""
    if hasattr(value, "item") and not isinstance(value, (list, tuple, dict, str)):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} in a page context")


def context_key(template: str, context: dict[str, Any]) -> str | None:
    """The page's key, or ``None`` when the context holds something not serialisable as data
    (then the page is always rendered: no key is better than a key that misses a difference)."""
    try:
        text = json.dumps(context, default=_plain, sort_keys=True, ensure_ascii=False)
    except (TypeError, ValueError):
        return None
    return digest([templates_digest(), template, text])


class PageCache:
    """Rendered pages under ``directory`` by key; ``directory`` None renders every page."""

    def __init__(self, directory: Path | None) -> None:
        self.directory = directory
        self.used: set[str] = set()
        self.rendered = 0
        self.reused = 0
        if directory is not None:
            directory.mkdir(parents=True, exist_ok=True)

    def place(self, target: Path, template: str, context: dict[str, Any], draw: Callable[[], str]) -> None:
        """Write the page ``draw()`` renders to ``target``, or link the cached one of the same key."""
        key = context_key(template, context) if self.directory is not None else None
        if key is None or self.directory is None:
            self.rendered += 1
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(draw(), encoding="utf-8")
            return
        cached = self.directory / f"{key}.html"
        self.used.add(cached.name)
        if cached.is_file():
            self.reused += 1
        else:
            self.rendered += 1
            atomic_write(cached, draw().encode("utf-8"))
        link_or_copy(cached, target)

    def prune(self) -> None:
        """Remove the cached pages this build did not use (the cache holds one site's pages)."""
        if self.directory is None:
            return
        for path in self.directory.glob("*.html"):
            if path.name not in self.used:
                path.unlink(missing_ok=True)
