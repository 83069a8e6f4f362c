"""The Jinja2 environment of the site: templates and static files shipped inside the package.

Why templates: the pages' markup, CSS and script are edited as HTML, CSS and JavaScript
(``leaderboard/web/templates``, ``leaderboard/web/static``), and Python only builds the data each page
shows (:mod:`leaderboard.web.pages`, :mod:`leaderboard.web.ranking_page`). Autoescaping is on for every
template, so any text from a results file (errors, tracebacks, configurations, names) is escaped
wherever it lands; markup built in Python is never passed in.

The filters below format numbers exactly like the tables (:func:`leaderboard.outputs.tables.fmt`), so the
site and ``table1.md`` never disagree on a digit.
"""

from __future__ import annotations

import html
import math
from functools import lru_cache
from pathlib import Path
from typing import Any

import jinja2
import pandas as pd
from markupsafe import Markup

from leaderboard.outputs.tables import fmt
from leaderboard.runs.aggregate import Group, safe_name

PACKAGE_DIR = Path(__file__).resolve().parent
TEMPLATES = PACKAGE_DIR / "templates"
STATIC = PACKAGE_DIR / "static"
#: The static files copied into ``<site>/assets/`` on every build.
STATIC_FILES = ("site.css", "site.js")


def is_missing(value: Any) -> bool:
    """None, pandas' NA and NaN: the values a table shows as a dash and sorts last."""
    if value is None or value is pd.NA:
        return True
    try:
        return math.isnan(float(value))
    except (TypeError, ValueError):
        return False


def sort_key(value: Any) -> str:
    """The exact value for a ``data-sort`` attribute (the script sorts on it); blank when missing."""
    return "" if is_missing(value) else repr(float(value))


def int_text(value: Any) -> str:
    try:
        return str(int(value))
    except (TypeError, ValueError):
        return "—"


def count_text(value: Any, noun: str = "run") -> str:
    """``1 run`` / ``1,890 runs``: a count written one way on every page (a box once said "1,890 runs"
    and "1890 run(s)")."""
    try:
        n = int(value)
    except (TypeError, ValueError):
        return f"— {noun}s"
    return f"{n:,} {noun}" + ("" if n == 1 else "s")


def clean(value: Any) -> Any:
    """NaN / NA -> None, numpy scalars -> Python (templates test ``is none`` and print plainly)."""
    if is_missing(value) and not isinstance(value, str):
        return None
    if hasattr(value, "item") and not isinstance(value, (list, tuple, dict, str)):
        try:
            return value.item()
        except (ValueError, AttributeError):
            return value
    return value


def clean_records(frame: pd.DataFrame) -> list[dict[str, Any]]:
    """A frame's rows as dicts with :func:`clean` values (list-valued columns are kept as they are)."""
    return [{k: (v if isinstance(v, (list, tuple)) else clean(v)) for k, v in r.items()} for r in frame.to_dict("records")]


# ---------------------------------------------------------------------------------------- links
def run_href(run_id: str, root: str) -> str:
    return f"{root}runs/{safe_name(run_id)}.html"


def scenario_href(scenario: str, root: str, anchor: str = "") -> str:
    return f"{root}scenarios/{safe_name(scenario)}.html" + (f"#{anchor}" if anchor else "")


def section_id(group: Group, chain: str) -> str:
    return f"{group.slug}--{safe_name(chain)}"


def finalize(value: Any) -> Any:
    """Escape every printed value with :func:`html.escape` (``&quot;``, as the site always wrote), None as "".

    Markup (macro output, already escaped) passes through untouched.
    """
    if isinstance(value, Markup):
        return value
    return Markup(html.escape("" if value is None else str(value), quote=True))


@lru_cache(maxsize=1)
def environment() -> jinja2.Environment:
    """One environment per process (templates are compiled once and cached by Jinja)."""
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(TEMPLATES)),
        autoescape=True,  # every template, whatever its extension
        undefined=jinja2.StrictUndefined,  # a misspelt field fails the build instead of printing nothing
        trim_blocks=False,
        lstrip_blocks=False,
        keep_trailing_newline=True,
        finalize=finalize,
    )
    env.filters.update(fmt=fmt, sortkey=sort_key, intstr=int_text, missing=is_missing, run_href=run_href, counted=count_text)
    return env


def render(template: str, **context: Any) -> str:
    """Render ``templates/<template>`` with ``context``."""
    return environment().get_template(template).render(**context)
