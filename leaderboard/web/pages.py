"""The data each page of the site shows: the index (status, Table 1, Figure 2), the runs index, a run
page and a scenario page. Plain dicts and lists of plain values; the templates lay them out.

Every value from a results file is passed as text (never as markup): the templates escape it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pandas as pd

from leaderboard.outputs.intervals import BOLD_RULE
from leaderboard.outputs.marks import NOTABLE_DELTA
from leaderboard.outputs.paper_figures import chain_title, norm_abbreviation, norm_label
from leaderboard.outputs.precision import DIGITS_RULE
from leaderboard.outputs.tables import fmt, interval_text
from leaderboard.runs.aggregate import (
    ORACLE_BEST,
    ORACLE_WORST,
    RANDOM_EXACT,
    STD_DDOF,
    Group,
    chain_norm_order,
    comparable_preset,
    not_comparable_text,
    safe_name,
)
from leaderboard.runs.opening import display_order, newest_own_group, whose_runs
from leaderboard.runs.sources import RESULTS_SOURCE
from leaderboard.web.llm_entries import llm_entries
from leaderboard.web.render import clean, clean_records, is_missing, run_href, scenario_href, section_id
from leaderboard.web.run_figures import episodes_of
from leaderboard.web.site_state import SiteBuild
from leaderboard.web.table1_grid import grid_context, opening_groups
from morality_gym.clitools import duration
from morality_gym.envs.registry import scenario_named
from morality_gym.results.schema import MF_PREFIX


def expected_count(record: dict[str, Any]) -> int:
    """The cell's expected number of runs (variants x seeds), or its planned count if unknown."""
    value = record.get("n_expected")
    if is_missing(value) or int(value) == 0:
        return int(record["n_planned"])
    return int(value)


def ci_text(record: dict[str, Any]) -> str:
    """``[low, high]`` to the decimals each bound is stable to, or a dash when there is no interval (the
    reason goes in the tooltip)."""
    return interval_text(record) or "—"


def bold_title(record: dict[str, Any]) -> str:
    """Tooltip of a row's best cell: why it is, or is not, bold."""
    if not record.get("best"):
        return ""
    note = record.get("bold_note") or ""
    return "bold: interval separated from every other learner" if record.get("bold") else f"not bold: {note}"


def cell_fields(sb: SiteBuild, record: dict[str, Any]) -> dict[str, Any]:
    """The fields a Table 1 learner or reference cell shows, wherever it is shown."""
    learner = str(record["learner"])
    is_learner = record.get("kind") == "learner"
    complete = bool(record.get("complete", True)) if is_learner else True
    return record | {
        "colour": sb.colour(learner),
        "submitted": sb.lb.submitted.get(learner) if is_learner else None,
        "complete": complete,
        "incomplete_reason": str(record.get("incomplete_reason") or ""),
        "best": bool(record.get("best")),
        "bold": bool(record.get("bold")),
        "bold_title": bold_title(record),
        "ci_text": ci_text(record) if is_learner else "",
        "ci_note": str(record.get("ci_note") or ""),
        "n_runs": int(record["n_runs"]) if is_learner and not is_missing(record.get("n_runs")) else 0,
        "expected": expected_count(record) if is_learner else 0,
    }


# ---------------------------------------------------------------------------------------- index
def status_context(sb: SiteBuild) -> dict[str, Any]:
    """Counts of runs, failures and missing runs, and the full lists (nothing hidden)."""
    lb = sb.lb
    n_failed, n_missing = len(lb.problems), len(lb.missing)
    n_planned = len(set(lb.planned) | set(lb.runs["run_id"]))
    learner_rows = lb.table.loc[lb.table["kind"] == "learner"]
    n_incomplete = int((~learner_rows["complete"].astype(bool)).sum()) if len(learner_rows) else 0
    stats = [
        ("good", lb.n_ok, "runs with a result"),
        ("bad" if n_failed else "", n_failed, "failed"),
        ("warn" if n_missing else "", n_missing, f"missing of {n_planned} planned"),
        *([("", len(lb.superseded), "superseded, not counted")] if len(lb.superseded) else []),
        *([("warn", n_incomplete, "incomplete cells (marked ⚠)")] if n_incomplete else []),
        *([("bad", len(lb.skipped), "unreadable files, left out")] if lb.skipped else []),
        ("", len(lb.pairs()), "(chain, scenario) rows"),
        ("", len(lb.groups), "sweeps (protocol · preset)"),
    ]
    return {
        "stats": stats,
        "sweeps": ", ".join(g.label for g in lb.groups),
        "n_runs": len(lb.runs),
        "failed": clean_records(lb.problems),
        "missing": clean_records(lb.missing),
        "superseded": clean_records(lb.superseded) if len(lb.superseded) else [],
        "skipped": list(lb.skipped),
        "quarantined": [{k: i.get(k) for k in ("file", "moved_to", "reason", "at")} for i in lb.quarantined],
        "reference_errors": list(lb.reference_errors.items()),
    }


