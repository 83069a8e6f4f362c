"""Which runs count (part of :mod:`leaderboard.runs.aggregate`, whose docstring states the rules).

Prepares the runs DataFrame, labels chains by what they are, keeps one configuration per cell and
one run per slot (the others are *superseded*), and lists what cannot count: runs without a usable
result (*problems*) and planned runs without a result (*missing*); also who submitted which entry.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from leaderboard.runs.display_order import Group, group_order
from morality_gym.norms.chain import builtin_chains, chain_fingerprint
from morality_gym.results.identity import (  # a run's identity: defined there
    PROVENANCE_KEY,
    SUBMITTED_ALGO,
    configuration_key,
)
from morality_gym.results.schema import MF_PREFIX

#: ``config["policy"]["kind"]`` of a submitted language-model episode (``python -m leaderboard.llm``).
LLM_POLICY_KIND = "llm"
#: The protocol or preset of a run or plan that records none: such runs form their own group.
UNKNOWN = "unknown"


# ---------------------------------------------------------------------------------------- runs
def prepare_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """A copy of the runs with the columns the aggregation relies on made dependable.

    Adds ``ok`` (status ``ok`` and a finite metric), fills an absent protocol or preset with
    ``"unknown"`` (so such runs form their own group instead of vanishing from a groupby) and
    turns ``relevant_norms`` into tuples (Parquet lists arrive as numpy arrays or None).
    """
    df = runs.copy()
    for column in ("run_id", "status", "error", "traceback", "env_id", "scenario", "variant", "chain", "learner",
                   "protocol", "preset", "gif_path", "config"):
        if column not in df.columns:
            df[column] = None
    for column in ("seed", "metric", "beta", "max_steps"):
        if column not in df.columns:
            df[column] = np.nan
    if "relevant_norms" not in df.columns:
        df["relevant_norms"] = None
    df["protocol"] = df["protocol"].astype(object).where(df["protocol"].notna(), UNKNOWN)
    df["preset"] = df["preset"].astype(object).where(df["preset"].notna(), UNKNOWN)
    df["relevant_norms"] = [_as_tuple(value) for value in df["relevant_norms"]]
    facts = [_config_facts(config, run_id) for config, run_id in zip(df["config"], df["run_id"])]
    df["config_key"] = [key for key, _ in facts]
    df["chain_key"] = [fingerprint for _, fingerprint in facts]
    df["chain"] = [chain_label(name, fingerprint) for name, fingerprint in zip(df["chain"], df["chain_key"])]
    metric = pd.to_numeric(df["metric"], errors="coerce")
    df["metric"] = metric
    df["ok"] = (df["status"].astype(object) == "ok") & np.isfinite(metric.to_numpy(dtype=float, na_value=np.nan))
    return df


def _config_facts(config: Any, run_id: Any) -> tuple[str, str | None]:
    """(configuration key, chain fingerprint) of a run from its recorded config JSON.

    A run without a readable config is its own configuration (it is never merged with others).
    """
    try:
        data = json.loads(config) if isinstance(config, str) else None
    except ValueError:
        data = None
    if not isinstance(data, dict):
        return f"run:{run_id}", None
    chain = data.get("chain")
    fingerprint = None
    if isinstance(chain, dict) and isinstance(chain.get("norms"), list):
        try:
            fingerprint = chain_fingerprint(chain["norms"])
        except (TypeError, ValueError):
            fingerprint = None
    return configuration_key(data), fingerprint


def chain_label(name: Any, fingerprint: str | None) -> Any:
    """The name a chain is shown and grouped under: its own, unless it takes a built-in chain's
    name for other norms; then ``<name>~<fingerprint>``, so it never passes for the built-in one."""
    if not isinstance(fingerprint, str) or not isinstance(name, str):  # pandas 3 turns a None beside strings into NaN
        return name

    builtin = builtin_chains().get(name)
    if builtin is not None and builtin.fingerprint != fingerprint:
        return f"{name}~{fingerprint[:8]}"
    return name


def _as_tuple(value: Any) -> tuple[str, ...]:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ()
    return tuple(str(v) for v in value)


def mf_columns(runs: pd.DataFrame) -> list[str]:
    """The per-norm morality function columns present (``mf_<norm>``)."""
    return [c for c in runs.columns if str(c).startswith(MF_PREFIX)]


def groups_of(runs: pd.DataFrame, planned: Mapping[str, Mapping[str, Any]]) -> list[Group]:
    """Every (protocol, preset) with a run or a planned run, in display order."""
    found = {Group(str(p), str(s)) for p, s in zip(runs["protocol"], runs["preset"])}
    found |= {Group(str(r.get("protocol") or UNKNOWN), str(r.get("preset") or UNKNOWN)) for r in planned.values()}
    return group_order(found)


# ---------------------------------------------------------------------------------------- superseded
#: What makes two runs compete for one place in the tables (see the module docstring).
SLOT_KEYS = ["protocol", "preset", "chain", "env_id", "learner", "seed", "beta", "max_steps"]
#: The columns that identify a run in every report (failed, missing, superseded).
REPORT_COLUMNS = ["run_id", "protocol", "preset", "chain", "scenario", "variant", "env_id", "learner", "seed"]


def split_superseded(runs: pd.DataFrame, planned: Mapping[str, Any]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(counted, superseded)``: one run per slot is counted, the rest are returned with the id of
    the run that replaces them (``superseded_by``) and their ``finished_at``.

    Preference within a slot: planned by a current sweep manifest (manifests are rewritten by every
    sweep, so they name the configuration that is meant now), then a usable result (``ok``), then
    the latest ``finished_at``, then the run id (so the choice never depends on file order).
    """
    if runs.empty:
        return runs, runs.assign(superseded_by=pd.Series(dtype=object)).iloc[0:0]
    df = runs.copy()
    finished = df["finished_at"] if "finished_at" in df.columns else pd.Series([None] * len(df), index=df.index)
    df["_planned"] = df["run_id"].isin(set(planned))
    df["_finished"] = finished.astype(object).where(finished.notna(), "").astype(str)
    keys = [k for k in SLOT_KEYS if k in df.columns]
    slot = df[keys].astype(str).agg("\x1f".join, axis=1)
    df["_slot"] = slot
    df = df.sort_values(["_slot", "_planned", "ok", "_finished", "run_id"], ascending=[True, False, False, False, True])
    first = ~df["_slot"].duplicated(keep="first")
    winner = df.loc[first].set_index("_slot")["run_id"]
    counted = df.loc[first].drop(columns=["_planned", "_finished", "_slot"])
    superseded = df.loc[~first].copy()
    superseded["superseded_by"] = superseded["_slot"].map(winner)
    superseded = superseded.drop(columns=["_planned", "_finished", "_slot"])
    return counted.sort_index(), superseded.sort_values(REPORT_COLUMNS[1:] + ["run_id"]).reset_index(drop=True)


