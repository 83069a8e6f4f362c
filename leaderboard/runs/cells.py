"""The numbers of Table 1 and of the per-norm and per-variant figures, from the counted runs (part of
:mod:`leaderboard.runs.aggregate`): each cell's mean and spread over seeds, how complete it is, its
comparison with the paper, the best of each row, and the group a build shows first.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from functools import cache
from typing import Any

import numpy as np
import pandas as pd

from leaderboard.runs.display_order import Group, chain_norm_order, group_order, learner_order, paper_values, row_order
from leaderboard.runs.reference_rows import (
    ORACLE_BEST,
    ORACLE_WORST,
    RANDOM_EXACT,
    REFERENCE_LEARNERS,
    covered_variants,
    reference_coverage,
    reference_key,
    reference_mean,
)
from leaderboard.runs.selection import CELL_KEYS, LLM_POLICY_KIND, UNKNOWN, cell_of, mf_columns
from morality_gym.constants import BETA, MAX_STEPS
from morality_gym.envs.registry import UnknownEnvError, scenario_named
from morality_gym.results.identity import SUBMITTED_ALGO
from morality_gym.results.presets import Preset, PresetError, load_preset, preset_seeds
from morality_gym.results.schema import MF_PREFIX

#: "Standard deviation over three seeds": the sample standard deviation (n - 1 in the denominator).
STD_DDOF = 1
#: Exactly the columns of ``results/table1.csv`` (readers select by name; this is the contract).
#: ``n_variants``/``n_seeds``: distinct variants/seeds among the cell's results, out of
#: ``n_variants_expected``/``n_seeds_expected``; ``complete``: every expected (variant, seed) has a
#: result; ``incomplete_reason``: what is lacking (empty when complete). Reference rows are exact
#: over all variants (``complete`` true, seed columns empty). ``ci_low``/``ci_high``: the 95% bootstrap
#: interval of the mean (whole seeds resampled, each with all its variants; empty with one seed and on reference
#: rows), joined by :mod:`leaderboard.outputs.intervals` (empty when the table was built without it);
#: ``ci_low_mcse``/``ci_high_mcse``: the Monte Carlo standard error of each bound (how far another
#: bootstrap seed would move it; the Markdown, LaTeX and site print a bound only to the decimals it
#: is stable to, :mod:`leaderboard.outputs.precision`).
#: ``ci_kind``: "bootstrap" (the bounds are a 95% interval) or "seed range" (too few seeds for a
#: bootstrap to be an interval: the bounds are the lowest and highest per-seed mean, exact);
#: ``seed_means``: the per-seed means in seed order, ``;``-separated; ``borderline``: the paper's
#: value lies within 3 Monte Carlo standard errors of a bound (give or take its rounding), so whether it
#: "meets the interval" is the bootstrap seed's call (``leaderboard.stats.cells.at_bound``).
#: ``delta_note``: why ``delta`` is empty although ``paper`` is not (``not comparable: preset smoke``,
#: ``not compared: incomplete``), or that the cell trained for another budget than its preset's
#: (``not comparable: trained 2,048 steps``, a submission, with or without a paper value);
#: empty when the delta is given or there is no paper value.
CSV_COLUMNS = ["chain", "scenario", "learner", "mean", "std", "ci_low", "ci_high", "ci_low_mcse", "ci_high_mcse",
               "ci_kind", "seed_means", "borderline", "n_runs", "paper", "delta",
               "n_variants", "n_variants_expected", "n_seeds", "n_seeds_expected", "complete", "incomplete_reason",
               "delta_note"]
#: The preset whose budget is the paper's (conf/preset/paper.yaml). A learner trained at any other
#: budget is not compared with the paper: a smoke cell's 2,048 steps against the paper's 1M read as
#: a deviation of the code when they are one of the budget (issue 36).
PAPER_PRESET = "paper"
#: Presets whose learners' numbers mean nothing (conf/preset/smoke.yaml: "2,048 steps teach
#: nothing, so only Random's numbers mean anything"): no learner of theirs is marked best.
NO_BEST_PRESETS = frozenset({"smoke"})
#: The decimals a mean is printed with on the site and in table1.md: ties are judged at them.
SHOWN_DIGITS = 3
COMPLETENESS_COLUMNS = ["n_variants", "n_variants_expected", "n_seeds", "n_seeds_expected", "n_expected", "complete",
                        "incomplete_reason"]
_TOLERANCE = 1e-12


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
        frame[column] = frame[column].astype(object).where(frame[column].notna(), UNKNOWN)
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
    records = [facts.get(cell_of(r), _no_facts()) for r in frame[CELL_KEYS].to_dict("records")]
    for column in COMPLETENESS_COLUMNS:
        frame[column] = [r[column] for r in records]
    frame["complete"] = frame["complete"].astype(bool)
    off = off_budgets(runs)
    frame["off_budget"] = [off.get(cell_of(r), 0) for r in frame[CELL_KEYS].to_dict("records")]
    return frame


@cache
def _preset(name: str) -> Preset | None:
    try:
        return load_preset(name)
    except PresetError:
        return None


def preset_budget(preset: str, scenario: str) -> int | None:
    """The budget ``conf/preset/<preset>.yaml`` gives ``scenario`` (None: no such preset)."""
    loaded = _preset(str(preset))
    return None if loaded is None else loaded.budget_for(str(scenario))


def off_budgets(runs: pd.DataFrame) -> dict[tuple[str, ...], int]:
    """Per cell, a budget its runs trained for that is not their preset's (absent: none).

    Why: a submitted policy (the torch example at ``--total-steps 2048``) lands in the ``paper``
    preset's grid, beside 1M-step baselines and the paper's values (issue 45); its preset says
    nothing of what it trained for, its recorded budget does. A budget of 0 is a policy not
    trained here, or of an unknown budget (a rule, a language model): nothing to compare."""
    if "budget" not in runs.columns or runs.empty:
        return {}
    ok = runs.loc[runs["ok"] & (pd.to_numeric(runs["budget"], errors="coerce").fillna(0) > 0)]
    out: dict[tuple[str, ...], int] = {}
    for record in ok[CELL_KEYS + ["budget"]].to_dict("records"):
        expected = preset_budget(record["preset"], record["scenario"])
        if expected is not None and int(record["budget"]) != expected:
            out.setdefault(cell_of(record), int(record["budget"]))
    return out


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
    """How complete each learner cell is (see the module docstring), keyed like :func:`cell_of`.

    Expected grid = every variant of the scenario x (the preset's seeds + the seeds the cell's
    sweeps planned + the seeds of its runs). ``complete``: a usable result for every point of it.
    """
    plans = _by_cell(planned.values())
    records = _by_cell(runs[CELL_KEYS + ["variant", "seed", "ok", "run_id"]].to_dict("records"))
    own_seeds = sampling_seeds(runs)
    seeds_of_preset: dict[str, set[int]] = {}
    out: dict[tuple[str, ...], dict[str, Any]] = {}
    for cell in set(plans) | set(records):
        preset = cell[1]
        if preset not in seeds_of_preset:
            seeds_of_preset[preset] = expected_seeds(preset, planned.values())
        seeds = own_seeds.get(cell, seeds_of_preset[preset])
        out[cell] = _cell_completeness(cell[3], records.get(cell, []), plans.get(cell, []), seeds)
    return out


def sampling_seeds(runs: pd.DataFrame) -> dict[tuple[str, ...], set[int]]:
    """The cells of language-model entries, each with the sampling seeds its entry asked for.

    Why not the preset's seeds: a language-model entry (``python -m leaderboard.llm``) trains
    nothing; its seeds are those of its episodes, ``seed`` to ``seed + episodes - 1`` of its run
    config. A greedy model in the deterministic environment plays every episode of a variant alike
    (tests/test_llm_column.py), so its column plays one episode per variant, and the cell is
    complete with it; held to the preset's three training seeds it would read "1/3 seeds" for ever.
    """
    if runs.empty or "config" not in runs.columns or "algo" not in runs.columns:
        return {}
    out: dict[tuple[str, ...], set[int]] = {}
    part = runs.loc[runs["algo"].astype(object) == SUBMITTED_ALGO]
    for record in part[CELL_KEYS + ["config"]].to_dict("records"):
        policy = _llm_policy(record["config"])
        if policy is None:
            continue
        first, episodes = _seed(policy.get("seed")), _seed(policy.get("episodes_per_variant"))
        if first is not None and episodes is not None and episodes > 0:
            out.setdefault(cell_of(record), set()).update(range(first, first + episodes))
    return out


def _llm_policy(config: Any) -> dict[str, Any] | None:
    """A run config's policy when it is a language model's (``policy.kind == "llm"``), else None."""
    try:
        policy = (json.loads(config) if isinstance(config, str) else {}).get("policy")
    except (ValueError, AttributeError):
        return None
    return policy if isinstance(policy, dict) and policy.get("kind") == LLM_POLICY_KIND else None


def _by_cell(items: Iterable[Mapping[str, Any]]) -> dict[tuple[str, ...], list[Mapping[str, Any]]]:
    """Runs or plans grouped by :func:`cell_of`, in their order."""
    out: dict[tuple[str, ...], list[Mapping[str, Any]]] = {}
    for item in items:
        out.setdefault(cell_of(item), []).append(item)
    return out


def _cell_completeness(scenario: str, cell_runs: list[Mapping[str, Any]], cell_plans: list[Mapping[str, Any]],
                       preset_seeds: set[int]) -> dict[str, Any]:
    """One cell's row of :func:`completeness`: its expected grid against the runs that succeeded."""
    variants, seeds = _expected_axes(scenario, [*cell_runs, *cell_plans], preset_seeds)
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
        reason = (f"{have} of {len(expected)} runs ({n_variants}/{len(variants)} variants, "
                  f"{n_seeds}/{len(seeds)} seeds{_lacking(expected, ok, failed, missing)})")
    return {"n_variants": n_variants, "n_variants_expected": len(variants), "n_seeds": n_seeds,
            "n_seeds_expected": len(seeds), "n_expected": len(expected), "complete": complete,
            "incomplete_reason": reason}


