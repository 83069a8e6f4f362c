"""The data of the ranking page (aggregates, probability of improvement, figures, rows used) and the
colours of Table 1's grid on the index page (:mod:`leaderboard.web.table1_grid`), both from :mod:`leaderboard.stats`.

Colours are computed here (a cell's background is data: its normalised score or its probability),
so the templates stay free of arithmetic.
"""

from __future__ import annotations

from typing import Any

import pandas as pd

from leaderboard.outputs.precision import DIGITS_RULE
from leaderboard.outputs.stats_figures import RANKING_FIGURES
from leaderboard.outputs.tables import fmt, interval_label, interval_text
from leaderboard.runs.aggregate import ORACLE_BEST, RANDOM_EXACT, Group, comparable_preset, not_comparable_text
from leaderboard.runs.cells import NO_BEST_PRESETS
from leaderboard.runs.opening import display_order, newest_own_group, whose_runs
from leaderboard.stats.cells import intervals_overlap
from leaderboard.stats.ranking import MIN_HEADROOM
from leaderboard.web.render import clean, clean_records, is_missing, scenario_href, section_id
from leaderboard.web.site_state import SiteBuild

#: Anchors of the score colour scale: worse than random (score -1 and below), random (0), oracle best (1).
SCORE_COLOURS = ("#f2a7a0", "#f7f7f7", "#7cc68d")
NOT_NORMALISED = "#e9ecf1"
#: Anchors of the probability colour scale: P = 0, 0.5, 1.
PROBABILITY_COLOURS = ("#f2a7a0", "#f7f7f7", "#8db8e8")
STATISTICS = (("mean", "Mean", max), ("iqm", "IQM", max), ("optimality_gap", "Optimality gap ↓", min))
MEASURE_TITLES = {"score": "Normalised score", "metric": "Raw morality metric"}
#: The rows each ranking figure is over: those of the normalised score or of the raw metric.
FIGURE_MEASURES = {"profile-score": "score", "aggregates-score": "score", "profile-metric": "metric",
                   "improvement": "metric"}


def _mix(a: str, b: str, t: float) -> str:
    """The colour ``t`` of the way from ``a`` to ``b`` (hex ``#rrggbb``)."""
    ca = [int(a[i:i + 2], 16) for i in (1, 3, 5)]
    cb = [int(b[i:i + 2], 16) for i in (1, 3, 5)]
    return "#" + "".join(f"{round(x + (y - x) * t):02x}" for x, y in zip(ca, cb))


def diverging(value: float | None, low: float, mid: float, high: float, anchors: tuple[str, str, str]) -> str:
    """A colour on a three-anchor scale (``low``..``mid``..``high``, clipped); grey when there is no value."""
    if value is None or is_missing(value):
        return NOT_NORMALISED
    value = min(max(float(value), low), high)
    if value <= mid:
        return _mix(anchors[0], anchors[1], (value - low) / (mid - low))
    return _mix(anchors[1], anchors[2], (value - mid) / (high - mid))


def interval(record: dict[str, Any] | None, digits: int = 3) -> str:
    """A record's ``[ci_low, ci_high]``, each bound to the decimals it is stable to (at most ``digits``), or a dash
    (with the record's ``ci_note`` when it says why there is none: too few runs for an interval)."""
    text = interval_text(record, digits) if record else ""
    if text:
        return text
    note = str((record or {}).get("ci_note") or "")
    return f"— ({note})" if note else "—"


def group_frame(frame: pd.DataFrame | None, group: Group) -> pd.DataFrame:
    if frame is None or frame.empty:
        return pd.DataFrame() if frame is None else frame
    return frame.loc[(frame["protocol"] == group.protocol) & (frame["preset"] == group.preset)]


# ---------------------------------------------------------------------------------------- Table 1 cells
def matrix_cell(c: dict[str, Any] | None, ref: dict[str, Any] | None, learner: str, chain: str,
                scenario: str) -> dict[str, Any]:
    """One Table 1 grid cell (:mod:`leaderboard.web.table1_grid`): the mean, coloured by its normalised score (when the row has one), with a tooltip."""
    if c is None or c["mean"] is None:
        return {"text": "—", "colour": NOT_NORMALISED, "title": f"{learner}: no result", "score": None,
                "bold": False, "incomplete": False}
    normalised = bool(ref and ref["normalised"])
    score = (c["mean"] - ref["random"]) / ref["headroom"] if normalised else None
    return {"text": fmt(c["mean"]), "colour": diverging(score, -1.0, 0.0, 1.0, SCORE_COLOURS),
            "title": " · ".join(_matrix_tip(c, ref, score, learner, chain, scenario)), "score": score,
            "bold": bool(c.get("bold")), "incomplete": not c["complete"]}


