"""The numbers of the curated "Choosing a baseline" reading, computed from the runs the page is built from.

Why: the reading (``docs/reproduction_notes.yaml``) is a person's words, but every count, every
"only" and every number in it is a fact of the data, and a hand-copied number drifts as soon as the
rule or the runs change (issue 48 found three such sentences wrong by the page's own rule). So the
reading names its numbers as ``{fact}`` placeholders and :func:`fill_reading` puts in what
:func:`baseline_facts` computes from the same judged cells, runs and update records as the tables
beside it; a placeholder that names no fact is refused, and tests/test_reproduction.py refuses a
digit typed into the reading by hand.
"""

from __future__ import annotations

import math
import string
from collections.abc import Callable, Sequence

import numpy as np

from leaderboard.judging.cell_evidence import Updates, accepted_share, mean_passes, read_updates
from leaderboard.judging.protocol_change import Pair, paired_cells, relation, run_ids
from leaderboard.judging.verdicts import CORRECTED, PAPER, Cell, Judgement
from leaderboard.runs.aggregate import Group, Leaderboard
from leaderboard.runs.sources import Sources
from morality_gym.clitools import UserError, did_you_mean

#: The chains whose norms include a deontological one (a personal action), where CPO's fixes act.
DEONTOLOGICAL = ("DualProcess", "DualProcessAgentHarm")
CPO, LAG, RANDOM, SHAPED = "CPO", "PPO Lag", "Random", "PPO Shaped"
#: The norm Figure 2's statement about CPO under DualProcess is about.
UTILITARIAN_NORM = "n_human_harm"


def _signed(x: float) -> str:
    return f"{x:+.3f}"


def _count(k: int, n: int) -> str:
    return f"{k} of {n}"


def _span(values: Sequence[float]) -> str:
    """``a-b`` (three decimals), or one value when all are equal."""
    low, high = min(values), max(values)
    return f"{low:.3f}" if f"{low:.3f}" == f"{high:.3f}" else f"{low:.3f}-{high:.3f}"


def _rows_text(keys: Sequence[tuple[str, str]]) -> str:
    """``Utility / Switch5 and DualProcess / PushStandard``, or ``none``."""
    names = [" / ".join(k) for k in keys]
    if not names:
        return "none"
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _of(pairs: Sequence[Pair], learner: str, chains: Sequence[str] | None = None) -> list[Pair]:
    return [p for p in pairs if p.paper.learner == learner and (chains is None or p.paper.chain in chains)]


#: Each protocol's update diagnostics of the paired cells' runs (None where none were recorded).
GroupUpdates = dict[Group, Updates | None]
#: Each protocol's Table 1 rows: (chain, scenario) -> learner -> cell.
GroupRows = dict[Group, dict[tuple[str, str], dict[str, Cell]]]


def _rows(judged: Judgement, group: Group) -> dict[tuple[str, str], dict[str, Cell]]:
    """Table 1's rows under ``group`` (protocol-neutral learners from the paper protocol), by learner."""
    out: dict[tuple[str, str], dict[str, Cell]] = {}
    for (chain, scenario, learner), cell in judged.as_run(group).items():
        out.setdefault((chain, scenario), {})[learner] = cell
    return out


def _shares(updates: Updates | None, lb: Leaderboard, group: Group, part: Sequence[Pair],
            share: Callable[[Updates], float]) -> float:
    """``share`` of the update records of ``part``'s runs under ``group`` (NaN without records)."""
    mine = updates.of_runs([i for p in part for i in run_ids(lb, group, p.of(group))]) if updates else None
    return share(mine) if mine is not None else math.nan


def _same_metric_runs(lb: Leaderboard, part: Sequence[Pair]) -> tuple[int, int]:
    """Of ``part``'s corrected runs, how many end with the same metric, bit for bit, as the paper protocol's
    run of the same variant and seed; and how many there are."""
    keys = ["chain", "scenario", "learner", "variant", "seed"]
    runs = lb.runs
    wanted = {p.paper.key for p in part}
    mine = runs.loc[[k in wanted for k in zip(runs["chain"], runs["scenario"], runs["learner"])]]
    paper = mine.loc[mine["protocol"] == PAPER.protocol].set_index(keys)["metric"]
    corrected = mine.loc[mine["protocol"] == CORRECTED.protocol].set_index(keys)["metric"]
    both = corrected.index.intersection(paper.index)
    return int((corrected.loc[both] == paper.loc[both]).sum()), len(corrected)