def table1_context(sb: SiteBuild, root: str) -> dict[str, Any]:
    """Table 1, long format: one row per (sweep, chain, scenario, learner), reference values alongside."""
    lb = sb.lb
    t = lb.table
    reference = {(r["protocol"], r["preset"], r["chain"], r["scenario"], r["learner"]): r["mean"]
                 for r in t.loc[t["kind"] == "reference"].to_dict("records")}
    rows = []
    for r in clean_records(t.loc[t["kind"] == "learner"]):
        group = Group(r["protocol"], r["preset"])
        delta = r["delta"]
        rows.append(cell_fields(sb, r) | {
            "slug": group.slug, "delta_note": str(r.get("delta_note") or ""),
            "href": scenario_href(r["scenario"], root, section_id(group, r["chain"])),
            "delta_class": "off" if delta is not None and abs(delta) >= NOTABLE_DELTA else "",
            "refs": [clean(reference.get((r["protocol"], r["preset"], r["chain"], r["scenario"], name)))
                     for name in (RANDOM_EXACT, ORACLE_BEST, ORACLE_WORST)],
        })
    return {
        "rows": rows,
        "ddof": STD_DDOF,
        "resamples": sb.resamples("cells"),
        "digits_rule": DIGITS_RULE,
        "bold_rule": BOLD_RULE,
        "notable": NOTABLE_DELTA,
        "random_exact": RANDOM_EXACT, "oracle_best": ORACLE_BEST, "oracle_worst": ORACLE_WORST,
        "default": opening.slug if (opening := opening_groups(lb)[0]) else "",
        "sweeps": [(g.slug, f"{g.protocol} · {g.preset}") for g in lb.groups],
        "chains": [(c, c) for c in dict.fromkeys(c for c, _ in lb.pairs())],
        "scenarios": [(s, s) for s in sorted({s for _, s in lb.pairs()})],
        "learners": [(name, name) for name in lb.learners],
        "downloads": sb.downloads_of("table1"),
    }


def figure2_context(sb: SiteBuild, root: str) -> list[dict[str, Any]]:
    groups = []
    for group in sb.lb.groups:
        items = [(chain, f"{root}figures/{group.slug}/{path.name}") for (g, chain), path in sb.figures.bars.items()
                 if g == group]
        if items:
            groups.append({"slug": group.slug, "label": group.label, "figures": items})
    return groups


def scenarios_context(sb: SiteBuild, root: str) -> list[tuple[str, str, str]]:
    by_scenario: dict[str, list[str]] = {}
    for chain, scenario in sb.lb.pairs():
        by_scenario.setdefault(scenario, []).append(chain)
    return [(s, scenario_href(s, root), ", ".join(chains)) for s, chains in sorted(by_scenario.items())]


def index_context(sb: SiteBuild) -> dict[str, Any]:
    opening = opening_groups(sb.lb)[0]
    return sb.common("MoralityGym leaderboard", "", "index.html") | {
        "opening": f"{opening.protocol} · {opening.preset}" if opening else "",
        "status": status_context(sb),
        "t1": table1_context(sb, ""),
        "grid": grid_context(sb, ""),
        "figure2": figure2_context(sb, ""),
        "scenarios": scenarios_context(sb, ""),
        "sources": sources_context(sb),
        "llm": llm_entries(sb.lb.runs),
    }


