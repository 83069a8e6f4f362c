"""The per-run charts of a build: a learning curve per run with learn-time evaluations, and a
per-update diagnostics chart per PPO-Lag or CPO run, as SVG files under ``<out>/figures/learn``.

Why a cache: a build after a sweep that added a few runs must not redraw the thousands that did
not change. Each chart's key is a digest of what it is drawn from (the side table's content, the
run's title and final metric, and the drawing code and template), kept in
``<out>/cache/run_charts.json``; a chart whose key is unchanged is reused, any other is redrawn.
Equal keys mean equal bytes, so a rebuild's site is the same as a fresh build's. One unreadable
side table is reported on its run page, never fatal.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import pandas as pd

from leaderboard.outputs.paper_figures import FigureSet
from leaderboard.runs.aggregate import Leaderboard, safe_name
from leaderboard.runs.sources import SideFile, Sources
from leaderboard.web import run_charts
from leaderboard.web.content_cache import atomic_write, digest, read_index, write_index

Progress = Callable[[Iterable[Any], str, int], Iterable[Any]]
#: The index of the charts' input digests, relative to ``--out``.
INDEX = Path("cache") / "run_charts.json"
#: File endings of per-run charts in ``<out>/figures/learn`` (``.png``: drawn by earlier versions).
CHART_FILES = ("*.svg", "*.png")
Draw = Callable[[dict[str, Any], pd.DataFrame], str]


def run_title(record: dict[str, Any]) -> str:
    return f"{record['learner']} · {record['scenario']}-{record['variant']} · seed {record['seed']}"


def final_metric(record: dict[str, Any]) -> float:
    value = record.get("metric")
    try:
        return math.nan if value is None else float(value)
    except (TypeError, ValueError):
        return math.nan


def episodes_of(record: dict[str, Any]) -> tuple[int | None, int | None]:
    """(episodes per learn-time estimate, episodes of the final evaluation) from the run's recorded
    config and row; None where not recorded."""
    try:
        config = json.loads(str(record.get("config") or "{}"))
    except ValueError:
        config = {}
    learn = config.get("learn_eval_episodes") if isinstance(config, dict) else None
    final = record.get("eval_episodes")
    as_int = (lambda v: int(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0
              else None)
    return as_int(learn), as_int(final)


def draw_learn(record: dict[str, Any], frame: pd.DataFrame) -> str:
    return run_charts.chart_svg(run_charts.learn_chart(frame, final_metric(record), run_title(record), *episodes_of(record)))


def draw_updates(record: dict[str, Any], frame: pd.DataFrame) -> str:
    return run_charts.chart_svg(run_charts.updates_chart(frame, run_title(record)))


def code_digest() -> str:
    """What every chart's bytes depend on besides its data: this code and the chart template."""
    return digest([Path(run_charts.__file__).read_bytes(), Path(__file__).read_bytes(), run_charts.template_text()])


def chart_key(code: str, kind: str, source: SideFile, record: dict[str, Any]) -> str:
    return digest([code, kind, source.digest(), run_title(record), repr(final_metric(record)), repr(episodes_of(record))])


def _charts(lb: Leaderboard, source_of: Callable[[str], SideFile | None], out_dir: Path, suffix: str, kind: str,
            draw: Draw, found: dict[str, Path], errors: dict[str, str], index: dict[str, str], fresh: dict[str, str],
            code: str, label: str, progress: Progress | None) -> int:
    """Draw the charts of one kind whose key changed; returns how many were drawn."""
    todo: list[tuple[dict[str, Any], SideFile, Path, str]] = []
    columns = [c for c in ("run_id", "metric", "scenario", "variant", "learner", "seed", "config", "eval_episodes")
               if c in lb.runs.columns]
    for record in lb.runs[columns].to_dict("records"):
        run_id = str(record["run_id"])
        source = source_of(run_id)
        if source is None:
            continue
        target = out_dir / f"{safe_name(run_id)}{suffix}.svg"
        try:
            key = chart_key(code, kind, source, record)
        except OSError as exc:
            errors[run_id] = f"{source.name}: {type(exc).__name__}: {exc}"
            continue
        found[run_id] = target
        if index.get(target.name) == key and target.is_file():
            fresh[target.name] = key
        else:
            todo.append((record, source, target, key))
    iterator: Iterable[Any] = progress(todo, label, len(todo)) if progress and todo else todo
    for record, source, target, key in iterator:
        run_id = str(record["run_id"])
        try:
            text = draw(record, source.read())
        except Exception as exc:  # noqa: BLE001 - one unreadable file must not sink the whole build
            found.pop(run_id, None)
            errors[run_id] = f"{source.name}: {type(exc).__name__}: {exc}"
            continue
        atomic_write(target, text.encode("utf-8"))
        fresh[target.name] = key
    return len(todo)


def write_run_charts(lb: Leaderboard, sources: Sources, out_dir: Path, figures: FigureSet, out_root: Path,
                     progress: Progress | None = None) -> int:
    """Every run's charts into ``out_dir`` (reusing unchanged ones) and ``figures.learn``/``updates``;
    charts of runs no longer shown are removed. Returns how many charts were drawn (not reused)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    index_path = out_root / INDEX
    index = read_index(index_path)
    fresh: dict[str, str] = {}
    code = code_digest()
    drawn = _charts(lb, sources.learn_of, out_dir, "", "learn", draw_learn, figures.learn, figures.learn_errors,
                    index, fresh, code, "learning curves", progress)
    drawn += _charts(lb, sources.updates_of, out_dir, ".updates", "updates", draw_updates, figures.updates,
                     figures.updates_errors, index, fresh, code, "update diagnostics", progress)
    for pattern in CHART_FILES:
        for path in out_dir.glob(pattern):
            if path.name not in fresh:
                path.unlink(missing_ok=True)
    write_index(index_path, fresh)
    return drawn
