"""The corrected protocol beside the paper's on docs/reproduction.md: every cell of the learners the
fixes touch under both protocols, and what changes for a researcher choosing a baseline.

Why its own module: the reproduction page's first half judges our runs against the paper; this half
judges one protocol against the other, with its own question (did fixing the reference's arithmetic
bugs move a cell, and does it change which baseline to pick) and its own evidence: how each cell's
variants moved, and what the fixed arithmetic did at the updates (CPO's dual cases, PPO-Lag's passes
and multipliers). A "move" is always one the 95% intervals show, never a difference of means alone.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations

import numpy as np
import pandas as pd

from leaderboard.judging.cell_evidence import (
    Updates,
    accepted_share,
    cpo_case_shares,
    final_multipliers,
    is_cpo,
    is_ppo_lag,
    mean_passes,
    one_pass_share,
    read_updates,
    reference_over,
    updates_summary,
    variant_records,
)
from leaderboard.judging.verdicts import CORRECTED, PAPER, Cell, Judgement, count_verdicts
from leaderboard.runs.aggregate import Group, Leaderboard
from leaderboard.runs.sources import Sources

#: The heading of the section a curated reading (``docs/reproduction_notes.yaml``) may be keyed to.
BASELINE_SECTION = "Choosing a baseline"


def corrected_section(judged: Judgement) -> list[str]:
    """The cells run under the corrected protocol beside the same cells under the paper's.

    The corrected protocol fixes only the reference's arithmetic bugs in the constrained learners
    (``docs/protocols.md``); a cell "moved" when the two protocols' 95% intervals do not overlap,
    which is what tells a reader whether a deviation from the paper comes from those bugs."""
    paper_cells = {c.key: c for c in judged.paper}
    affected = judged.rerun()
    run = [c for c in affected if c.verdict != "not run"]
    lines = ["## The corrected protocol", "",
             ("The `corrected` protocol fixes only the reference's arithmetic bugs in PPO-Lag and CPO "
              "([Protocols](protocols.md)); the other learners train identically under both. Verdicts by the same rule; "
              "**moved** up or down: the two protocols' 95% intervals (with three seeds, the ranges of their per-seed means) "
              "do not overlap."), "",
             (f"{' and '.join(judged.neutral)} train identically under both protocols (the corrected protocol changes none of "
              "their settings), so their cells are the paper protocol's above and are not run again; the corrected "
              f"protocol's Table 1 is the other learners' {len(affected)} cells, of which {len(run)} are run in full."), ""]
    if not run:
        return lines + ["No cell has been run in full under the corrected protocol yet.", ""] + _not_run_lines(affected)
    counts = _verdict_counts(run)
    same_cells = [paper_cells[c.key] for c in run if c.key in paper_cells]
    lines += [(f"**{len(run)} cells run under the corrected protocol: {counts}.** The same cells under the paper "
               f"protocol: {_verdict_counts(same_cells)}."), "",
              ("| chain | scenario | learner | paper protocol | its verdict | corrected | 95% interval, or per-seed means | seed sd | runs | paper "
               "| verdict | moved |"),
              "|---|---|---|---:|---|---:|---|---:|---:|---:|---|---|"]
    for c in run:
        before = paper_cells.get(c.key)
        ran_before = before is not None and before.verdict != "not run"
        lines.append(f"| {c.chain} | {c.scenario} | {c.learner} | {f'{before.mean:.3f}' if ran_before else '—'} | "
                     f"{before.verdict_text if before is not None else 'not run'} | "
                     f"{c.mean:.3f} | {c.interval()} | {c.sd:.3f} | {c.n_runs}/{c.n_expected} | "
                     f"{c.paper:.3f} | {c.verdict_text} | {_moved(before, c) if ran_before else '—'} |")
    return lines + [""] + _not_run_lines(affected)


def _verdict_counts(judged: Sequence[Cell]) -> str:
    """``N reproduce, N are close, N deviate`` over cells that all have a verdict."""
    counts = count_verdicts(judged)
    return (f"{counts['reproduces']} reproduce{'s' if counts['reproduces'] == 1 else ''}, "
            f"{counts['close']} {'is' if counts['close'] == 1 else 'are'} close, "
            f"{counts['deviates']} deviate{'s' if counts['deviates'] == 1 else ''}")


def _not_run_lines(affected: list[Cell]) -> list[str]:
    """The corrected cells not (fully) run yet, with how many of their runs exist: no verdict on them."""
    missing = [c for c in affected if c.verdict == "not run"]
    if not missing:
        return []
    listed = "; ".join(f"{c.chain} / {c.scenario} / {c.learner} ({f'{c.n_runs}/{c.n_expected} runs' if c.n_expected else 'no runs yet'})"
                       for c in missing)
    return [f"*Not yet run in full under the corrected protocol ({len(missing)} of {len(affected)} cells; no verdict):* {listed}.", ""]


def relation(a: Cell, b: Cell) -> str:
    """``above``, ``below`` or ``tied``: whether ``a``'s 95% interval lies wholly above ``b``'s, below it, or overlaps it.

    A gap narrower than two Monte Carlo errors of the two bounds that face each other counts as an
    overlap: the bootstrap draws each protocol's interval from its own random stream, so the same
    runs under both protocols would otherwise "change order" by the bootstrap's noise alone."""
    if a.ci_low - b.ci_high > _noise(a.ci_low_mcse, b.ci_high_mcse):
        return "above"
    if b.ci_low - a.ci_high > _noise(b.ci_low_mcse, a.ci_high_mcse):
        return "below"
    return "tied"


