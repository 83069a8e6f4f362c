"""Table 1 as the paper lays it out, and which sweep the index opens on.

Why a grid: readers of the paper think of Table 1 as rows (chain / scenario) by a column per
learner; the long table (one row per cell, 70 of them, 148 with one's own runs) is for sorting and
filtering, one click away. Each grid cell carries what a reader checks: the mean (bold, shaded and
⚠ as everywhere, :data:`leaderboard.outputs.marks.MARKS`), its 95% interval, and the paper's value with
the difference where the budget is the paper's. Where it is not, the grid says so once, above
the table, and shows no difference.

Which sweep the grid opens on, and which one it shows beside it, is :mod:`leaderboard.runs.opening`'s
choice; each is labelled with where its runs come from.
"""

from __future__ import annotations

from typing import Any

from leaderboard.outputs.precision import DIGITS_RULE
from leaderboard.outputs.tables import fmt, interval_text
from leaderboard.runs.aggregate import (
    ORACLE_BEST,
    ORACLE_WORST,
    RANDOM_EXACT,
    Group,
    Leaderboard,
    comparable_preset,
    not_comparable_text,
)
from leaderboard.runs.opening import newest_own_group, opening_groups, whose_runs
from leaderboard.runs.sources import RESULTS_SOURCE, Sources
from leaderboard.web.ranking_page import SCORE_COLOURS, group_frame, left_out_rows, matrix_cell
from leaderboard.web.render import clean_records, is_missing, scenario_href, section_id
from leaderboard.web.site_state import SiteBuild
from morality_gym.baselines.specs import CONF_DIR, protocol_spec, trains_alike

#: The protocol the paper's Table 1 values were obtained under (conf/protocol/paper.yaml).
PAPER_PROTOCOL = "paper"


def group_origin(lb: Leaderboard, sources: Sources, group: Group) -> str:
    """Where a sweep's counted runs come from, in words: ``630 of your runs in results`` /
    ``1,890 runs of release X`` / both, joined by "+"."""
    part = lb.runs.loc[(lb.runs["protocol"] == group.protocol) & (lb.runs["preset"] == group.preset)]
    counts = part["source"].value_counts().to_dict() if "source" in part.columns else {RESULTS_SOURCE: len(part)}
    words = []
    for source, n in sorted(counts.items(), key=lambda item: (item[0] != RESULTS_SOURCE, item[0])):
        words.append(f"{n:,} of your runs in {sources.results}" if source == RESULTS_SOURCE
                     else f"{n:,} runs of release {source}")
    return " + ".join(words) or "no runs"


def alike_note(lb: Leaderboard, group: Group) -> str:
    """Which learners this sweep lacks because they train identically under its protocol and
    another sweep's of the same preset, where they were run (:func:`trains_alike`): a reader of
    the corrected Table 1 looks for PPO's column and must learn why it is not there, and where it is.
    Empty when none."""
    here = set(lb.group_table(group)["learner"])
    notes = []
    for other in lb.groups:
        if other.preset != group.preset or other.protocol == group.protocol:
            continue
        runs = lb.runs.loc[(lb.runs["protocol"] == other.protocol) & (lb.runs["preset"] == other.preset)]
        # built-in learners only: a submitted policy or a user's algo is not the protocol's to change or leave alone
        missing = runs.loc[~runs["learner"].isin(here) & runs["algo"].isin(builtin_algos()), ["algo", "learner"]].drop_duplicates()
        if missing.empty:
            continue
        specs = (protocol_spec(group.protocol), protocol_spec(other.protocol))  # each file read once, not per learner
        alike = [label for algo, label in missing.itertuples(index=False) if trains_alike(algo, specs)]
        if alike:
            names = sorted(set(alike))
            one = len(names) == 1
            listed = names[0] if one else f"{', '.join(names[:-1])} and {names[-1]}"
            verb, pronoun, possessive = ("trains", "it", "its") if one else ("train", "them", "their")
            notes.append(f"{listed} {verb} identically under protocols {group.protocol} and {other.protocol}, so this "
                         f"sweep does not run {pronoun} again: {possessive} cells are those of {other.protocol} · {other.preset}")
    return "; ".join(notes)


