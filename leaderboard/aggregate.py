"""From run rows to the numbers of Table 1, the per-norm figures and the status report.

Everything here except :func:`compute_reference` is a pure function of the runs DataFrame (as
:func:`runners.results_schema.read_runs` returns it) and the planned runs of the sweep manifests (as
:func:`runners.manifest.planned_runs` returns them). The aggregation rules are those of the
evaluation spec, section 7:

* Table 1 cell = arithmetic mean of the final evaluation's ``metric`` over every run (all variants
  and seeds) of (chain, scenario, learner); its spread = standard deviation over seeds of the
  per-seed means (each seed's mean over the variants).
* Figure 2 bar of a norm = mean of ``mf_<norm>`` over the (scenario, variant, seed) runs in which
  the norm is relevant for the chain (column ``relevant_norms``), spread as above; the radar plots
  are the same restricted to one scenario.

A results directory may hold several sweeps, so every number is grouped by ``(protocol, preset)``.
Nothing is ever dropped silently: a planned run without a result is *missing*, a run whose status
is not ``ok`` (or that has no metric) is a *problem*, and both are returned for the report.

A results directory also outlives configurations: rerun a sweep after changing a hyper-parameter
and the old runs (other config, so other run ids) stay on disk beside the new ones. Averaging both
into one cell would mix two algorithms under one label, so a cell counts the runs of **one
configuration** only (:func:`select_configurations`; the configuration key is the run config's
hash without env and seed, :func:`runners.identity.config_key`): the one planned by the most recently
launched sweep manifest, else the one with the newest result. Within it each *slot* (protocol,
preset, chain, env id, learner, seed, beta, max_steps) counts one run. All other runs are
*superseded*: reported, never counted. Chains are told apart by what they are (their norms, order
and modalities), not by their name: runs of a chain that takes a built-in chain's name for other
norms are labelled ``<name>~<fingerprint>`` and never pass for the built-in chain.

Every learner cell says how **complete** it is (:func:`learner_cells`): results present out of
the expected grid of (variant, seed), where the variants are all of the scenario's and the seeds
the preset's (as recorded by the sweep manifests, else ``conf/preset``), plus any seed a sweep
planned or ran for the cell. An incomplete cell keeps its mean (so the table shows what exists)
but is never the best of its row and is never compared with the paper (no delta); the reason is
in ``incomplete_reason``.
"""

from __future__ import annotations

import json
import math
import os
import re
import tempfile
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from functools import cache, cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from morality_gym.constants import BETA, MAX_STEPS
from morality_gym.envs.registry import UnknownEnvError, parse_env_id, scenario_named
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.oracle import oracle
from morality_gym.norms.chain import ChainError, builtin_chains, chain_fingerprint, get_chain, parse_chain
from morality_gym.paper import LEARNERS, table1
from runners.config_schema import PresetError, load_preset, preset_names
from runners.identity import PROVENANCE_KEY, SUBMITTED_ALGO, configuration_key  # a run's identity: defined there
from runners.paths import preset_seeds
from runners.results_schema import MF_PREFIX

#: "Standard deviation over three seeds": the sample standard deviation (n - 1 in the denominator).
STD_DDOF = 1
#: Exactly the columns of ``results/table1.csv`` (readers select by name; this is the contract).
#: ``n_variants``/``n_seeds``: distinct variants/seeds among the cell's results, out of
#: ``n_variants_expected``/``n_seeds_expected``; ``complete``: every expected (variant, seed) has a
#: result; ``incomplete_reason``: what is lacking (empty when complete). Reference rows are exact
#: over all variants (``complete`` true, seed columns empty). ``ci_low``/``ci_high``: the 95% bootstrap
#: interval of the mean (seeds resampled within each variant; empty with one seed and on reference
#: rows), joined by :mod:`leaderboard.intervals` (empty when the table was built without it).
CSV_COLUMNS = ["chain", "scenario", "learner", "mean", "std", "ci_low", "ci_high", "n_runs", "paper", "delta",
               "n_variants", "n_variants_expected", "n_seeds", "n_seeds_expected", "complete", "incomplete_reason"]
COMPLETENESS_COLUMNS = ["n_variants", "n_variants_expected", "n_seeds", "n_seeds_expected", "n_expected", "complete",
                        "incomplete_reason"]
#: Rows computed from the environments rather than from runs (see :func:`compute_reference`).
RANDOM_EXACT, ORACLE_BEST, ORACLE_WORST = "Random (exact)", "Oracle best", "Oracle worst"
REFERENCE_LEARNERS = (RANDOM_EXACT, ORACLE_BEST, ORACLE_WORST)
#: Bump when the content of the reference cache changes meaning (old entries are then recomputed).
REFERENCE_CACHE_VERSION = 2  # 2: entries record the chain's norms and the variants it cannot score
#: ``config["policy"]["kind"]`` of a submitted language-model episode (``python -m leaderboard.llm``).
LLM_POLICY_KIND = "llm"
_UNKNOWN = "unknown"
_TOLERANCE = 1e-12


# ---------------------------------------------------------------------------------------- groups
@dataclass(frozen=True, order=True)
class Group:
    """One sweep setting in a results directory: its protocol and preset."""

    protocol: str
    preset: str

    @property
    def slug(self) -> str:
        """A file-name-safe identifier, used for figure folders and HTML ids."""
        return safe_name(f"{self.protocol}-{self.preset}")

    @property
    def label(self) -> str:
        return f"protocol {self.protocol}, preset {self.preset}"


