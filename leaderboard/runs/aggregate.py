"""From run rows to the numbers of Table 1, the per-norm figures and the status report.

Everything here except :func:`compute_reference` is a pure function of the runs DataFrame (as
:func:`morality_gym.results.schema.read_runs` returns it) and the planned runs of the sweep manifests (as
:func:`morality_gym.results.manifest.planned_runs` returns them). The aggregation rules are those of the
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
hash without env and seed, :func:`morality_gym.results.identity.config_key`): the one planned by the most recently
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

The work is split by job: :mod:`leaderboard.runs.selection` decides which runs count (and reports
the rest), :mod:`leaderboard.runs.cells` computes the cells of Table 1 and the figures' frames,
:mod:`leaderboard.runs.reference_rows` the rows computed from the environments, and
:mod:`leaderboard.runs.display_order` the order and names shown. This module puts them together
(:func:`aggregate`, :class:`Leaderboard`) and re-exports their names, so readers import from here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import pandas as pd

from leaderboard.runs.cells import (
    COMPLETENESS_COLUMNS,
    CSV_COLUMNS,
    PAPER_PRESET,
    STD_DDOF,
    choose_primary,
    comparable_preset,
    completeness,
    csv_rows,
    expected_seeds,
    group_stats,
    learner_cells,
    norm_long,
    norm_summary,
    not_comparable_text,
    row_settings,
    scenario_variants,
    seed_spread,
    table1_frame,
    variant_frame,
)
from leaderboard.runs.display_order import (
    Group,
    chain_norm_order,
    group_order,
    learner_order,
    paper_rows,
    paper_values,
    preset_rank,
    row_order,
    safe_name,
)
from leaderboard.runs.reference_rows import (
    ORACLE_BEST,
    ORACLE_WORST,
    RANDOM_EXACT,
    REFERENCE_CACHE_VERSION,
    REFERENCE_LEARNERS,
    ReferenceResult,
    chain_definitions,
    compute_reference,
    covered_variants,
    load_reference_cache,
    reference_coverage,
    reference_key,
    reference_mean,
    reference_requests,
)
from leaderboard.runs.selection import (
    CELL_KEYS,
    LLM_POLICY_KIND,
    REPORT_COLUMNS,
    SLOT_KEYS,
    chain_label,
    groups_of,
    label_planned,
    mf_columns,
    missing_runs,
    prepare_runs,
    problem_runs,
    select_configurations,
    split_superseded,
    submitted_learners,
)
from morality_gym.results.identity import PROVENANCE_KEY, SUBMITTED_ALGO

#: Every name readers import from here; the pieces live in the modules above, each with one job.
__all__ = [
    "CELL_KEYS",
    "COMPLETENESS_COLUMNS",
    "CSV_COLUMNS",
    "LLM_POLICY_KIND",
    "ORACLE_BEST",
    "ORACLE_WORST",
    "PAPER_PRESET",
    "PROVENANCE_KEY",
    "RANDOM_EXACT",
    "REFERENCE_CACHE_VERSION",
    "REFERENCE_LEARNERS",
    "REPORT_COLUMNS",
    "SLOT_KEYS",
    "STD_DDOF",
    "SUBMITTED_ALGO",
    "Group",
    "Leaderboard",
    "ReferenceResult",
    "aggregate",
    "chain_definitions",
    "chain_label",
    "chain_norm_order",
    "choose_primary",
    "comparable_preset",
    "completeness",
    "compute_reference",
    "covered_variants",
    "csv_rows",
    "expected_seeds",
    "group_order",
    "group_stats",
    "groups_of",
    "label_planned",
    "learner_cells",
    "learner_order",
    "load_reference_cache",
    "mf_columns",
    "missing_runs",
    "norm_long",
    "norm_summary",
    "not_comparable_text",
    "paper_rows",
    "paper_values",
    "prepare_runs",
    "preset_rank",
    "problem_runs",
    "reference_coverage",
    "reference_key",
    "reference_mean",
    "reference_requests",
    "row_order",
    "row_settings",
    "safe_name",
    "scenario_variants",
    "seed_spread",
    "select_configurations",
    "split_superseded",
    "submitted_learners",
    "table1_frame",
    "variant_frame",
    "with_reference",
]


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