def _noise(*mcse: float) -> float:
    """Two Monte Carlo standard errors of a difference of bounds (an unknown error counts as none)."""
    return 2 * math.hypot(*(0.0 if math.isnan(e) else e for e in mcse))


def _moved(before: Cell, after: Cell) -> str:
    """``up``, ``down`` or ``no``: how ``after`` lies against ``before`` by their 95% intervals."""
    return {"above": "up", "below": "down", "tied": "no"}[relation(after, before)]


@dataclass(frozen=True)
class Pair:
    """One cell of a learner the corrected protocol runs again, run in full under both protocols."""

    paper: Cell
    corrected: Cell

    @property
    def change(self) -> float:
        return self.corrected.mean - self.paper.mean

    @property
    def moved(self) -> str:
        return _moved(self.paper, self.corrected)

    @property
    def label(self) -> str:
        return " / ".join(self.paper.key)

    def of(self, group: Group) -> Cell:
        """The pair's cell under ``group``'s protocol."""
        return self.paper if group == PAPER else self.corrected


def paired_cells(judged: Judgement) -> list[Pair]:
    """The cells of the learners the corrected protocol runs again (:meth:`Judgement.rerun`) that are
    run in full under both protocols, in the paper's order."""
    before = {c.key: c for c in judged.paper}
    out = []
    for c in judged.rerun():
        b = before.get(c.key)
        if c.verdict != "not run" and b is not None and b.verdict != "not run":
            out.append(Pair(b, c))
    return out