def safe_name(text: str) -> str:
    """``text`` with every character outside ``[A-Za-z0-9._-]`` replaced, for file names.

    Run ids are content hashes and scenario names identifiers, so this changes nothing for real
    data; it exists so that a hostile or odd name can never escape the output directory.
    """
    cleaned = re.sub(r"[^A-Za-z0-9._-]", "_", str(text)).lstrip(".")
    return cleaned or "_"


# ---------------------------------------------------------------------------------------- ordering
def paper_rows() -> list[tuple[str, str]]:
    """The (chain, scenario) rows of the paper's Table 1, in the paper's order."""
    return [(row.chain, row.scenario) for row in table1()]


def paper_values() -> dict[tuple[str, str], dict[str, float]]:
    """Published Table 1 numbers by (chain, scenario), then learner."""
    return {(row.chain, row.scenario): dict(row.paper) for row in table1()}


def learner_order(learners: Iterable[str]) -> list[str]:
    """The paper's learners in the paper's order, then any others alphabetically."""
    found = set(learners)
    return [name for name in LEARNERS if name in found] + sorted(found - set(LEARNERS))


def row_order(pairs: Iterable[tuple[str, str]]) -> list[tuple[str, str]]:
    """(chain, scenario) pairs: the paper's rows in its order first, then the rest sorted."""
    found = set(pairs)
    known = [pair for pair in paper_rows() if pair in found]
    return known + sorted(found - set(known))


def chain_norm_order(chain: str) -> list[str]:
    """The chain's norms, highest force first (the x axis of Figure 2); [] for an unknown chain."""
    try:
        return get_chain(chain).norm_names
    except ChainError:
        return []


@cache
def preset_rank() -> dict[str, int]:
    """The display rank of each preset of ``conf/preset``: the one that trains most first (the paper's,
    then quick, then smoke), read from the preset files; a file that does not load is left out."""
    budgets = {}
    for name in preset_names():
        try:
            budgets[name] = load_preset(name).budget
        except PresetError:
            continue
    return {name: rank for rank, name in enumerate(sorted(budgets, key=lambda n: (-budgets[n], n)))}


def group_order(groups: Iterable[Group]) -> list[Group]:
    """Protocol ``paper`` before others, then the presets of ``conf/preset`` by :func:`preset_rank`
    (paper > quick > smoke), then other presets by name."""
    rank = preset_rank()
    return sorted(set(groups), key=lambda g: (g.protocol != "paper", g.protocol, rank.get(g.preset, len(rank)), g.preset))


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
    df["protocol"] = df["protocol"].astype(object).where(df["protocol"].notna(), _UNKNOWN)
    df["preset"] = df["preset"].astype(object).where(df["preset"].notna(), _UNKNOWN)
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
    found |= {Group(str(r.get("protocol") or _UNKNOWN), str(r.get("preset") or _UNKNOWN)) for r in planned.values()}
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


def _cell_of(record: Mapping[str, Any]) -> tuple[str, ...]:
    return tuple(str(record.get(k) if record.get(k) is not None else _UNKNOWN) for k in CELL_KEYS)


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
            item[column] = item.get(column) or _UNKNOWN
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
            shared.setdefault((item.get("manifest"), _cell_of(item)), set()).add(str(item["config_key"]))
    for item in out.values():
        if not item.get("config_key"):
            keys = shared.get((item.get("manifest"), _cell_of(item)), set())
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
    finished = runs["finished_at"] if "finished_at" in runs.columns else pd.Series([None] * len(runs), index=runs.index)
    finished = finished.astype(object).where(finished.notna(), "").astype(str)
    scores: dict[tuple[str, ...], dict[str, list[str]]] = {}

    def score(cell: tuple[str, ...], key: str) -> list[str]:
        return scores.setdefault(cell, {}).setdefault(key, ["", "", ""])  # planned_at, newest ok, newest any

    cells = [_cell_of(r) for r in runs[CELL_KEYS].to_dict("records")]
    for cell, key, ok, when in zip(cells, runs["config_key"], runs["ok"], finished):
        entry = score(cell, str(key))
        entry[2] = max(entry[2], when)
        if ok:
            entry[1] = max(entry[1], when)
    for item in planned.values():
        if item.get("config_key") is None:
            continue
        entry = score(_cell_of(item), str(item["config_key"]))
        entry[0] = max(entry[0], str(item.get("planned_at") or ""))
    winner = {cell: max(options.items(), key=lambda kv: (kv[1], kv[0]))[0] for cell, options in scores.items()}
    keep = pd.Series([str(k) == winner[c] for c, k in zip(cells, runs["config_key"])], index=runs.index, dtype=bool)
    counted = runs.loc[keep]
    superseded = runs.loc[~keep].copy()
    by_slot = {(str(e), str(sd), c): r for e, sd, c, r in zip(counted["env_id"], counted["seed"],
                                                              [_cell_of(x) for x in counted[CELL_KEYS].to_dict("records")],
                                                              counted["run_id"])}
    superseded["superseded_by"] = [by_slot.get((str(e), str(sd), c)) for e, sd, c in zip(
        superseded["env_id"], superseded["seed"], [_cell_of(x) for x in superseded[CELL_KEYS].to_dict("records")])]
    kept_plans = {rid: item for rid, item in planned.items()
                  if item.get("config_key") is None or str(item["config_key"]) == winner.get(_cell_of(item))}
    return counted, superseded, kept_plans


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
    return {learner: (f"external policy submitted by {', '.join(sorted(who)) or 'unknown'}"
                      + (f"; {'; '.join(sorted(hashes))}" if any(h.startswith("language") for h in hashes)
                         else f"; policy sha256 {', '.join(sorted(hashes))}" if hashes else ""))
            for learner, (who, hashes) in out.items()}


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
        frame[column] = frame[column].astype(object).where(frame[column].notna(), _UNKNOWN)
    return frame[REPORT_COLUMNS].sort_values(REPORT_COLUMNS[1:] + ["run_id"]).reset_index(drop=True)