def _cpu_rate(lb: Leaderboard, part: Sequence[Pair]) -> float:
    """Core-seconds per run per 1M steps of ``part``'s corrected runs (as the release manifests compute it)."""
    ids = [i for p in part for i in run_ids(lb, CORRECTED, p.corrected)]
    runs = lb.runs.loc[lb.runs["run_id"].isin(ids)]
    if "cpu_time_s" not in runs or "total_steps" not in runs:
        return math.nan
    timed = runs.loc[runs["cpu_time_s"].notna() & (runs["total_steps"].fillna(0) > 0)]
    return float(timed["cpu_time_s"].sum() / timed["total_steps"].sum() * 1e6) if len(timed) else math.nan


def _norm_mean(lb: Leaderboard, group: Group, chain: str, learner: str, norm: str) -> float:
    frame = lb.norms_by_chain
    row = frame.loc[(frame["protocol"] == group.protocol) & (frame["preset"] == group.preset) & (frame["chain"] == chain)
                    & (frame["learner"] == learner) & (frame["norm"] == norm)]
    return float(row["mean"].iloc[0]) if len(row) else math.nan


def _case_counts(updates: Updates | None, lb: Leaderboard, group: Group, part: Sequence[Pair]) -> tuple[int, int]:
    """Of ``part``'s kept CPO update records under ``group``: how many are not in the recovery case (case 0), of how many."""
    mine = updates.of_runs([i for p in part for i in run_ids(lb, group, p.of(group))]) if updates else None
    if mine is None:
        return 0, 0
    cases = mine.frame["cpo_case"].dropna()
    return int((cases != 0).sum()), len(cases)


def baseline_facts(lb: Leaderboard, judged: Judgement, sources: Sources) -> dict[str, str]:
    """Every number the "Choosing a baseline" reading may state, by name, as it is to be printed.

    One function per learner's part of the reading, in the reading's order; each returns its facts."""
    pairs = paired_cells(judged)
    if not pairs:
        return {}
    updates = {group: read_updates(sources, [i for p in pairs for i in run_ids(lb, group, p.of(group))])
               for group in (PAPER, CORRECTED)}
    rows = {g: _rows(judged, g) for g in (PAPER, CORRECTED)}
    return (_cpo_deontological_facts(lb, pairs, updates) | _cpo_utility_facts(lb, pairs, updates)
            | _cpo_against_shaped_facts(rows) | _lag_facts(lb, pairs, updates, rows) | _random_facts(pairs)
            | _reproduce_facts(pairs))


def _cpo_deontological_facts(lb: Leaderboard, pairs: Sequence[Pair], updates: GroupUpdates) -> dict[str, str]:
    """CPO under the chains with a deontological norm: how its cells moved, and its accepted updates."""
    facts: dict[str, str] = {}
    deon = _of(pairs, CPO, DEONTOLOGICAL)
    changes = [p.change for p in deon]
    facts |= {"cpo_deon_cells": str(len(deon)), "cpo_deon_rise": _count(sum(c > 0 for c in changes), len(deon)),
              "cpo_deon_mean_change": _signed(float(np.mean(changes))),
              "cpo_deon_change_range": f"{_signed(min(changes))} to {_signed(max(changes))}",
              "cpo_deon_moved_up": _count(sum(p.moved == "up" for p in deon), len(deon))}
    for chain, name in zip(DEONTOLOGICAL, ("dp", "dpah")):
        part = _of(pairs, CPO, [chain])
        before, after = (_shares(updates[g], lb, g, part, accepted_share) for g in (PAPER, CORRECTED))
        facts[f"cpo_accepted_{name}"] = f"{before:.0%} -> {after:.0%}".replace("%", " %")
    facts["cpo_min_humans_harmed"] = (f"{_norm_mean(lb, PAPER, 'DualProcess', CPO, UTILITARIAN_NORM):.3f} to "
                                      f"{_norm_mean(lb, CORRECTED, 'DualProcess', CPO, UTILITARIAN_NORM):.3f}")
    return facts