def _expected_axes(scenario: str, items: list[Mapping[str, Any]], preset_seeds: set[int]) -> tuple[list[str], set[int]]:
    """The cell's expected variants (the scenario's, else those its runs and plans name) and seeds."""
    variants = scenario_variants(scenario)
    if variants is None:
        variants = sorted({str(x["variant"]) for x in items if x.get("variant") is not None})
    seeds = set(preset_seeds)
    seeds |= {s for s in (_seed(x.get("seed")) for x in items) if s is not None}
    return variants, seeds


def _lacking(expected: set, ok: set, failed: set, missing: set) -> str:
    """``; 2 failed; 1 missing; 3 never planned`` for the expected points without a result ("" if none)."""
    lacking = [f"{len(failed & expected)} failed" if failed & expected else "",
               f"{len(missing & expected)} missing" if missing & expected else "",
               (f"{len(expected - ok - failed - missing)} never planned" if expected - ok - failed - missing else "")]
    detail = "; ".join(x for x in lacking if x)
    return "; " + detail if detail else ""


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
        rows += _reference_rows(rows, runs, reference)
    if not rows:
        return pd.DataFrame(columns=[*CELL_KEYS, "kind", "mean", "std", "n_runs", "n_planned", "n_failed", "n_missing",
                                     "beta", "max_steps", *COMPLETENESS_COLUMNS, "paper", "delta", "delta_note", "best"])
    return _sort_table(_with_paper(pd.DataFrame(rows), published))