def _matrix_tip(c: dict[str, Any], ref: dict[str, Any] | None, score: float | None, learner: str, chain: str,
                scenario: str) -> list[str]:
    """A matrix cell's tooltip parts: mean, interval, runs, score, and why it is incomplete or not bold."""
    tip = [f"{learner} · {chain} / {scenario}", f"mean {fmt(c['mean'])}",
           interval_label(c) if not is_missing(c.get("ci_low")) else f"95% CI — ({c.get('ci_note') or 'none'})",
           f"runs {int(c['n_runs'])}",
           f"normalised score {fmt(score)}" if score is not None
           else "not normalised" + (f" ({ref['note']})" if ref and ref.get("note") else "")]
    if not c["complete"]:
        tip.append(f"incomplete: {c['incomplete_reason']}")
    if c.get("best"):
        tip.append("bold" if c.get("bold") else f"highest mean, not bold: {c.get('bold_note') or ''}")
    return tip


# ---------------------------------------------------------------------------------------- ranking
def _measure_rows(sb: SiteBuild, aggregates: pd.DataFrame, measure: str, marks: bool = True) -> list[dict[str, Any]]:
    """Per learner, each statistic with its interval, shaded when best and bold when also separated
    from every other learner's interval: the one meaning of the marks (:mod:`leaderboard.outputs.marks`).
    ``marks`` False: none (a sweep whose learners learn nothing, :data:`NO_BEST_PRESETS`)."""
    part = aggregates.loc[aggregates["measure"] == measure] if not aggregates.empty else aggregates
    if part.empty:
        return []
    learners = [n for n in sb.lb.learners if n in set(part["learner"])]
    marks_of = {statistic: _column_marks(part.loc[part["statistic"] == statistic], pick) if marks else {}
                for statistic, _, pick in STATISTICS}
    rows = []
    for learner in learners:
        mine = {r["statistic"]: r for r in clean_records(part.loc[part["learner"] == learner])}
        stats = []
        for statistic, _, _ in STATISTICS:
            r = mine.get(statistic)
            best, bold = marks_of[statistic].get(learner, (False, False))
            stats.append({"value": None if r is None else r["value"],
                          "ci": interval(r), "top": best, "bold": bold})
        first = next(iter(mine.values()))
        rows.append({"learner": learner, "colour": sb.colour(learner), "stats": stats,
                     "n_rows": first["n_rows"], "n_runs": first["n_runs"]})
    return rows


def _column_marks(column: pd.DataFrame, pick: Any) -> dict[str, tuple[bool, bool]]:
    """learner -> (best, bold) of one statistic: best = the best value (ties all best); bold = the
    only best, with an interval that overlaps no other learner's (as Table 1's bold)."""
    good = column.loc[column["value"].notna()]
    if good.empty:
        return {}
    top = pick(good["value"])
    best = good.loc[(good["value"] - top).abs() < 1e-12]
    out = {str(r["learner"]): (True, False) for r in best.to_dict("records")}
    if len(best) == 1 and len(good) > 1:
        cell = best.iloc[0]
        others = good.drop(index=best.index)
        overlaps = [intervals_overlap(cell["ci_low"], cell["ci_high"], o["ci_low"], o["ci_high"])
                    for o in others.to_dict("records")]
        out[str(cell["learner"])] = (True, all(o is False for o in overlaps))
    return out


def _improvement(sb: SiteBuild, frame: pd.DataFrame) -> tuple[list[tuple[str, str]], list[dict[str, Any]]]:
    if frame.empty:
        return [], []
    learners = [n for n in sb.lb.learners if n in set(frame["learner_x"])]
    pairs = {(r["learner_x"], r["learner_y"]): r for r in clean_records(frame)}
    rows = []
    for x in learners:
        cells = []
        for y in learners:
            r = pairs.get((x, y))
            if x == y or r is None:
                cells.append(None)
                continue
            cells.append({"probability": r["probability"], "ci": interval(r, 2),
                          "colour": diverging(r["probability"], 0.0, 0.5, 1.0, PROBABILITY_COLOURS),
                          "title": f"P({x} > {y}) = {fmt(r['probability'])}, 95% CI "
                                   f"{interval(r)}, over {r['n_rows']} row(s)"})
        rows.append({"learner": x, "colour": sb.colour(x), "cells": cells})
    return [(n, sb.colour(n)) for n in learners], rows


def left_out(rows: list[dict[str, Any]], measure: str) -> str:
    """Which rows the statistics of ``measure`` (``score`` | ``metric``; ``normalised``: the colours of
    the Table 1 grid) leave out and why, from the ranking's rows (:func:`leaderboard.stats.ranking_rows`):
    one sentence for the page, never hard-coded."""
    if not rows:
        return ""
    out = left_out_rows(rows, measure)
    counted = f"{len(rows)} rows with runs" if len(rows) > 1 else "1 row with runs"
    if not out:
        return f"Over {'all ' if len(rows) > 1 else ''}the {counted}: none is left out."
    return f"Leaves out {len(out)} of the {counted}: {'; '.join(out)}."