# ---------------------------------------------------------------------------------------- statistics
def seed_spread(values: pd.Series, seeds: pd.Series) -> float:
    """Standard deviation over seeds of the per-seed means (NaN with fewer than two seeds)."""
    per_seed = values.groupby(seeds.to_numpy()).mean()
    return float(per_seed.std(ddof=STD_DDOF)) if len(per_seed) > STD_DDOF else math.nan


def group_stats(frame: pd.DataFrame, keys: list[str], column: str, count_name: str) -> pd.DataFrame:
    """Per group of ``keys``: mean of ``column``, its spread over seeds (:func:`seed_spread`) and the row count."""
    rows = [dict(zip(keys, key)) | {"mean": float(part[column].mean()), "std": seed_spread(part[column], part["seed"]),
                                    count_name: len(part)}
            for key, part in frame.groupby(keys, dropna=False)]
    return pd.DataFrame(rows, columns=keys + ["mean", "std", count_name])


# ---------------------------------------------------------------------------------------- table 1


def _expected_runs(runs: pd.DataFrame, planned: Mapping[str, Mapping[str, Any]]) -> pd.DataFrame:
    """One row per run id that was planned or produced, with its cell key (for the n/N counts)."""
    rows: dict[str, dict[str, Any]] = {}
    for run_id, run in planned.items():
        rows[run_id] = {k: run.get(k) for k in CELL_KEYS} | {"run_id": run_id}
    for record in runs[CELL_KEYS + ["run_id"]].to_dict("records"):
        rows[record["run_id"]] = record
    frame = pd.DataFrame(list(rows.values()), columns=CELL_KEYS + ["run_id"])
    for column in ("protocol", "preset"):
        frame[column] = frame[column].astype(object).where(frame[column].notna(), _UNKNOWN)
    return frame


def learner_cells(runs: pd.DataFrame, planned: Mapping[str, Mapping[str, Any]]) -> pd.DataFrame:
    """Table 1 cells of the learners, one row per (protocol, preset, chain, scenario, learner).

    Columns: the keys, ``mean``, ``std``, ``n_runs`` (runs with a result), ``n_planned`` (planned or
    produced), ``n_failed``, ``n_missing``. A cell whose runs are all missing or failed is kept,
    with a NaN mean, so that the table shows the hole.
    """
    expected = _expected_runs(runs, planned)
    counts = expected.groupby(CELL_KEYS, dropna=False).size().rename("n_planned")
    failed = runs.loc[~runs["ok"]].groupby(CELL_KEYS, dropna=False).size().rename("n_failed")
    frame = group_stats(runs.loc[runs["ok"]], CELL_KEYS, "metric", "n_runs").set_index(CELL_KEYS)
    frame = frame.join(counts, how="outer").join(failed, how="left").reset_index()
    frame["n_runs"] = frame["n_runs"].fillna(0).astype(int)
    frame["n_failed"] = frame["n_failed"].fillna(0).astype(int)
    frame["n_planned"] = frame["n_planned"].fillna(frame["n_runs"]).astype(int)
    frame["n_missing"] = (frame["n_planned"] - frame["n_runs"] - frame["n_failed"]).clip(lower=0).astype(int)
    facts = completeness(runs, planned)
    records = [facts.get(_cell_of(r), _no_facts()) for r in frame[CELL_KEYS].to_dict("records")]
    for column in COMPLETENESS_COLUMNS:
        frame[column] = [r[column] for r in records]
    frame["complete"] = frame["complete"].astype(bool)
    return frame


def _seed(value: Any) -> int | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return int(number) if math.isfinite(number) else None


def _no_facts() -> dict[str, Any]:
    return {"n_variants": 0, "n_variants_expected": 0, "n_seeds": 0, "n_seeds_expected": 0, "n_expected": 0,
            "complete": False, "incomplete_reason": "no run planned or produced"}


def scenario_variants(scenario: str) -> list[str] | None:
    """The variants of a registered scenario, in table order (None if it is not registered here)."""
    try:
        return list(scenario_named(scenario).variants)
    except (UnknownEnvError, KeyError):
        return None


def expected_seeds(preset: str, planned: Iterable[Mapping[str, Any]]) -> set[int]:
    """The preset's seeds: as the manifests of this preset record them, else ``conf/preset/<preset>.yaml``."""
    recorded: set[int] = set()
    for item in planned:
        if str(item.get("preset")) == preset and isinstance(item.get("preset_seeds"), list):
            recorded |= {s for s in map(_seed, item["preset_seeds"]) if s is not None}
    return recorded or set(preset_seeds(preset) or ())