def sources_context(sb: SiteBuild) -> list[dict[str, Any]]:
    """Where the numbers come from, one entry per source that contributed runs: a release with its
    name, title, commit and date (so shipped numbers are labelled as such), and the results directory."""
    counts = sb.lb.runs["source"].value_counts().to_dict() if "source" in sb.lb.runs.columns else {}
    out = []
    if sb.sources.has_results_runs:
        out.append({"kind": "results", "label": str(sb.sources.results), "title": "your runs",
                    "runs": int(counts.get(RESULTS_SOURCE, 0)), "commit": "", "created": "", "replaced": ""}
                   | own_sweeps(sb))
    for release in sb.sources.releases:
        m = release.manifest
        out.append({"kind": "release", "label": release.name, "title": str(m.get("title", "")),
                    "runs": int(counts.get(release.name, 0)), "commit": ", ".join(release.commits), "commit_word": release.commit_word,
                    "created": str(m.get("created", ""))[:10],
                    "replaced": sb.sources.replaced_note(release, int(counts.get(release.name, 0)), source_label)})
    return out


def own_sweeps(sb: SiteBuild) -> dict[str, str]:
    """The sweeps the user's runs are in (``paper · smoke (630)``) and when the newest finished."""
    runs = sb.lb.runs
    own = runs.loc[runs["source"] == RESULTS_SOURCE] if "source" in runs.columns else runs
    if own.empty:
        return {"sweeps": "", "newest": ""}
    counts = own.groupby(["protocol", "preset"], sort=False).size()
    sweeps = ", ".join(f"{protocol} · {preset} ({n:,})" for (protocol, preset), n in counts.items())
    finished = own["finished_at"].dropna().astype(str)
    newest = max(finished).replace("T", " ")[:16] + " UTC" if len(finished) else ""
    return {"sweeps": sweeps, "newest": newest}


def source_label(source: str) -> str:
    """How the All runs page names a run's source: ``your runs`` or ``release <name>``."""
    return "your runs" if source == RESULTS_SOURCE else f"release {source}"


# ---------------------------------------------------------------------------------------- runs index
def runs_context(sb: SiteBuild) -> dict[str, Any]:
    runs = sb.lb.runs.sort_values(["protocol", "preset", "chain", "scenario", "variant", "learner", "seed"])
    if "source" not in runs.columns:
        runs = runs.assign(source=RESULTS_SOURCE)
    records = [r | {"state": "ok" if r["ok"] else "failed", "colour": sb.colour(str(r["learner"])),
                    "sweep": Group(r["protocol"], r["preset"]).slug, "source_label": source_label(str(r["source"]))}
               for r in clean_records(runs[["run_id", "ok", "status", "protocol", "preset", "chain", "scenario", "variant",
                                            "learner", "seed", "metric", "source"]])]
    sources = dict.fromkeys(str(s) for s in runs["source"])
    return sb.common("All runs", "../", "runs/index.html") | {
        "runs": records,
        "sources": [(s, source_label(s)) for s in sources],
        # opens on the user's own runs when there are runs of a release too (issue 36); "all" one click away
        "source_default": RESULTS_SOURCE if RESULTS_SOURCE in sources and len(sources) > 1 else "",
        "sweeps": [(g.slug, f"{g.protocol} · {g.preset}") for g in sb.lb.groups],
        "chains": [(c, c) for c in dict.fromkeys(c for c, _ in sb.lb.pairs())],
        "learners": [(n, n) for n in sb.lb.learners],
        "downloads_list": sb.downloads_of("runs"),
    }


# ---------------------------------------------------------------------------------------- run pages
METRICS = [
    ("metric", "Morality metric (final evaluation, Monte Carlo)", 4),
    ("metric_stderr", "Standard error of the metric", 4),
    ("exact_metric", "Exact metric of the final policy", 4),
    ("mean_return", "Mean return", 2),
    ("mean_cost", "Mean cost", 3),
    ("mean_length", "Mean episode length", 2),
    ("truncation_rate", "Truncation rate", 3),
    ("goal_rate", "Landmark reached rate", 3),
]
INFO = [("budget", "Training budget (steps)"), ("total_steps", "Steps trained"), ("eval_episodes", "Evaluation episodes"),
        ("beta", "beta"), ("max_steps", "max_steps"), ("wall_time_s", "Wall time"),
        ("cpu_time_s", "CPU time"), ("started_at", "Started"),
        ("finished_at", "Finished"), ("hostname", "Host"), ("git_commit", "Git commit"), ("model_path", "Model"),
        ("gif_path", "GIF"), ("source", "Source (results directory or release)")]