def left_out_rows(rows: list[dict[str, Any]], measure: str) -> list[str]:
    """``chain / scenario — why`` of each row :func:`left_out` names."""
    flag = {"score": "in_score", "metric": "in_metric", "normalised": "normalised"}[measure]
    return [f"{r['chain']} / {r['scenario']} — {_why_left_out(r, measure)}" for r in rows if not r[flag]]


def _why_left_out(row: dict[str, Any], measure: str) -> str:
    missing = f"no run of {row['missing']}" if row.get("missing") else ""
    normalised = row.get("normalised_note") or ""
    parts = {"score": [missing, normalised], "metric": [missing], "normalised": [normalised]}[measure]
    return ", ".join(p for p in parts if p) or str(row.get("note") or "")


def footnote(rows: list[dict[str, Any]]) -> str:
    """Which rows enter the score and the metric aggregates, and why the others do not."""
    n = len(rows)
    in_score = sum(bool(r["in_score"]) for r in rows)
    in_metric = sum(bool(r["in_metric"]) for r in rows)
    left = [f"{r['chain']} / {r['scenario']}: {r['note']}" for r in rows if not r["in_score"] and r["note"]]
    text = (f"The normalised score aggregates {in_score} of the {n} row(s) with runs; the raw metric {in_metric}. "
            "A row enters only if every learner compared has a usable run there (so all learners are aggregated over "
            f"the same rows), and the score only if the reference values exist and Oracle best − Random exact ≥ "
            f"{MIN_HEADROOM:g}: below that the row's distance from random is within one standard error of the final "
            f"evaluation's 100 episodes, and dividing by it would blow evaluation noise up {1 / MIN_HEADROOM:.0f}-fold. ")
    text += ("Left out of the score: " + "; ".join(left) + ".") if left else "No row is left out."
    return text


def ranking_context(sb: SiteBuild) -> dict[str, Any]:
    stats = sb.stats
    groups = []
    newest = newest_own_group(sb.lb)
    for group in display_order(sb.lb):
        if stats is None:
            break
        aggregates = group_frame(stats.aggregates, group)
        rows = [r | {"href": scenario_href(r["scenario"], "", section_id(group, r["chain"]))}
                for r in clean_records(group_frame(stats.rows, group))]
        measures = []
        for measure in ("score", "metric"):
            empty = ("No row can be normalised (no reference values, or too little headroom): see the rows below."
                     if measure == "score" else "No row where every learner has a usable run.")
            measures.append({"measure": measure, "title": MEASURE_TITLES[measure],
                             "rows": _measure_rows(sb, aggregates, measure, marks=group.preset not in NO_BEST_PRESETS),
                             "empty": empty,
                             "left_out": left_out(rows, measure)})
        learners, improvement = _improvement(sb, group_frame(stats.improvement, group))
        captions = dict(RANKING_FIGURES)
        figures = [{"src": path, "alt": f"{kind} of {group.label}",
                    "caption": " ".join(filter(None, [captions.get(kind, ""),
                                                      left_out(rows, FIGURE_MEASURES[kind]) if kind in FIGURE_MEASURES
                                                      else ""]))}
                   for kind, path in sb.ranking_figures.get(group, [])]
        groups.append({"slug": group.slug, "label": group.label, "whose": whose_runs(sb.lb, group, newest),
                       "not_comparable": "" if comparable_preset(group.preset) else not_comparable_text(group.preset),
                       "marks": group.preset not in NO_BEST_PRESETS, "measures": measures, "learners": learners,
                       "improvement": improvement, "improvement_left_out": left_out(rows, "metric"),
                       "figures": figures, "rows": rows, "footnote": footnote(rows)})
    n_rows = {len(g["rows"]) for g in groups}
    n_rows_text = f"{n_rows.pop()} rows" if len(n_rows) == 1 else "rows"
    return sb.common("Ranking across the benchmark", "", "ranking.html") | {
        "groups": groups, "stat_labels": [label for _, label, _ in STATISTICS],
        "resamples": sb.resamples("aggregates"), "improvement_resamples": sb.resamples("improvement"),
        "digits_rule": DIGITS_RULE,
        "random_exact": RANDOM_EXACT, "oracle_best": ORACLE_BEST, "n_rows_text": n_rows_text,
        "downloads_list": sb.downloads_of("ranking"),
    }


__all__ = ["clean", "diverging", "footnote", "group_frame", "left_out", "left_out_rows", "matrix_cell", "ranking_context"]