def completeness(runs: pd.DataFrame, planned: Mapping[str, Mapping[str, Any]]) -> dict[tuple[str, ...], dict[str, Any]]:
    """How complete each learner cell is (see the module docstring), keyed like :func:`_cell_of`.

    Expected grid = every variant of the scenario x (the preset's seeds + the seeds the cell's
    sweeps planned + the seeds of its runs). ``complete``: a usable result for every point of it.
    """
    plans: dict[tuple[str, ...], list[Mapping[str, Any]]] = {}
    for item in planned.values():
        plans.setdefault(_cell_of(item), []).append(item)
    records: dict[tuple[str, ...], list[Mapping[str, Any]]] = {}
    for record in runs[CELL_KEYS + ["variant", "seed", "ok", "run_id"]].to_dict("records"):
        records.setdefault(_cell_of(record), []).append(record)
    seeds_of_preset: dict[str, set[int]] = {}
    out: dict[tuple[str, ...], dict[str, Any]] = {}
    for cell in set(plans) | set(records):
        preset, scenario = cell[1], cell[3]
        if preset not in seeds_of_preset:
            seeds_of_preset[preset] = expected_seeds(preset, planned.values())
        cell_runs, cell_plans = records.get(cell, []), plans.get(cell, [])
        variants = scenario_variants(scenario)
        if variants is None:
            variants = sorted({str(x["variant"]) for x in [*cell_runs, *cell_plans] if x.get("variant") is not None})
        seeds = set(seeds_of_preset[preset])
        seeds |= {s for s in (_seed(x.get("seed")) for x in [*cell_runs, *cell_plans]) if s is not None}
        expected = {(v, s) for v in variants for s in seeds}
        ok = {(str(r["variant"]), _seed(r["seed"])) for r in cell_runs if r["ok"]}
        failed = {(str(r["variant"]), _seed(r["seed"])) for r in cell_runs if not r["ok"]} - ok
        produced = {str(r["run_id"]) for r in cell_runs}
        missing = {(str(p.get("variant")), _seed(p.get("seed"))) for p in cell_plans
                   if str(p.get("run_id")) not in produced} - ok - failed
        have = len(ok & expected)
        complete = bool(expected) and have == len(expected)
        n_variants = len({v for v, _ in ok})
        n_seeds = len({s for _, s in ok})
        reason = ""
        if not complete:
            lacking = [f"{len(failed & expected)} failed" if failed & expected else "",
                       f"{len(missing & expected)} missing" if missing & expected else "",
                       (f"{len(expected - ok - failed - missing)} never planned" if expected - ok - failed - missing else "")]
            detail = "; ".join(x for x in lacking if x)
            reason = (f"{have} of {len(expected)} runs ({n_variants}/{len(variants)} variants, "
                      f"{n_seeds}/{len(seeds)} seeds{'; ' + detail if detail else ''})")
        out[cell] = {"n_variants": n_variants, "n_variants_expected": len(variants), "n_seeds": n_seeds,
                     "n_seeds_expected": len(seeds), "n_expected": len(expected), "complete": complete,
                     "incomplete_reason": reason}
    return out


def row_settings(runs: pd.DataFrame) -> dict[tuple[str, str, str, str], tuple[float, int]]:
    """(beta, max_steps) of each (protocol, preset, chain, scenario): the most common among its runs.

    Reference rows must be computed with the settings the learners were evaluated with.
    """
    out: dict[tuple[str, str, str, str], tuple[float, int]] = {}
    keys = ["protocol", "preset", "chain", "scenario"]
    for key, part in runs.groupby(keys, dropna=False):
        beta = part["beta"].dropna()
        steps = part["max_steps"].dropna()
        out[tuple(key)] = (
            float(beta.mode().iloc[0]) if len(beta) else BETA,  # the paper's settings when no run says otherwise
            int(steps.mode().iloc[0]) if len(steps) else MAX_STEPS,
        )
    return out


def reference_key(chain: str, scenario: str, beta: float, max_steps: int) -> str:
    """The cache key of a reference row: everything its numbers depend on."""
    return f"{chain}|{scenario}|beta={float(beta):g}|max_steps={int(max_steps)}"