def pretty_json(text: Any) -> str:
    if text is None or (isinstance(text, float) and math.isnan(text)):
        return "(none)"
    try:
        return json.dumps(json.loads(str(text)), indent=2, sort_keys=True)
    except ValueError:
        return str(text)


def tracking_info(tracking_dir: Path | None, run_id: str) -> tuple[str, str | None]:
    """(``mlflow_run_id`` or a reason, ``experiment_id``) from ``<results>/tracking/<run_id>.json``
    (``tracking_dir`` None: the run came from a release, which carries no MLflow store)."""
    if tracking_dir is None:
        return "from a release (no MLflow store)", None
    path = tracking_dir / f"{safe_name(run_id)}.json"
    if not path.is_file():
        return "not synced", None
    try:
        body = json.loads(path.read_text())
        return str(body["mlflow_run_id"]), (str(body["experiment_id"]) if body.get("experiment_id") is not None else None)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return f"tracking file unreadable ({type(exc).__name__}: {exc})", None


def seconds_text(value: float) -> str:
    """A duration for people: ``3.2 s`` under a minute, else ``2m03s (123 s)``; full precision stays in
    the downloads (``data/runs.csv``, ``data/runs.parquet``)."""
    if value < 60:
        return f"{value:.1f} s"
    return f"{duration(value)} ({value:,.0f} s)"


#: Run-page fields shown rounded for people, and how.
PEOPLE_FORMATS = {
    "wall_time_s": seconds_text,
    "cpu_time_s": seconds_text,
    "budget": lambda v: f"{int(v):,}",
    "total_steps": lambda v: f"{int(v):,}",
}


def value_text(record: dict[str, Any], key: str, digits: int | None = None) -> str:
    value = record.get(key)
    if is_missing(value) and not isinstance(value, str):
        return "—"
    if digits is not None:
        return fmt(value, digits)
    if key in PEOPLE_FORMATS and isinstance(value, (int, float)):
        return PEOPLE_FORMATS[key](float(value))
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)


def run_context(sb: SiteBuild, record: dict[str, Any]) -> dict[str, Any]:
    root = "../"
    run_id = str(record["run_id"])
    group = Group(record["protocol"], record["preset"])
    relevant = set(record["relevant_norms"])
    norms = [n for n in chain_norm_order(str(record["chain"])) if f"{MF_PREFIX}{n}" in record]
    norms += sorted(k[len(MF_PREFIX):] for k in record if str(k).startswith(MF_PREFIX)
                    and k[len(MF_PREFIX):] not in norms and not is_missing(record[k]))
    mlflow_id, experiment = tracking_info(sb.sources.tracking_dir(run_id), run_id)
    run = {
        "run_id": run_id, "ok": bool(record["ok"]), "state": "ok" if record["ok"] else "failed",
        "status": record["status"], "chain": record["chain"], "scenario": record["scenario"],
        "scenario_href": scenario_href(str(record["scenario"]), root, section_id(group, str(record["chain"]))),
        "variant": record["variant"], "env_id": record["env_id"], "learner": record["learner"],
        "colour": sb.colour(str(record["learner"])), "algo": clean(record.get("algo")),
        "protocol": record["protocol"], "preset": record["preset"], "seed": record["seed"],
        "error": clean(record.get("error")), "traceback": clean(record.get("traceback")),
        "metrics": [(label, value_text(record, key, digits)) for key, label, digits in METRICS],
        "info": [(label, source_label(str(record["source"])) if key == "source" and not is_missing(record.get(key))
                  else value_text(record, key)) for key, label in INFO],
        "mlflow_id": mlflow_id, "experiment": experiment,
        "norms": [{"name": n, "label": norm_label(n), "abbreviation": norm_abbreviation(n), "relevant": n in relevant,
                   "value": clean(record.get(f"{MF_PREFIX}{n}"))} for n in norms],
        "learn": sb.learn.get(run_id), "gif": sb.gifs.get(run_id),
        **dict(zip(("learn_episodes", "final_episodes"), episodes_of(record))),
        "learn_error": sb.figures.learn_errors.get(run_id),
        "updates": sb.updates.get(run_id), "updates_error": sb.figures.updates_errors.get(run_id),
        "config": pretty_json(record.get("config")), "versions": pretty_json(record.get("versions")),
    }
    title = f"{record['learner']} · {record['env_id']} · seed {_int(record['seed'])}"
    return sb.common(title, root, "") | {"run": run}