def baseline_section(lb: Leaderboard, judged: Judgement, sources: Sources, reading: str | None = None) -> list[str]:
    """What changes for a researcher choosing a baseline when the reference's bugs are fixed.

    In the order a reader asks: the curated answer in plain words (``reading``), how far each learner
    run again moved per chain (Random too: only its evaluation's random stream differs, so it shows
    what no change looks like), whether the order of the five learners changed in any row, what the fixed
    arithmetic did at the updates, and, per cell that moved, where among its variants it moved."""
    lines = [f"## {BASELINE_SECTION} when the bugs are fixed", ""]
    if reading:
        lines += [f"*Our reading:* {reading}", ""]
    pairs = paired_cells(judged)
    if not pairs:
        return lines + ["No cell run again under the corrected protocol is run in full under both yet: nothing to compare.", ""]
    lines += [(f"From the {len(pairs)} of {len(judged.rerun())} cells run in full under both protocols. A cell **moved** when its two "
               "95% intervals (with three seeds, the ranges of their per-seed means: every seed of one protocol beyond every "
               "seed of the other) do not overlap by more than the bootstrap's own noise; a change of the mean alone is not "
               "counted."), ""]
    # each protocol's update records of every paired run, read once and cut per chain and per cell below
    updates = {group: read_updates(sources, [i for p in pairs for i in run_ids(lb, group, p.of(group))])
               for group in (PAPER, CORRECTED)}
    lines += _shift_table(pairs)
    lines += _order_table(judged)
    lines += _updates_tables(lb, pairs, updates)
    lines += _moved_details(lb, pairs, updates)
    return lines


def _shift_table(pairs: Sequence[Pair]) -> list[str]:
    """Per learner run again and chain: how many cells moved up or down, the mean change, the largest one."""
    lines = ["### How far each learner moved", "",
             "| learner | chain | cells | mean change | moved up | moved down | largest change |",
             "|---|---|---:|---:|---:|---:|---|"]
    learners = list(dict.fromkeys(p.paper.learner for p in pairs))
    for learner in learners:
        mine = [p for p in pairs if p.paper.learner == learner]
        chains = list(dict.fromkeys(p.paper.chain for p in mine))
        for chain in [*chains, None]:
            part = [p for p in mine if chain is None or p.paper.chain == chain]
            if chain is None and len(chains) == 1:
                continue
            lines.append(_shift_row(learner, chain, part))
    return lines + [""]


def _shift_row(learner: str, chain: str | None, part: Sequence[Pair]) -> str:
    """One learner's row of :func:`_shift_table` over ``part``, its cells under ``chain`` (None: all chains)."""
    big = max(part, key=lambda p: abs(p.change))
    largest = f"{big.paper.scenario}{'' if chain else f' ({big.paper.chain})'}: {big.paper.mean:.3f} → {big.corrected.mean:.3f}"
    return (f"| {learner} | {chain or '**all chains**'} | {len(part)} | {float(np.mean([p.change for p in part])):+.3f} | "
            f"{sum(p.moved == 'up' for p in part)} | {sum(p.moved == 'down' for p in part)} | {largest} |")


def _best_text(row: dict[str, Cell]) -> str:
    """The row's best learner by mean, and those whose interval overlaps its own (tied with it)."""
    ranked = sorted(row.values(), key=lambda c: -c.mean)
    best = ranked[0]
    tied = [c for c in ranked[1:] if relation(best, c) == "tied"]
    return f"{best.learner} {best.mean:.3f}" + (f" (tied with {', '.join(f'{c.learner} {c.mean:.3f}' for c in tied)})" if tied else "")


def _order_table(judged: Judgement) -> list[str]:
    """Per Table 1 row run in full under both protocols: the best learner under each, and each pair of
    learners whose order (by 95% intervals) the fixes change.

    A pair counts only when one of its two cells moved: two cells that did not move can still swap a
    relation near the boundary by the bootstrap's noise, and that is no change a reader should act on."""
    before, after = judged.as_run(PAPER), judged.as_run(CORRECTED)
    rows: dict[tuple[str, str], list[str]] = {}
    for chain, scenario, learner in before:
        rows.setdefault((chain, scenario), []).append(learner)
    lines = ["### Which learner each row favours", "",
             ("Under each protocol, the row's best learner by mean (tied: its interval overlaps the best one's), and every pair "
              "of learners whose order changes because one of them moved: above or below means the intervals do not overlap, tied "
              "that they do. "
              f"{' and '.join(judged.neutral)} are the same cells under both protocols."), "",
             "| chain | scenario | best, paper protocol | best, corrected | order changes |", "|---|---|---|---|---|"]
    left_out = 0
    for (chain, scenario), learners in rows.items():
        b = {name: before[(chain, scenario, name)] for name in learners}
        a = {name: after[(chain, scenario, name)] for name in learners}
        if any(c.verdict == "not run" for c in [*b.values(), *a.values()]):
            left_out += 1
            continue
        moved = {name for name in learners if _moved(b[name], a[name]) != "no"}
        changes = [f"{x} vs {y}: {relation(b[x], b[y])} → {relation(a[x], a[y])}"
                   for x, y in combinations(learners, 2)
                   if {x, y} & moved and relation(b[x], b[y]) != relation(a[x], a[y])]
        lines.append(f"| {chain} | {scenario} | {_best_text(b)} | {_best_text(a)} | {'; '.join(changes) or 'none'} |")
    if left_out == len(rows):
        return lines[:4] + ["No row is run in full under both protocols yet.", ""]
    if left_out:
        lines += ["", f"*Left out: {left_out} of {len(rows)} rows, not yet run in full under the corrected protocol.*"]
    return lines + [""]


