"""The build's date: from ``SOURCE_DATE_EPOCH`` or the newest run, never the clock.

Why: the same results must give byte-identical tables and pages (reproducible builds, as the
``SOURCE_DATE_EPOCH`` convention of reproducible-builds.org asks), so that a diff of two builds
shows changed results and nothing else. The newest run's ``finished_at`` is what a reader wants
to know anyway: how recent the numbers are.
"""

from __future__ import annotations

import os
from datetime import UTC, datetime

import pandas as pd

ENV = "SOURCE_DATE_EPOCH"


class StampError(ValueError):
    """``SOURCE_DATE_EPOCH`` is set but is not a number of seconds."""


def source_date_epoch() -> datetime | None:
    """``SOURCE_DATE_EPOCH`` as a date, None when unset; :class:`StampError` when it is not a number.

    The build checks it first thing: numpy (through f2py, imported by scipy) reads the same variable
    at import and dies with a bare ``int()`` traceback on a bad value.
    """
    raw = os.environ.get(ENV)
    if raw is None or not raw.strip():
        return None
    try:
        return datetime.fromtimestamp(int(raw.strip()), UTC)
    except (ValueError, OverflowError, OSError) as exc:
        raise StampError(f"{ENV}={raw!r} is not a Unix time in whole seconds (e.g. {ENV}=$(date +%s), "
                         f"or unset it to date the build by its newest run)") from exc


def build_time(runs: pd.DataFrame) -> datetime | None:
    """``SOURCE_DATE_EPOCH`` if set, else the newest ``finished_at`` of the runs, else None."""
    epoch = source_date_epoch()
    if epoch is not None:
        return epoch
    if "finished_at" not in runs.columns or runs.empty:
        return None
    times = pd.to_datetime(runs["finished_at"], errors="coerce", utc=True).dropna()
    return None if times.empty else times.max().to_pydatetime()


def stamp_text(runs: pd.DataFrame) -> str:
    """The stamp as shown: ``2026-11-21 10:00 UTC (newest run)``, or why there is none."""
    when = build_time(runs)
    if when is None:
        return "(no run has finished yet)"
    source = f"{ENV}" if os.environ.get(ENV, "").strip() else "newest run"
    return f"{when.astimezone(UTC).strftime('%Y-%m-%d %H:%M UTC')} ({source})"