# ---------------------------------------------------------------------------------------- configurations
CELL_KEYS = ["protocol", "preset", "chain", "scenario", "learner"]


def cell_of(record: Mapping[str, Any]) -> tuple[str, ...]:
    return tuple(str(record.get(k) if record.get(k) is not None else UNKNOWN) for k in CELL_KEYS)


def label_planned(planned: Mapping[str, Mapping[str, Any]], runs: pd.DataFrame) -> dict[str, dict[str, Any]]:
    """Planned runs with the chain label and configuration key the aggregation groups by.

    A manifest of this version records both; for an older one, a planned run with a result takes
    its result's, and one without takes those of its manifest's other runs in the same cell (a
    sweep plans one configuration per cell), else none: such a plan does not choose the cell's
    configuration, it is counted with whichever is chosen.
    """
    by_run = {str(r): (c, k) for r, c, k in zip(runs["run_id"], runs["chain"], runs["config_key"])}
    out: dict[str, dict[str, Any]] = {}
    for run_id, entry in planned.items():
        item = dict(entry)
        for column in ("protocol", "preset"):
            item[column] = item.get(column) or UNKNOWN
        known = by_run.get(str(run_id))
        if item.get("chain_key"):
            item["chain"] = chain_label(item.get("chain"), str(item["chain_key"]))
        elif known is not None:
            item["chain"] = known[0]
        if not item.get("config_key") and known is not None:
            item["config_key"] = known[1]
        out[str(run_id)] = item
    shared: dict[tuple[Any, ...], set[str]] = {}
    for item in out.values():
        if item.get("config_key"):
            shared.setdefault((item.get("manifest"), cell_of(item)), set()).add(str(item["config_key"]))
    for item in out.values():
        if not item.get("config_key"):
            keys = shared.get((item.get("manifest"), cell_of(item)), set())
            item["config_key"] = next(iter(keys)) if len(keys) == 1 else None  # unknown: joins the cell's choice
    return out