def _reference_rows(rows: list[dict[str, Any]], runs: pd.DataFrame,
                    reference: Mapping[str, Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Random (exact), Oracle best and Oracle worst for every learner row's settings, over the
    variants its cells cover (none where a cell covers a variant the chain cannot score)."""
    out = []
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
            out.append({
                "protocol": protocol, "preset": preset, "chain": chain, "scenario": scenario,
                "learner": learner, "kind": "reference",
                "mean": reference_mean(entry, field_name, variants), "std": math.nan,
                "n_runs": pd.NA, "n_planned": pd.NA, "n_failed": pd.NA, "n_missing": pd.NA,
                "beta": beta, "max_steps": steps,
                "n_variants": len(variants), "n_variants_expected": n_all, "n_seeds": pd.NA,
                "n_seeds_expected": pd.NA, "n_expected": pd.NA, "complete": len(variants) == n_all,
                "incomplete_reason": reason,
            })
    return out


def _with_paper(frame: pd.DataFrame, published: Mapping[tuple[str, str], Mapping[str, float]]) -> pd.DataFrame:
    """The paper's value and the delta to it (complete cells only), typed counts, and the best flags."""
    paper = []
    for chain, scenario, learner in zip(frame["chain"], frame["scenario"], frame["learner"]):
        lookup = "Random" if learner == RANDOM_EXACT else learner
        paper.append(published.get((chain, scenario), {}).get(lookup, math.nan))
    frame["paper"] = pd.Series(paper, index=frame.index, dtype=float)
    frame["complete"] = frame["complete"].astype(bool)
    if "off_budget" not in frame.columns:
        frame["off_budget"] = 0
    frame["off_budget"] = frame["off_budget"].fillna(0).astype(int)
    frame["delta_note"] = [delta_note(r) for r in frame[["kind", "preset", "complete", "paper", "off_budget"]].to_dict("records")]
    # Compared only where the runs are the paper's: complete, and trained at the paper's budget.
    frame["delta"] = (frame["mean"].astype(float) - frame["paper"]).where(frame["delta_note"] == "", math.nan)
    for column in ("n_runs", "n_planned", "n_failed", "n_missing", "n_variants", "n_variants_expected", "n_seeds",
                   "n_seeds_expected", "n_expected"):
        frame[column] = frame[column].astype("Int64")
    frame["incomplete_reason"] = frame["incomplete_reason"].fillna("").astype(str)
    frame["best"] = _best_flags(frame)
    return frame


def comparable_preset(preset: str) -> bool:
    """Whether a learner trained at ``preset`` may be compared with the paper (its budget is the paper's)."""
    return str(preset) == PAPER_PRESET


def not_comparable_text(preset: str) -> str:
    """The mark of a cell, table or sweep whose budget is not the paper's."""
    return f"not comparable: preset {preset}"


def off_budget_text(budget: int) -> str:
    """The mark of a cell whose runs trained for another budget than their preset's (:func:`off_budgets`)."""
    return f"not comparable: trained {budget:,} steps"


def delta_note(cell: Mapping[str, Any]) -> str:
    """Why a cell with a paper value gets no delta ("" when it gets one, or has no paper value).

    A cell trained for another budget than its preset's (a submission, ``off_budget``) is marked
    whether or not it has a paper value of its own: the paper's values and the release's 1M-step
    baselines sit beside it in its row. Reference rows are exact computations with no training
    budget (Random (exact) is the expectation of the paper's Random at any preset), so only
    completeness could stop them."""
    if cell.get("kind", "learner") == "learner" and comparable_preset(cell["preset"]) and int(cell.get("off_budget") or 0):
        return off_budget_text(int(cell["off_budget"]))
    if math.isnan(float(cell["paper"])):
        return ""
    if cell.get("kind", "learner") == "learner" and not comparable_preset(cell["preset"]):
        return not_comparable_text(cell["preset"])
    if not bool(cell["complete"]):
        return "not compared: incomplete"
    return ""


def _best_flags(frame: pd.DataFrame) -> pd.Series:
    """The highest mean among the row's *complete* learner cells that mean something (issue 45):
    none in a preset whose learners learn nothing (:data:`NO_BEST_PRESETS`), none for a cell trained
    at another budget than its row's (``off_budget``). Ties are all best, at the digits the pages
    print (:data:`SHOWN_DIGITS`): 0.8071 and 0.8068 both read 0.807, so both are outlined or neither."""
    learners = (frame["kind"] == "learner") & frame["complete"] & ~frame["preset"].astype(str).isin(NO_BEST_PRESETS)
    if "off_budget" in frame.columns:
        learners &= frame["off_budget"].fillna(0).astype(int) == 0
    best = pd.Series(False, index=frame.index)
    if not learners.any():
        return best
    shown = frame.loc[learners, "mean"].astype(float).round(SHOWN_DIGITS)
    row_max = shown.groupby([frame.loc[learners, k] for k in ("protocol", "preset", "chain", "scenario")]).transform("max")
    best.loc[learners] = (shown >= row_max - _TOLERANCE) & shown.notna()
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