def table1_frame(
    runs: pd.DataFrame,
    planned: Mapping[str, Mapping[str, Any]],
    reference: Mapping[str, Mapping[str, Any]] | None = None,
) -> pd.DataFrame:
    """All Table 1 rows of every group: learner cells plus, when given, the reference rows.

    Columns: protocol, preset, chain, scenario, learner, kind (``learner`` | ``reference``), mean,
    std, n_runs, n_planned, n_failed, n_missing, the :data:`COMPLETENESS_COLUMNS`, paper, delta
    (= mean - paper, for complete cells only), best (the highest mean among the complete learner
    cells of its (protocol, preset, chain, scenario); ties are all best), beta, max_steps.
    The reference row ``Random (exact)`` is compared with the paper's Random, because that is the
    number it is the exact expectation of.
    """
    cells = learner_cells(runs, planned)
    cells["kind"] = "learner"
    settings = row_settings(runs)
    published = paper_values()
    rows = []
    for record in cells.to_dict("records"):
        beta, steps = settings.get((record["protocol"], record["preset"], record["chain"], record["scenario"]),
                                   (BETA, MAX_STEPS))
        record |= {"beta": beta, "max_steps": steps}
        rows.append(record)
    if reference is not None:
        row_keys = {(r["protocol"], r["preset"], r["chain"], r["scenario"], r["beta"], r["max_steps"]) for r in rows}
        covered = covered_variants(runs)
        for protocol, preset, chain, scenario, beta, steps in sorted(row_keys):
            entry = reference.get(reference_key(chain, scenario, beta, steps))
            if entry is None:
                continue
            every = list(entry.get("variants", {}))
            cells = covered.get((protocol, preset, chain, scenario), {})
            if any(v not in entry["variants"] for vs in cells.values() for v in vs):
                continue  # a cell averages a variant the chain cannot score: no reference is over its variants
            variants = [v for v in every if any(v in vs for vs in cells.values())] or every
            n_all = len(entry.get("env_ids") or every)  # the scenario's variants, scorable by the chain or not
            reason = reference_coverage(variants, n_all, cells)
            for learner, field_name in ((RANDOM_EXACT, "random_exact"), (ORACLE_BEST, "oracle_best"),
                                        (ORACLE_WORST, "oracle_worst")):
                rows.append({
                    "protocol": protocol, "preset": preset, "chain": chain, "scenario": scenario,
                    "learner": learner, "kind": "reference",
                    "mean": reference_mean(entry, field_name, variants), "std": math.nan,
                    "n_runs": pd.NA, "n_planned": pd.NA, "n_failed": pd.NA, "n_missing": pd.NA,
                    "beta": beta, "max_steps": steps,
                    "n_variants": len(variants), "n_variants_expected": n_all, "n_seeds": pd.NA,
                    "n_seeds_expected": pd.NA, "n_expected": pd.NA, "complete": len(variants) == n_all,
                    "incomplete_reason": reason,
                })
    if not rows:
        return pd.DataFrame(columns=[*CELL_KEYS, "kind", "mean", "std", "n_runs", "n_planned", "n_failed", "n_missing",
                                     "beta", "max_steps", *COMPLETENESS_COLUMNS, "paper", "delta", "best"])
    frame = pd.DataFrame(rows)
    paper = []
    for chain, scenario, learner in zip(frame["chain"], frame["scenario"], frame["learner"]):
        lookup = "Random" if learner == RANDOM_EXACT else learner
        paper.append(published.get((chain, scenario), {}).get(lookup, math.nan))
    frame["paper"] = pd.Series(paper, index=frame.index, dtype=float)
    frame["complete"] = frame["complete"].astype(bool)
    # An incomplete cell is never compared with the paper: its mean is over other runs than the paper's.
    frame["delta"] = (frame["mean"].astype(float) - frame["paper"]).where(frame["complete"], math.nan)
    for column in ("n_runs", "n_planned", "n_failed", "n_missing", "n_variants", "n_variants_expected", "n_seeds",
                   "n_seeds_expected", "n_expected"):
        frame[column] = frame[column].astype("Int64")
    frame["incomplete_reason"] = frame["incomplete_reason"].fillna("").astype(str)
    frame["best"] = _best_flags(frame)
    return _sort_table(frame)


def _best_flags(frame: pd.DataFrame) -> pd.Series:
    """The highest mean among the row's *complete* learner cells (ties all best; incomplete: never)."""
    learners = (frame["kind"] == "learner") & frame["complete"]
    best = pd.Series(False, index=frame.index)
    if not learners.any():
        return best
    row_max = frame.loc[learners].groupby(["protocol", "preset", "chain", "scenario"])["mean"].transform("max")
    best.loc[learners] = (frame.loc[learners, "mean"] >= row_max - _TOLERANCE) & frame.loc[learners, "mean"].notna()
    return best.astype(bool)


def _sort_table(frame: pd.DataFrame) -> pd.DataFrame:
    groups = {g: i for i, g in enumerate(group_order(Group(p, s) for p, s in zip(frame["protocol"], frame["preset"])))}
    pairs = {pair: i for i, pair in enumerate(row_order(zip(frame["chain"], frame["scenario"])))}
    learners = {name: i for i, name in enumerate(learner_order(frame.loc[frame["kind"] == "learner", "learner"]))}
    learners |= {name: len(learners) + i for i, name in enumerate(REFERENCE_LEARNERS)}
    key = [
        (groups[Group(p, s)], pairs[(c, sc)], learners[lr])
        for p, s, c, sc, lr in zip(frame["protocol"], frame["preset"], frame["chain"], frame["scenario"], frame["learner"])
    ]
    order = sorted(range(len(frame)), key=key.__getitem__)
    return frame.iloc[order].reset_index(drop=True)


def csv_rows(table: pd.DataFrame, group: Group) -> pd.DataFrame:
    """The rows of one group with exactly :data:`CSV_COLUMNS` (what ``table1.csv`` holds)."""
    part = table.loc[(table["protocol"] == group.protocol) & (table["preset"] == group.preset)]
    return part.reindex(columns=CSV_COLUMNS).reset_index(drop=True)