def select_configurations(runs: pd.DataFrame, planned: Mapping[str, Mapping[str, Any]]
                          ) -> tuple[pd.DataFrame, pd.DataFrame, dict[str, dict[str, Any]]]:
    """``(counted, superseded, planned)``: per cell, only the runs and plans of one configuration.

    The configuration of a cell is the one planned by the most recently launched manifest that
    plans anything in the cell; a cell no manifest plans takes the configuration of its newest
    ``ok`` result (then of its newest result). Runs of every other configuration are returned as
    superseded (``superseded_by``: the counted run of the same env and seed, if any), and the plans
    of other configurations are dropped (their runs are not *missing*: they are no longer wanted).
    """
    if runs.empty and not planned:
        return runs, runs.assign(superseded_by=pd.Series(dtype=object)).iloc[0:0], {}
    cells = [cell_of(r) for r in runs[CELL_KEYS].to_dict("records")]
    scores = _configuration_scores(runs, cells, planned)
    winner = {cell: max(options.items(), key=lambda kv: (kv[1], kv[0]))[0] for cell, options in scores.items()}
    keep = pd.Series([str(k) == winner[c] for c, k in zip(cells, runs["config_key"])], index=runs.index, dtype=bool)
    counted = runs.loc[keep]
    superseded = runs.loc[~keep].copy()
    superseded["superseded_by"] = _superseded_by(counted, superseded)
    kept_plans = {rid: item for rid, item in planned.items()
                  if item.get("config_key") is None or str(item["config_key"]) == winner.get(cell_of(item))}
    return counted, superseded, kept_plans


def _configuration_scores(runs: pd.DataFrame, cells: list[tuple[str, ...]], planned: Mapping[str, Mapping[str, Any]]
                          ) -> dict[tuple[str, ...], dict[str, list[str]]]:
    """Per cell and configuration key: ``[planned_at, newest ok, newest any]``, compared as strings
    (ISO times) so that :func:`select_configurations` can take the largest."""
    finished = runs["finished_at"] if "finished_at" in runs.columns else pd.Series([None] * len(runs), index=runs.index)
    finished = finished.astype(object).where(finished.notna(), "").astype(str)
    scores: dict[tuple[str, ...], dict[str, list[str]]] = {}

    def score(cell: tuple[str, ...], key: str) -> list[str]:
        return scores.setdefault(cell, {}).setdefault(key, ["", "", ""])  # planned_at, newest ok, newest any

    for cell, key, ok, when in zip(cells, runs["config_key"], runs["ok"], finished):
        entry = score(cell, str(key))
        entry[2] = max(entry[2], when)
        if ok:
            entry[1] = max(entry[1], when)
    for item in planned.values():
        if item.get("config_key") is None:
            continue
        entry = score(cell_of(item), str(item["config_key"]))
        entry[0] = max(entry[0], str(item.get("planned_at") or ""))
    return scores


def _superseded_by(counted: pd.DataFrame, superseded: pd.DataFrame) -> list[Any]:
    """For each superseded run, the counted run of the same env, seed and cell (None if there is none)."""
    by_slot = {(str(e), str(sd), c): r for e, sd, c, r in zip(counted["env_id"], counted["seed"],
                                                              [cell_of(x) for x in counted[CELL_KEYS].to_dict("records")],
                                                              counted["run_id"])}
    return [by_slot.get((str(e), str(sd), c)) for e, sd, c in zip(
        superseded["env_id"], superseded["seed"], [cell_of(x) for x in superseded[CELL_KEYS].to_dict("records")])]