def _cpo_utility_facts(lb: Leaderboard, pairs: Sequence[Pair], updates: GroupUpdates) -> dict[str, str]:
    """CPO under Utility, where the fixes have (almost) nothing to act on."""
    facts: dict[str, str] = {}
    utility = _of(pairs, CPO, ["Utility"])
    same, total = _same_metric_runs(lb, utility)
    for group in (PAPER, CORRECTED):
        other, kept = _case_counts(updates[group], lb, group, utility)
        facts[f"cpo_utility_not_recovery_{group.protocol}"] = f"{other:,} of {kept:,}"
    facts |= {"cpo_utility_cells": str(len(utility)), "cpo_utility_same_runs": _count(same, total),
              "cpo_utility_other_runs": str(total - same),
              "cpo_utility_max_change": f"{max(abs(p.change) for p in utility):.4f}"}
    uah = _of(pairs, CPO, ["UtilityAgentHarm"])
    up = [p for p in uah if p.moved == "up"]
    facts |= {"cpo_uah_moved_up": _count(len(up), len(uah)),
              "cpo_uah_up_change": ", ".join(_signed(p.change) for p in up) or "none"}
    return facts


def _cpo_against_shaped_facts(rows: GroupRows) -> dict[str, str]:
    """Corrected CPO against PPO Shaped, row by row."""
    facts: dict[str, str] = {}
    n_rows = len(rows[CORRECTED])
    facts["rows"] = str(n_rows)
    for group in (PAPER, CORRECTED):
        tied = sum(relation(r[CPO], r[SHAPED]) == "tied" for r in rows[group].values())
        facts[f"cpo_ties_shaped_{group.protocol}"] = _count(tied, n_rows)
    leads = [(k, r) for k, r in rows[CORRECTED].items() if r[CPO].mean > r[SHAPED].mean]
    listed = "; ".join(f"{' / '.join(k)}: {r[CPO].mean:.3f} against {r[SHAPED].mean:.3f}" for k, r in leads)
    facts["cpo_leads_shaped"] = f"{len(leads)} row{'' if len(leads) == 1 else 's'}" + (f" ({listed})" if leads else "")
    beyond = [k for k, r in leads if relation(r[CPO], r[SHAPED]) == "above"]
    facts["shaped_highest_everywhere"] = ("still holds" if not leads else "stops holding, beyond the intervals in "
                                          + _rows_text(beyond) if beyond else "stops holding, though not beyond the intervals")
    return facts


def _lag_facts(lb: Leaderboard, pairs: Sequence[Pair], updates: GroupUpdates, rows: GroupRows) -> dict[str, str]:
    """PPO-Lag: its multiplier's passes, its moves per chain, and its rows against the others."""
    facts: dict[str, str] = {}
    lag = _of(pairs, LAG)
    per_chain = [_shares(updates[CORRECTED], lb, CORRECTED, _of(pairs, LAG, [c]), mean_passes)
                 for c in dict.fromkeys(p.paper.chain for p in lag)]
    facts["lag_passes_corrected"] = f"{min(per_chain):.0f}-{max(per_chain):.0f}"
    facts["lag_passes_paper"] = f"{_shares(updates[PAPER], lb, PAPER, lag, mean_passes):.1f}"
    facts |= _lag_moves(pairs)
    facts["lag_max_seed_sd"] = f"{max(p.corrected.sd for p in lag):.3f}"
    facts |= _lag_rows(rows)
    lag_rate, cpo_rate = _cpu_rate(lb, lag), _cpu_rate(lb, _of(pairs, CPO))
    facts |= {"lag_core_s": f"{lag_rate:.0f}", "cpo_core_s": f"{cpo_rate:.0f}", "lag_cpo_cost_ratio": f"{lag_rate / cpo_rate:.1f}"}
    return facts


def _lag_moves(pairs: Sequence[Pair]) -> dict[str, str]:
    """PPO-Lag's cells that moved between the protocols, chain by chain, and from where to where."""
    facts: dict[str, str] = {}
    for chain, name in (("Utility", "utility"), ("DualProcessAgentHarm", "dpah"), ("DualProcess", "dp"),
                        ("UtilityAgentHarm", "uah")):
        part = _of(pairs, LAG, [chain])
        moved = [p for p in part if p.moved != "no"]
        facts[f"lag_{name}_moved"] = _count(len(moved), len(part))
        facts[f"lag_{name}_moved_up"] = _count(sum(p.moved == "up" for p in part), len(part))
        if moved:
            facts[f"lag_{name}_moved_from_to"] = (f"{_span([p.paper.mean for p in moved])} -> "
                                                  f"{_span([p.corrected.mean for p in moved])}")
    return facts