def _int(value: Any) -> str:
    try:
        return str(int(value))
    except (TypeError, ValueError):
        return "—"


# ---------------------------------------------------------------------------------------- scenario pages
def variant_specs(scenario: str) -> tuple[Any, list[str]]:
    try:
        spec = scenario_named(scenario)
    except KeyError:
        return None, []
    return spec, list(spec.variants)


def summary_rows(sb: SiteBuild, group: Group, chain: str, scenario: str) -> list[dict[str, Any]]:
    t = sb.lb.group_table(group)
    t = t.loc[(t["chain"] == chain) & (t["scenario"] == scenario)]
    return [cell_fields(sb, r) for r in clean_records(t)]


def breakdown(sb: SiteBuild, group: Group, chain: str, scenario: str, variant_names: list[str]) -> dict[str, Any]:
    """Metric per variant (rows) and learner (columns), with seed links, and the reference values."""
    lb = sb.lb
    v = lb.variants
    v = v.loc[(v["protocol"] == group.protocol) & (v["preset"] == group.preset) & (v["chain"] == chain)
              & (v["scenario"] == scenario)]
    miss = lb.missing
    miss = miss.loc[(miss["protocol"] == group.protocol) & (miss["preset"] == group.preset) & (miss["chain"] == chain)
                    & (miss["scenario"] == scenario)]
    learners = [name for name in lb.learners if name in set(v["learner"]) | set(miss["learner"])]
    entry = lb.reference_entry(chain, scenario, group)
    names = [n for n in variant_names if n in set(v["variant"]) | set(miss["variant"])]
    names += sorted((set(v["variant"]) | set(miss["variant"])) - set(names))
    failed = set(lb.runs.loc[~lb.runs["ok"], "run_id"])
    rows = []
    for name in names:
        cells = []
        for learner in learners:
            part = v.loc[(v["variant"] == name) & (v["learner"] == learner)]
            missing_seeds = miss.loc[(miss["variant"] == name) & (miss["learner"] == learner), "seed"]
            cells.append(_breakdown_cell(part, missing_seeds, failed))
        ref = (entry or {}).get("variants", {}).get(name) if entry else None
        refs = [clean(ref[key]) if ref else None for key in ("random_exact", "oracle_best", "oracle_worst")]
        rows.append({"name": name, "cells": cells, "refs": refs})
    return {"learners": [(n, sb.colour(n)) for n in learners], "rows": rows,
            "ref_labels": (RANDOM_EXACT, ORACLE_BEST, ORACLE_WORST)}


def _breakdown_cell(part: pd.DataFrame, missing_seeds: pd.Series, failed: set[Any]) -> dict[str, Any]:
    """One (variant, learner) cell: mean ± std over seeds, and a link per seed (run, failed or missing)."""
    links: list[dict[str, Any]] = []
    value, sort = "—", ""
    if not part.empty:
        r = part.iloc[0]
        if not math.isnan(r["mean"]):
            value = f"{fmt(r['mean'])} ± {fmt(r['std'])}" if r["n_runs"] > 1 else fmt(r["mean"])
            sort = repr(float(r["mean"]))
        links += [{"seed": _int(seed), "href": run_href(str(run_id), "../"), "failed": run_id in failed,
                   "missing": False} for run_id, seed in zip(r["run_ids"], r["seeds"])]
    links += [{"seed": _int(s), "href": "", "failed": False, "missing": True} for s in missing_seeds]
    return {"value": value, "sort": sort, "links": links}