# ---------------------------------------------------------------------------------------- submissions
def submitted_learners(runs: pd.DataFrame) -> dict[str, str]:
    """``{learner: note}`` for the learners whose counted runs were submitted (``algo == "submitted"``).

    The note names the submitters and the policy hash(es) as recorded in the runs' configs, so the
    page can say whose policy an entry is.
    """
    if "algo" not in runs.columns or runs.empty:
        return {}
    out: dict[str, tuple[set[str], set[str]]] = {}
    part = runs.loc[runs["algo"].astype(object) == SUBMITTED_ALGO]
    for learner, config in zip(part["learner"], part["config"]):
        who, hashes = out.setdefault(str(learner), (set(), set()))
        _add_submission_facts(config, who, hashes)
    return {learner: _submission_note(who, hashes) for learner, (who, hashes) in out.items()}


def _add_submission_facts(config: Any, who: set[str], hashes: set[str]) -> None:
    """Add a submitted run's submitter and policy identity (file hash, or model and settings) from its config JSON."""
    try:
        data = json.loads(config) if isinstance(config, str) else {}
    except ValueError:
        data = {}
    prov = data.get(PROVENANCE_KEY) if isinstance(data, dict) else None
    policy = data.get("policy") if isinstance(data, dict) else None
    if isinstance(prov, dict) and prov.get("submitter"):
        who.add(str(prov["submitter"]))
    if isinstance(policy, dict) and policy.get("sha256"):
        hashes.add(str(policy["sha256"])[:12])
    if isinstance(policy, dict) and policy.get("kind") == LLM_POLICY_KIND:  # python -m leaderboard.llm: no file to hash
        hashes.add(f"language model {policy.get('model')}, framing {policy.get('framing')}, "
                   f"temperature {policy.get('temperature')}")


def _submission_note(who: set[str], hashes: set[str]) -> str:
    """``external policy submitted by ...; policy sha256 ...`` (a language model is named, not hashed)."""
    return (f"external policy submitted by {', '.join(sorted(who)) or 'unknown'}"
            + (f"; {'; '.join(sorted(hashes))}" if any(h.startswith("language") for h in hashes)
               else f"; policy sha256 {', '.join(sorted(hashes))}" if hashes else ""))


# ---------------------------------------------------------------------------------------- problems


def problem_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """Runs that produced a row but no usable result, with the reason (never dropped silently).

    ``status == "failed"`` carries the runner's error and traceback; a row that says ``ok`` but has
    no finite metric, or has another status, is reported with a reason made up here.
    """
    bad = runs.loc[~runs["ok"]].copy()
    reasons = []
    for status, error in zip(bad["status"], bad["error"]):
        if isinstance(error, str) and error.strip():
            reasons.append(error.strip())
        elif status == "ok":
            reasons.append("status 'ok' but the metric is missing or not finite")
        else:
            reasons.append(f"status {status!r} without an error message")
    bad["error"] = reasons
    bad["status"] = bad["status"].astype(object).where(bad["status"].notna(), "(none)")
    columns = REPORT_COLUMNS + ["status", "error", "traceback"]
    return bad[columns].sort_values(["protocol", "preset", "chain", "scenario", "learner", "variant", "seed"]).reset_index(drop=True)


def missing_runs(runs: pd.DataFrame, planned: Mapping[str, Mapping[str, Any]]) -> pd.DataFrame:
    """Planned runs (from the manifests) without any result file."""
    present = set(runs["run_id"].astype(object))
    rows = [dict(run) for run_id, run in planned.items() if run_id not in present]
    frame = pd.DataFrame(rows, columns=REPORT_COLUMNS + ["algo"])
    for column in ("protocol", "preset"):
        frame[column] = frame[column].astype(object).where(frame[column].notna(), UNKNOWN)
    return frame[REPORT_COLUMNS].sort_values(REPORT_COLUMNS[1:] + ["run_id"]).reset_index(drop=True)