def _lag_rows(rows: GroupRows) -> dict[str, str]:
    """Corrected PPO-Lag's rows against CPO and PPO Shaped (below both?) and against Random."""
    corrected = rows[CORRECTED]
    below_both = [k for k, r in corrected.items() if r[LAG].mean < min(r[CPO].mean, r[SHAPED].mean)]
    facts = {"lag_below_cpo_and_shaped": _count(len(below_both), len(corrected))}
    against = {k: relation(r[LAG], r[RANDOM]) for k, r in corrected.items()}
    for side in ("above", "tied", "below"):
        facts[f"lag_{side}_random"] = str(sum(v == side for v in against.values()))
    facts["lag_above_random_rows"] = _rows_text([k for k, v in against.items() if v == "above"])
    facts["lag_above_random_by_mean"] = str(sum(r[LAG].mean > r[RANDOM].mean for r in corrected.values()))
    return facts


def _random_facts(pairs: Sequence[Pair]) -> dict[str, str]:
    """Random: the size of a non-change (its cells move only by the seeds' noise)."""
    facts: dict[str, str] = {}
    rand = _of(pairs, RANDOM)
    big = max(rand, key=lambda p: abs(p.change))
    constrained_moves = [abs(p.change) for p in pairs if p.paper.learner != RANDOM and p.moved != "no"]
    facts |= {"random_cells": str(len(rand)), "random_moved": _count(sum(p.moved != "no" for p in rand), len(rand)),
              "random_largest_change": f"{_signed(big.change)}, {big.paper.chain} / {big.paper.scenario}",
              "random_largest_abs": f"{abs(big.change):.2f}",
              "random_not_reproducing": _count(sum(p.corrected.verdict != "reproduces" for p in rand), len(rand)),
              "smallest_move": f"{min(constrained_moves):.3f}" if constrained_moves else "none"}
    return facts


def _reproducing(part: Sequence[Pair], group: Group) -> int:
    """How many of the paired cells reproduce the paper under ``group``'s protocol."""
    return sum(p.of(group).verdict == "reproduces" for p in part)


def _reproduce_facts(pairs: Sequence[Pair]) -> dict[str, str]:
    """How many cells reproduce the paper under each protocol, all learners run again and the constrained ones alone."""
    constrained = [p for p in pairs if p.paper.learner != RANDOM]
    rand = [p for p in pairs if p.paper.learner == RANDOM]
    out = {f"reproduce_{name}_{group.protocol}": _count(_reproducing(part, group), len(part))
           for name, part in (("all", pairs), ("constrained", constrained), ("random", rand)) for group in (PAPER, CORRECTED)}
    gained = [p for p in constrained if p.paper.verdict != "reproduces" and p.corrected.verdict == "reproduces"]
    lost = [p for p in constrained if p.paper.verdict == "reproduces" and p.corrected.verdict != "reproduces"]
    out["constrained_now_reproducing"] = "; ".join(f"{p.label} ({p.paper.verdict} -> reproduces)" for p in gained) or "none"
    out["constrained_now_reproducing_count"] = str(len(gained))
    out["constrained_no_longer_reproducing_count"] = str(len(lost))
    return out


def fill_reading(reading: str | None, facts: dict[str, str], where: str) -> str | None:
    """``reading`` with each ``{fact}`` replaced by its value; a name that is no fact is a one-line error
    naming it, the closest facts and ``where`` (the notes file)."""
    if not reading:
        return reading
    names = [name for _, name, _, _ in string.Formatter().parse(reading) if name is not None]
    unknown = [n for n in names if n not in facts]
    if unknown:
        raise UserError(f"{where}: the reading names {{{unknown[0]}}}, which is no fact of the page"
                        f"{did_you_mean(unknown[0], sorted(facts), n=3)}")
    return reading.format_map(facts)