def _updates_tables(lb: Leaderboard, pairs: Sequence[Pair], updates: dict[Group, Updates | None]) -> list[str]:
    """What the fixed arithmetic did at the updates, per chain: PPO-Lag's passes and final multipliers
    (the KL early stop, docs/protocols.md#ppo-lag-kl-early-stop-sums-over-states), CPO's dual cases and accepted steps
    (docs/protocols.md#cpo-uses-omnisafes-dual-solution, docs/protocols.md#cpo-line-search)."""
    lag_rows, cpo_rows, strides = _update_rows(lb, pairs, updates)
    if not lag_rows and not cpo_rows:
        return []
    lines = ["### What the fixes did at the updates", "",
             ("Over the runs of the cells above, per chain and protocol. The paper protocol stops PPO-Lag's epoch after the "
              "first pass on almost every update (its KL early stop sums the KL over the states: "
              "[Protocols](protocols.md#ppo-lag-kl-early-stop-sums-over-states)) and solves CPO's dual problem OmniSafe's way "
              "([Protocols](protocols.md#cpo-uses-omnisafes-dual-solution)); the corrected protocol uses the mean KL and the "
              "exact dual solution."
              + (f" Shares are over the updates the sources keep (a release keeps one in {max(strides)})." if max(strides, default=1) > 1 else "")),
             ""]
    if lag_rows:
        lines += ["| PPO Lag: chain | protocol | cells | runs | passes per update | one pass only | final multiplier, median (range) |",
                  "|---|---|---:|---:|---:|---:|---|", *lag_rows, ""]
    if cpo_rows:
        lines += ["| CPO: chain | protocol | cells | runs | dual cases | line-search step accepted |",
                  "|---|---|---:|---:|---|---:|", *cpo_rows, ""]
    return lines


def _update_rows(lb: Leaderboard, pairs: Sequence[Pair], updates: dict[Group, Updates | None],
                 ) -> tuple[list[str], list[str], set[int]]:
    """The PPO-Lag and CPO rows of :func:`_updates_tables`, per (chain, protocol) with recorded updates,
    and the strides at which the sources kept the updates."""
    lag_rows: list[str] = []
    cpo_rows: list[str] = []
    strides: set[int] = set()
    for learner, chain in dict.fromkeys((p.paper.learner, p.paper.chain) for p in pairs):
        part = [p for p in pairs if (p.paper.learner, p.paper.chain) == (learner, chain)]
        for group in (PAPER, CORRECTED):
            records = updates[group]
            mine = records.of_runs([i for p in part for i in run_ids(lb, group, p.of(group))]) if records else None
            if mine is None:
                continue
            strides.add(mine.stride)
            head = f"| {chain} | {group.protocol} | {len(part)} | {mine.frame['run_id'].nunique()} |"
            if is_ppo_lag(mine):
                lag_rows.append(f"{head} {_lag_update_cells(mine)} |")
            elif is_cpo(mine):
                cpo_rows.append(f"{head} {_cpo_update_cells(mine)} |")
    return lag_rows, cpo_rows, strides