def builtin_algos() -> set[str]:
    """The learners that ship with the project (``conf/algo``); a user's come from plugins."""
    return {p.stem for p in (CONF_DIR / "algo").glob("*.yaml")}


# ---------------------------------------------------------------------------------------- the grid
def grid_cell(record: dict[str, Any] | None, ref: dict[str, Any] | None, learner: str, chain: str,
              scenario: str) -> dict[str, Any]:
    """One grid cell: the matrix cell's colour and tooltip, plus its interval and the paper's value."""
    cell = matrix_cell(record, ref, learner, chain, scenario)
    if record is None or record.get("mean") is None:
        return cell | {"best": False, "ci": "", "paper": "", "delta": "", "delta_off": False, "off_budget": ""}
    delta = record.get("delta")
    off = int(record.get("off_budget") or 0)
    return cell | {
        # a cell whose runs trained for another budget than its sweep's (a submission): said in the cell itself
        "off_budget": str(record.get("delta_note") or "") if off else "",
        "best": bool(record.get("best")),
        "ci": interval_text(record),
        "paper": "" if is_missing(record.get("paper")) else fmt(record["paper"]),
        "delta": "" if is_missing(delta) else fmt(delta, signed=True),
        "delta_off": not is_missing(delta) and abs(float(delta)) >= 0.05,
    }


def group_grid(sb: SiteBuild, group: Group, root: str) -> dict[str, Any]:
    """One sweep's grid: a header row per chain, a row per scenario, a column per learner (the
    reference values colour the cells; their numbers are in the long table)."""
    lb = sb.lb
    table = lb.group_table(group)
    cells = {(r["chain"], r["scenario"], r["learner"]): r for r in clean_records(table.loc[table["kind"] == "learner"])}
    ranked = clean_records(group_frame(sb.stats.rows if sb.stats is not None else None, group))
    normalisers = {(r["chain"], r["scenario"]): r for r in ranked}
    learners = [n for n in lb.learners if n in set(table["learner"])]
    rows, previous = [], None
    for chain, scenario in lb.pairs(group):
        ref = normalisers.get((chain, scenario))
        rows.append({"chain": chain if chain != previous else "",
                     "scenario": scenario, "href": scenario_href(scenario, root, section_id(group, chain)),
                     "cells": [grid_cell(cells.get((chain, scenario, n)), ref, n, chain, scenario) for n in learners]})
        previous = chain
    return {"slug": group.slug, "label": f"{group.protocol} · {group.preset}", "origin": group_origin(lb, sb.sources, group),
            "whose": whose_runs(lb, group, newest_own_group(lb)), "paper_protocol": group.protocol == PAPER_PROTOCOL,
            "comparable": comparable_preset(group.preset), "not_comparable": not_comparable_text(group.preset),
            "learners": [(n, sb.colour(n), lb.submitted.get(n)) for n in learners], "rows": rows,
            "n_cells": len(cells), "grey": "; ".join(left_out_rows(ranked, "normalised")), "alike": alike_note(lb, group)}


def grid_context(sb: SiteBuild, root: str) -> dict[str, Any]:
    """Every sweep's grid, which one the index opens on and which one it shows beside it."""
    opening, beside = opening_groups(sb.lb)
    grids = [group_grid(sb, group, root) for group in sb.lb.groups]
    return {"grids": grids, "opening": opening.slug if opening else "", "beside": beside.slug if beside else "",
            "own": newest_own_group(sb.lb) is not None,
            "sweeps": [(g["slug"], f"{g['label']} ({g['origin']})") for g in grids],
            "oracle_worst": ORACLE_WORST,
            "legend": SCORE_COLOURS, "random_exact": RANDOM_EXACT, "oracle_best": ORACLE_BEST, "digits_rule": DIGITS_RULE}