def gif_items(sb: SiteBuild, group: Group, chain: str, scenario: str) -> list[dict[str, Any]]:
    items = []
    for learner in sb.lb.learners:
        record = sb.gif_choices.get((group, chain, scenario, learner))
        if record is None:
            continue
        items.append({"src": sb.gifs[str(record["run_id"])], "learner": learner, "colour": sb.colour(learner),
                      "variant": record["variant"], "seed": record["seed"], "metric": clean(record["metric"]),
                      "href": run_href(str(record["run_id"]), "../")})
    return items


def violation_rows(sb: SiteBuild, group: Group, chain: str, scenario: str) -> tuple[list[Any], list[dict[str, Any]]]:
    """Per-norm violation rates of one row: one line per (norm, measure), one column per learner."""
    frame = sb.stats.violations if sb.stats is not None else pd.DataFrame()
    if frame.empty:
        return [], []
    part = frame.loc[(frame["protocol"] == group.protocol) & (frame["preset"] == group.preset)
                     & (frame["chain"] == chain) & (frame["scenario"] == scenario)]
    if part.empty:
        return [], []
    learners = [n for n in sb.lb.learners if n in set(part["learner"])]
    lines = []
    for (rank, norm, measure), lines_of in part.groupby(["rank", "norm", "measure"], sort=True):
        by_learner = {r["learner"]: r for r in lines_of.to_dict("records")}
        values = [(clean(by_learner[n]["value"]), int(by_learner[n]["n_runs"])) if n in by_learner else (None, None)
                  for n in learners]
        lines.append({"rank": int(rank), "norm": norm, "label": norm_label(norm), "abbreviation": norm_abbreviation(norm),
                      "measure": measure, "cells": values})
    return [(n, sb.colour(n)) for n in learners], lines


def scenario_context(sb: SiteBuild, scenario: str) -> dict[str, Any]:
    spec, variant_names = variant_specs(scenario)
    first = next(iter(spec.variants)) if spec is not None else None
    variants = None
    if spec is not None:
        variants = [{"name": name, "env_id": spec.env_id(name),
                     "characters": ", ".join(f"{n} {t}" for t, n in zip(variant.types, variant.amounts)),
                     "relevant": [(norm_label(n), norm_abbreviation(n)) for n in variant.relevant]}
                    for name, variant in spec.variants.items()]
    sections = []
    newest = newest_own_group(sb.lb)
    for group in display_order(sb.lb):
        for chain, scen in sb.lb.pairs(group):
            if scen != scenario:
                continue
            radar = sb.figures.radars.get((group, chain, scenario))
            violation_learners, violations = violation_rows(sb, group, chain, scenario)
            row_figures = sb.row_figures.get((group, chain, scenario), {})
            sections.append({
                "id": section_id(group, chain), "chain": chain, "chain_title": chain_title(chain),
                "group_label": group.label, "whose": whose_runs(sb.lb, group, newest),
                "not_comparable": "" if comparable_preset(group.preset) else not_comparable_text(group.preset),
                "summary": summary_rows(sb, group, chain, scenario),
                "radar": f"figures/{group.slug}/{radar.name}" if radar is not None else None,
                "curves": row_figures.get("curves"), "curves_note": row_figures.get("curves_note", ""),
                "tradeoff": row_figures.get("tradeoff"),
                "violation_learners": violation_learners, "violations": violations,
                "breakdown": breakdown(sb, group, chain, scenario, variant_names),
                "gifs": gif_items(sb, group, chain, scenario),
            })
    return sb.common(scenario, "../", "") | {
        "scenario": scenario,
        "summary": spec.summary if spec is not None and spec.summary else "",
        "layout_img": sb.layouts.get(scenario), "layout_note": sb.layout_notes.get(scenario, ""),
        "first_variant": first,
        "picture": "\n".join(spec.picture(first)) if spec is not None else None,
        "variants": variants, "sections": sections, "bold_rule": BOLD_RULE,
        "downloads_list": sb.downloads_of("scenario"),
    }