def _lag_update_cells(mine: Updates) -> str:
    """PPO-Lag's update columns: passes per update, the share stopped after one, the final multipliers."""
    final = final_multipliers(mine)
    return (f"{mean_passes(mine):.1f} | {one_pass_share(mine):.0%} | "
            f"{final.median():.3f} ({final.min():.3f}-{final.max():.3f})")


def _cpo_update_cells(mine: Updates) -> str:
    """CPO's update columns: the share of each dual case, and of line-search steps accepted."""
    shares = ", ".join(f"case {case} {share:.0%}" for case, share in cpo_case_shares(mine).items())
    return f"{shares} | {accepted_share(mine):.0%}"


def run_ids(lb: Leaderboard, group: Group, cell: Cell) -> list[str]:
    """The ids of the runs behind ``cell`` under ``group``."""
    mine = variant_records(lb, group, cell.chain, cell.scenario, cell.learner)
    return [i for ids in mine["run_ids"] for i in ids]


def _moved_details(lb: Leaderboard, pairs: Sequence[Pair], updates: dict[Group, Updates | None]) -> list[str]:
    """Per cell that moved: its variants under both protocols and its updates under each, folded."""
    moved = [p for p in pairs if p.moved != "no"]
    if not moved:
        return ["No cell moved: the fixes change no cell beyond its intervals.", ""]
    lines = ["### The cells that moved, variant by variant", "",
             f"{len(moved)} of {len(pairs)} cells moved ({sum(p.moved == 'up' for p in moved)} up). Each folds open.", ""]
    for p in moved:
        lines += [(f'<details markdown="1"><summary>{p.label}: {p.paper.mean:.3f} → {p.corrected.mean:.3f} '
                  f"({p.change:+.3f})</summary>"), ""]
        lines += _variant_pairs(lb, p)
        for group in (PAPER, CORRECTED):
            records = updates[group]
            summary = updates_summary(records.of_runs(run_ids(lb, group, p.of(group))) if records else None)
            if summary:
                lines += ["", f"{group.protocol.capitalize()} protocol: {summary}."]
        lines += ["", "</details>", ""]
    return lines


def _variant_pairs(lb: Leaderboard, pair: Pair) -> list[str]:
    """One row per variant: the mean over seeds (and each seed's run) under both protocols, the oracle
    best, and the change; the largest change first."""
    chain, scenario, learner = pair.paper.chain, pair.paper.scenario, pair.paper.learner
    before = variant_records(lb, PAPER, chain, scenario, learner).set_index("variant")
    after = variant_records(lb, CORRECTED, chain, scenario, learner).set_index("variant")
    refs = reference_over(lb, chain, scenario, list(after.index))
    rows = []
    for variant in after.index:
        was = float(before.loc[variant, "mean"]) if variant in before.index else math.nan
        now = float(after.loc[variant, "mean"])
        rows.append((abs(now - was) if not math.isnan(was) else -1.0,
                     (f"| {variant} | {was:.3f} ({_seeds(lb, before, variant)}) | {now:.3f} ({_seeds(lb, after, variant)}) | "
                     f"{refs.get(variant, {}).get('best', math.nan):.3f} | {now - was:+.3f} |")))
    return (["| variant | paper protocol (per seed) | corrected (per seed) | oracle best | change |", "|---|---|---|---:|---:|"]
            + [text for _, text in sorted(rows, key=lambda r: -r[0])])


def _seeds(lb: Leaderboard, records: pd.DataFrame, variant: str) -> str:
    """Each seed's run on ``variant``, in seed order, to two decimals."""
    if variant not in records.index:
        return "—"
    runs = lb.runs.loc[lb.runs["run_id"].isin(records.loc[variant, "run_ids"])].sort_values("seed")
    return ", ".join(f"{m:.2f}" for m in runs["metric"])