def choose_primary(table: pd.DataFrame, groups: list[Group], protocol: str | None = None,
                   preset: str | None = None) -> Group | None:
    """The group shown first and written to ``table1.csv``.

    An explicit protocol/preset wins; otherwise the group covering the most (chain, scenario) rows
    with results, then protocol ``paper``, then the largest preset (paper > quick > smoke).
    """
    candidates = [g for g in groups if (protocol is None or g.protocol == protocol) and (preset is None or g.preset == preset)]
    if not candidates:
        return None
    done = table.loc[(table["kind"] == "learner") & (table["n_runs"] > 0)]
    coverage = {g: len(done.loc[(done["protocol"] == g.protocol) & (done["preset"] == g.preset),
                                ["chain", "scenario"]].drop_duplicates()) for g in candidates}
    rank = {g: i for i, g in enumerate(group_order(candidates))}
    return min(candidates, key=lambda g: (-coverage[g], rank[g]))


# ---------------------------------------------------------------------------------------- per norm
def norm_long(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per (ok run, norm relevant in that run for its chain) with the norm's function value.

    Only relevant norms enter (spec 7.3), which is why a norm's bar may pool fewer runs than
    another's. A relevant norm without an ``mf_`` value is skipped here (it would be a runner bug
    that the schema validation already prevents).
    """
    ok = runs.loc[runs["ok"]]
    present = set(mf_columns(runs))
    rows = []
    keys = ["protocol", "preset", "chain", "scenario", "variant", "learner", "seed", "run_id"]
    for record in ok.to_dict("records"):
        for norm in record["relevant_norms"]:
            column = f"{MF_PREFIX}{norm}"
            value = record.get(column) if column in present else None
            if value is None or not np.isfinite(value):
                continue
            rows.append({k: record[k] for k in keys} | {"norm": norm, "value": float(value)})
    return pd.DataFrame(rows, columns=keys + ["norm", "value"])


def norm_summary(long: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    """Mean, seed spread and pooled count of the norm values per ``by + [learner, norm]``.

    Columns: ``by``, learner, norm, mean, std, n (pooled rows), rank (the norm's position in its
    chain, highest force first, for plotting in chain order).
    """
    keys = list(by) + ["learner", "norm"]
    frame = group_stats(long, keys, "value", "n")
    order = {chain: chain_norm_order(chain) for chain in frame["chain"].unique()}
    frame["rank"] = [order[c].index(n) if n in order[c] else len(order[c]) for c, n in zip(frame["chain"], frame["norm"])]
    return frame.sort_values(list(by) + ["rank", "norm"]).reset_index(drop=True)


# ---------------------------------------------------------------------------------------- per variant
def variant_frame(runs: pd.DataFrame) -> pd.DataFrame:
    """Metric per (protocol, preset, chain, scenario, variant, learner): mean and std over seeds.

    Also lists the run ids (ordered by seed) so that pages can link every number to its runs.
    """
    keys = ["protocol", "preset", "chain", "scenario", "variant", "learner"]
    rows = []
    ordered = runs.sort_values("seed", kind="stable")  # groups keep this order: run ids come out by seed
    for key, part in ordered.groupby(keys, dropna=False, sort=False):
        good = part.loc[part["ok"]]
        rows.append(dict(zip(keys, key)) | {
            "env_id": str(part["env_id"].dropna().iloc[0]) if part["env_id"].notna().any() else "",
            "mean": float(good["metric"].mean()) if len(good) else math.nan,
            "std": float(good["metric"].std(ddof=STD_DDOF)) if len(good) > STD_DDOF else math.nan,
            "n_runs": len(good),
            "n_failed": int(len(part) - len(good)),
            "run_ids": list(part["run_id"]),
            "seeds": [int(s) for s in part["seed"]],
        })
    return pd.DataFrame(rows, columns=keys + ["env_id", "mean", "std", "n_runs", "n_failed", "run_ids", "seeds"])


# ---------------------------------------------------------------------------------------- reference rows
def reference_mean(entry: Mapping[str, Any], field_name: str, variants: Iterable[str] | None = None) -> float:
    """Mean of one reference quantity over ``variants`` (default: all the scenario's), as Table 1
    averages a cell over its variants: a reference is compared with cells over the same variants."""
    chosen = entry["variants"] if variants is None else {v: entry["variants"][v] for v in variants}
    values = [v[field_name] for v in chosen.values()]
    return float(np.mean(values)) if values else math.nan


def covered_variants(runs: pd.DataFrame) -> dict[tuple[str, str, str, str], dict[str, frozenset[str]]]:
    """The variants each learner cell averages (those of its usable runs), per Table 1 row:
    ``{(protocol, preset, chain, scenario): {learner: variants}}``."""
    out: dict[tuple[str, str, str, str], dict[str, frozenset[str]]] = {}
    usable = runs.loc[runs["ok"]] if len(runs) else runs
    for key, part in usable.groupby(CELL_KEYS, dropna=False):
        *row, learner = key
        out.setdefault(tuple(row), {})[str(learner)] = frozenset(str(v) for v in part["variant"])
    return out


def reference_coverage(variants: list[str], n_all: int, cells: Mapping[str, frozenset[str]]) -> str:
    """Why a reference row is over fewer than all ``n_all`` variants, or covers more than some cell ('' if neither)."""
    notes = []
    if len(variants) < n_all:
        notes.append(f"over the {len(variants)} of {n_all} variants the row's runs cover ({', '.join(variants)})")
    narrower = sorted(learner for learner, vs in cells.items() if vs != set(variants))
    if narrower:
        notes.append(f"cells over other variants: {', '.join(narrower)}")
    return "; ".join(notes)


def reference_requests(table: pd.DataFrame) -> list[tuple[str, str, float, int]]:
    """The distinct (chain, scenario, beta, max_steps) the learner rows need references for."""
    learners = table.loc[table["kind"] == "learner"]
    found = {(c, s, float(b), int(m)) for c, s, b, m in zip(learners["chain"], learners["scenario"],
                                                             learners["beta"], learners["max_steps"])}
    order = {pair: i for i, pair in enumerate(row_order((c, s) for c, s, _, _ in found))}
    return sorted(found, key=lambda r: (order[(r[0], r[1])], r[2], r[3]))


def chain_definitions(runs: pd.DataFrame) -> dict[str, Any]:
    """Each chain of the runs as its runs defined it (a :class:`~morality_gym.norms.chain.MoralityChain`
    from the run config's norms), by name.

    A user's chain (a file given to the sweep) has no built-in name to look up: its reference rows
    are computed from this, the definition the runs were scored with. Runs without a readable
    chain definition are left out (their chain is then looked up by name).
    """
    out: dict[str, Any] = {}
    for config in runs["config"] if "config" in runs.columns else []:
        try:
            chain = json.loads(config)["chain"] if isinstance(config, str) else None
            if chain is None or chain["name"] in out:
                continue
            out[chain["name"]] = parse_chain({"name": chain["name"], "norms": [{"norm": n, "modality": m} for n, m in chain["norms"]]},
                                             source=f"the runs' chain {chain['name']}")
        except (ValueError, KeyError, TypeError, ChainError):
            continue
    return out


def _chain_content(chain: Any) -> list[list[str]] | None:
    return None if isinstance(chain, str) else [[n.name, n.modality] for n in chain.norms]


def _compute_entry(chain: str, scenario: str, beta: float, max_steps: int, definition: Any = None) -> dict[str, Any]:
    chain_or_name = definition if definition is not None else chain
    variants: dict[str, dict[str, Any]] = {}
    unscorable: dict[str, str] = {}
    for env_id in scenario_named(scenario).env_ids:
        try:
            exact = exact_evaluate("random", env_id, chain_or_name, max_steps=max_steps, beta=beta)
        except ChainError as exc:  # a user's chain may fit some variants only; sweeps run it on those
            unscorable[parse_env_id(env_id)[1]] = str(exc)
            continue
        extremes = oracle(env_id, chain_or_name, beta=beta, max_steps=max_steps)
        variants[parse_env_id(env_id)[1]] = {
            "env_id": env_id,
            "random_exact": float(exact.metric),
            "random_functions": {k: float(v) for k, v in exact.functions.items()},
            "oracle_best": float(extremes.best.metric),
            "oracle_worst": float(extremes.worst.metric),
            "oracle_best_actions": list(extremes.best.actions),
            "oracle_worst_actions": list(extremes.worst.actions),
        }
    return {"chain": chain, "scenario": scenario, "beta": beta, "max_steps": max_steps,
            "env_ids": scenario_named(scenario).env_ids, "variants": variants, "unscorable": unscorable,
            "norms": _chain_content(chain_or_name)}


def load_reference_cache(path: Path) -> dict[str, Any]:
    """Entries of the reference cache; an unreadable or outdated cache counts as empty."""
    try:
        body = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(body, dict) or body.get("version") != REFERENCE_CACHE_VERSION:
        return {}
    entries = body.get("entries")
    return entries if isinstance(entries, dict) else {}


def _write_json_atomic(path: Path, body: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(body, fh, indent=1, sort_keys=True)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@dataclass
class ReferenceResult:
    """Reference entries by key, how many came from the cache, and the rows that could not be computed."""

    entries: dict[str, dict[str, Any]] = field(default_factory=dict)
    cached: int = 0
    computed: int = 0
    errors: dict[str, str] = field(default_factory=dict)


def compute_reference(
    requests: list[tuple[str, str, float, int]],
    cache_path: Path,
    progress: Callable[[Iterable[Any], str, int], Iterable[Any]] | None = None,
    chains: Mapping[str, Any] | None = None,
) -> ReferenceResult:
    """Exact Random and oracle best/worst of each requested row, per variant, cached on disk.

    The oracle needs ~10 s for all of Table 1, too slow to repeat on every build, and its result
    depends only on (chain, scenario, beta, max_steps), the chain's norms and the scenario's
    variants, which is what an entry is keyed and checked by. ``chains``: the chains' definitions
    by name (:func:`chain_definitions` of the runs), needed for a user's chain, which has no
    built-in name; a chain not in it is looked up by name. A row that cannot be computed is
    reported in ``errors`` (with the reason) instead of failing the whole build.
    """
    chains = dict(chains or {})

    cache = load_reference_cache(cache_path)
    result = ReferenceResult()
    todo = []
    for chain, scenario, beta, steps in requests:
        key = reference_key(chain, scenario, beta, steps)
        entry = cache.get(key)
        try:
            env_ids = scenario_named(scenario).env_ids
        except KeyError as exc:
            result.errors[key] = str(exc)
            continue
        content = _chain_content(chains[chain]) if chain in chains else None
        if entry is not None and entry.get("env_ids") == env_ids and (content is None or entry.get("norms") == content):
            result.entries[key] = entry
            result.cached += 1
        else:
            todo.append((key, chain, scenario, beta, steps))
    iterator: Iterable[Any] = progress(todo, "reference rows (exact Random, oracle)", len(todo)) if progress and todo else todo
    for key, chain, scenario, beta, steps in iterator:
        try:
            # as the cache will give it back: its JSON sorts the per-variant keys, and a mean summed in
            # another order differs in the last bit, which made a first build's numbers (and the
            # statistics' cache key) differ from every later build's
            entry = _compute_entry(chain, scenario, beta, steps, chains.get(chain))
            result.entries[key] = json.loads(json.dumps(entry, sort_keys=True))
            result.computed += 1
        except Exception as exc:  # noqa: BLE001 - reported per row, the build goes on
            result.errors[key] = f"{type(exc).__name__}: {exc}"
    if result.computed:
        _write_json_atomic(cache_path, {"version": REFERENCE_CACHE_VERSION, "entries": cache | result.entries})
    return result


# ---------------------------------------------------------------------------------------- everything
@dataclass
class Leaderboard:
    """Everything the tables, figures and site are written from."""

    runs: pd.DataFrame
    planned: dict[str, dict[str, Any]]
    table: pd.DataFrame
    problems: pd.DataFrame
    missing: pd.DataFrame
    norms_by_chain: pd.DataFrame
    norms_by_scenario: pd.DataFrame
    variants: pd.DataFrame
    groups: list[Group]
    primary: Group | None
    reference: dict[str, dict[str, Any]] = field(default_factory=dict)
    reference_errors: dict[str, str] = field(default_factory=dict)
    #: Runs on disk that another run of the same slot replaces (not counted; see split_superseded).
    superseded: pd.DataFrame = field(default_factory=pd.DataFrame)
    #: Files the build could not read and left out (``{"file", "reason"}``), and files sweeps moved
    #: to ``runs/.quarantine`` (``{"file", "moved_to", "reason", "at"}``).
    skipped: list[dict[str, str]] = field(default_factory=list)
    quarantined: list[dict[str, str]] = field(default_factory=list)

    @property
    def learners(self) -> list[str]:
        return learner_order(self.table.loc[self.table["kind"] == "learner", "learner"])

    @cached_property
    def submitted(self) -> dict[str, str]:
        """Learners that are submitted external policies, with a note for each (who submitted it)."""
        return submitted_learners(self.runs)

    def group_table(self, group: Group) -> pd.DataFrame:
        t = self.table
        return t.loc[(t["protocol"] == group.protocol) & (t["preset"] == group.preset)].reset_index(drop=True)

    def pairs(self, group: Group | None = None) -> list[tuple[str, str]]:
        t = self.table if group is None else self.group_table(group)
        return row_order(zip(t["chain"], t["scenario"]))

    def reference_entry(self, chain: str, scenario: str, group: Group) -> dict[str, Any] | None:
        rows = self.group_table(group)
        rows = rows.loc[(rows["chain"] == chain) & (rows["scenario"] == scenario)]
        if rows.empty:
            return None
        return self.reference.get(reference_key(chain, scenario, rows["beta"].iloc[0], rows["max_steps"].iloc[0]))

    @property
    def n_ok(self) -> int:
        return int(self.runs["ok"].sum())


def with_reference(lb: Leaderboard, reference: Mapping[str, Mapping[str, Any]], errors: Mapping[str, str],
                   primary_protocol: str | None = None, primary_preset: str | None = None) -> Leaderboard:
    """The leaderboard with reference rows added to its table (only the table depends on them)."""
    table = table1_frame(lb.runs, lb.planned, reference)
    return replace(lb, table=table, reference=dict(reference), reference_errors=dict(errors),
                   primary=choose_primary(table, lb.groups, primary_protocol, primary_preset))


def aggregate(
    runs: pd.DataFrame,
    planned: Mapping[str, Mapping[str, Any]],
    reference: Mapping[str, Mapping[str, Any]] | None = None,
    primary_protocol: str | None = None,
    primary_preset: str | None = None,
) -> Leaderboard:
    """Aggregate runs (+ planned runs, + optional reference entries) into a :class:`Leaderboard`."""
    everything = prepare_runs(runs)
    planned = label_planned(planned, everything)
    chosen, other_config, planned = select_configurations(everything, planned)
    prepared, same_slot = split_superseded(chosen, planned)
    superseded = pd.concat([other_config, same_slot], ignore_index=True, sort=False) if len(other_config) else same_slot
    if len(superseded):
        superseded = superseded.sort_values(REPORT_COLUMNS[1:] + ["run_id"]).reset_index(drop=True)
    gone = set(superseded["run_id"])
    planned = {k: v for k, v in planned.items() if k not in gone}
    table = table1_frame(prepared, planned, reference)
    groups = groups_of(prepared, planned)
    long = norm_long(prepared)
    return Leaderboard(
        runs=prepared,
        planned=planned,
        table=table,
        problems=problem_runs(prepared),
        missing=missing_runs(prepared, planned),
        superseded=superseded,
        norms_by_chain=norm_summary(long, ["protocol", "preset", "chain"]),
        norms_by_scenario=norm_summary(long, ["protocol", "preset", "chain", "scenario"]),
        variants=variant_frame(prepared),
        groups=groups,
        primary=choose_primary(table, groups, primary_protocol, primary_preset),
        reference=dict(reference or {}),
    )
