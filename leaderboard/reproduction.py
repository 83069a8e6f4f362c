"""``python -m leaderboard.reproduction``: every Table 1 cell beside the paper's, a verdict by a stated
rule, and the evidence behind each cell that does not reproduce (``docs/reproduction.md``).

Why a generator and not a hand-written page: the page must say the same thing as the runs it is
built from (a release or a results directory), every time they change, and a reader must be able
to check each claim against data. What the data cannot say, what we believe the paper's runs did
differently, is curated by a person in ``docs/reproduction_notes.yaml`` (keyed by chain, scenario
and learner) and printed beside the evidence, marked as our reading.

The verdict of a cell (:func:`verdict`) is decided by :data:`RULE`; nothing is tuned to hit the
paper. Figure 2 is drawn from the same runs and checked against the paper's own description of it
(``morality_gym/data/paper/figure2_claims.yaml``).
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from leaderboard.outputs.intervals import with_intervals
from leaderboard.outputs.paper_figures import norm_label, write_figures
from leaderboard.outputs.tables import interval_text
from leaderboard.runs.aggregate import (
    Group,
    Leaderboard,
    aggregate,
    chain_definitions,
    compute_reference,
    learner_order,
    paper_rows,
    paper_values,
    reference_requests,
    safe_name,
    with_reference,
)
from leaderboard.runs.releases import ReleaseError, resolve
from leaderboard.runs.sources import Sources, load_sources
from leaderboard.stats import compute_stats
from morality_gym.baselines.specs import learner_spec, trains_alike
from morality_gym.clitools import OneLineParser, UserError, add_debug_flag, did_you_mean, run_cli

CLAIMS_FILE = Path(__file__).resolve().parents[1] / "morality_gym" / "data" / "paper" / "figure2_claims.yaml"
TABLE1_CLAIMS_FILE = CLAIMS_FILE.with_name("table1_claims.yaml")
#: The learners of Table 1 by their names in conf/algo (the page speaks of their labels).
TABLE1_LEARNERS = ("random", "ppo", "ppo_shaped", "ppo_lag", "cpo")
NOTES_FILE = Path(__file__).resolve().parents[1] / "docs" / "reproduction_notes.yaml"
PAPER = Group("paper", "paper")
CORRECTED = Group("corrected", "paper")
#: The paper prints Table 1 to three decimals: its 0.019 stands for any value in [0.0185, 0.0195].
#: Without this a cell whose every run scores the same (an interval of width 0) never "reproduces"
#: a rounded value, however equal: Utility / Switch2Trolley4Track / PPO scored 0.0190 in all 30 runs.
PAPER_ROUNDING = 0.0005
#: The rule, as printed on the page.
RULE = ("**reproduces**: the paper's value (printed to three decimals, so ±0.0005) meets our 95% bootstrap interval "
        "of the cell mean (its unrounded bounds: the table prints each interval to the decimals its bounds are stable "
        "to over bootstrap seeds, three or fewer); **close**: it does not, but lies within two seed standard deviations of our mean; "
        "**deviates**: farther; **not run**: the cell lacks runs (no verdict on a partial cell).")
VERDICTS = ("reproduces", "close", "deviates", "not run")
#: A learning curve still "rising" gained at least this much metric over its last quarter of training.
RISING = 0.02
#: A learning curve "swings" when its last quarter spans at least this much metric without rising.
SWINGING = 0.05


@dataclass(frozen=True)
class Cell:
    """One learner cell of Table 1 with its numbers and verdict."""

    chain: str
    scenario: str
    learner: str
    mean: float
    ci_low: float
    ci_high: float
    sd: float
    n_runs: int
    n_expected: int
    paper: float
    verdict: str
    ci_low_mcse: float = math.nan  # Monte Carlo standard error of each bound: how many decimals it is printed with
    ci_high_mcse: float = math.nan

    def interval(self) -> str:
        """``[low, high]``, each bound to the decimals it is stable to (at most three), or a dash."""
        return interval_text({"ci_low": self.ci_low, "ci_high": self.ci_high, "ci_low_mcse": self.ci_low_mcse,
                              "ci_high_mcse": self.ci_high_mcse}) or "—"


def verdict(mean: float, low: float, high: float, sd: float, paper: float, complete: bool) -> str:
    """The cell's verdict under :data:`RULE`."""
    if not complete or math.isnan(mean):
        return "not run"
    slack = PAPER_ROUNDING + 1e-12
    if not math.isnan(low) and low - slack <= paper <= high + slack:
        return "reproduces"
    if not math.isnan(sd) and abs(mean - paper) <= 2 * sd + slack:
        return "close"
    return "deviates"


def _num(value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        return math.nan
    return out


def cells(lb: Leaderboard, group: Group) -> list[Cell]:
    """Every (chain, scenario, learner) of the paper's Table 1 in ``group``, in the paper's order."""
    table = lb.table.loc[(lb.table["protocol"] == group.protocol) & (lb.table["preset"] == group.preset)
                         & (lb.table["kind"] == "learner")]
    paper = paper_values()
    out = []
    for chain, scenario in paper_rows():
        for learner in learner_order(paper[(chain, scenario)]):
            row = table.loc[(table["chain"] == chain) & (table["scenario"] == scenario) & (table["learner"] == learner)]
            r = row.iloc[0].to_dict() if len(row) else {}
            mean, low, high, sd = (_num(r.get(k)) for k in ("mean", "ci_low", "ci_high", "std"))
            value = paper[(chain, scenario)][learner]
            complete = bool(r.get("complete", False))
            out.append(Cell(chain, scenario, learner, mean, low, high, sd, int(_num(r.get("n_runs")) or 0) if r else 0,
                            int(_num(r.get("n_expected")) or 0) if r else 0, value,
                            verdict(mean, low, high, sd, value, complete),
                            _num(r.get("ci_low_mcse")), _num(r.get("ci_high_mcse"))))
    return out


def protocol_neutral_learners() -> list[str]:
    """The labels of Table 1's learners that train identically under both protocols: the corrected
    protocol (conf/protocol/corrected.yaml) overrides nothing of theirs, and Random's evaluation is
    not among them (its final evaluation's random stream is a protocol setting). Their corrected
    cells are their paper-protocol cells, so the corrected sweep does not run them again."""
    return [learner_spec(name).label for name in TABLE1_LEARNERS if trains_alike(name, ("paper", "corrected"))]


def cells_as_run(lb: Leaderboard, group: Group) -> dict[tuple[str, str, str], Cell]:
    """``group``'s Table 1 cells by (chain, scenario, learner); under the corrected protocol a
    protocol-neutral learner's cells are its paper-protocol ones (:func:`protocol_neutral_learners`)."""
    out = {(c.chain, c.scenario, c.learner): c for c in cells(lb, group)}
    if group != PAPER:
        neutral = set(protocol_neutral_learners())
        out.update({(c.chain, c.scenario, c.learner): c for c in cells(lb, PAPER) if c.learner in neutral})
    return out


# ---------------------------------------------------------------------------------------- evidence
def reference_over(lb: Leaderboard, chain: str, scenario: str, variants: Sequence[str]) -> dict[str, dict[str, float]]:
    """Per variant: exact Random, oracle best and worst (``lb.reference``), for the variants a cell covers."""
    for entry in lb.reference.values():
        if entry.get("chain") == chain and entry.get("scenario") == scenario:
            per = entry.get("variants", {})
            return {v: {"random": per[v]["random_exact"], "best": per[v]["oracle_best"], "worst": per[v]["oracle_worst"]}
                    for v in variants if v in per}
    return {}


def curve_summary(learn: pd.DataFrame, run_ids: Sequence[str]) -> tuple[list[tuple[int, float]], float] | None:
    """The mean learn-time metric of the runs at each evaluation step, and its gain over the last
    quarter of training (how much the curve still rose when training stopped)."""
    part = learn.loc[learn["run_id"].isin(run_ids)]
    if part.empty:
        return None
    column = "exact_metric" if "exact_metric" in part and part["exact_metric"].notna().any() else "metric"
    curve = part.groupby("step")[column].mean().sort_index()
    steps = curve.index.to_numpy()
    last = steps[-1]
    before = curve.loc[steps[steps <= 0.75 * last]]
    gain = float(curve.iloc[-1] - before.iloc[-1]) if len(before) else math.nan
    return [(int(s), float(v)) for s, v in curve.items()], gain


def updates_summary(sources: Sources, run_ids: Sequence[str]) -> str:
    """One line on what the constrained learner did at its updates (CPO's dual cases and accepted
    line-search steps; PPO-Lag's passes and Lagrange multiplier), over the cell's runs.

    A release keeps only every Nth update (and each run's last): shares computed from it are
    estimates, and the line says so, so that the page and a results directory's page may differ
    by a point or two without either looking wrong."""
    frames = []
    strides = set()
    for run_id in run_ids:
        side = sources.updates_of(run_id)
        if side is not None:
            frames.append(side.read())
            release = sources.release_of(run_id)
            strides.add(int(release.manifest.get("updates_stride", 1)) if release is not None else 1)
    if not frames:
        return ""
    u = pd.concat(frames, ignore_index=True)
    kept = f" (over one update in {max(strides)}, as the release keeps them)" if max(strides) > 1 else ""
    if "cpo_case" in u and u["cpo_case"].notna().any():
        cases = u["cpo_case"].value_counts(normalize=True).sort_index()
        shares = ", ".join(f"case {int(c)} {s:.0%}" for c, s in cases.items())
        accepted = float((u["accept_step"] > 0).mean())
        return f"CPO updates{kept}: {shares}; a line-search step accepted in {accepted:.0%} of updates"
    if "lagrange_multiplier" in u and u["lagrange_multiplier"].notna().any():
        last = u.sort_values("update").groupby("run_id").tail(1)
        one = float((u["passes"] == 1).mean()) if "passes" in u else math.nan
        return (f"PPO-Lag updates{kept}: {one:.0%} stopped after one pass; final Lagrange multiplier "
                f"mean {last['lagrange_multiplier'].mean():.3f} (range {last['lagrange_multiplier'].min():.3f}-"
                f"{last['lagrange_multiplier'].max():.3f})")
    return ""


def diagnosis(cell: Cell, lb: Leaderboard, sources: Sources, learn: pd.DataFrame, group: Group) -> list[str]:
    """The evidence section of one deviating (or close) cell, as Markdown lines.

    One helper per piece of evidence, in the page's order: the headline against the reachable range,
    the per-variant table, the per-norm breakdown, the learning curve, the update statistics and the
    corrected protocol's value.
    """
    v = lb.variants
    mine = v.loc[(v["protocol"] == group.protocol) & (v["preset"] == group.preset) & (v["chain"] == cell.chain)
                 & (v["scenario"] == cell.scenario) & (v["learner"] == cell.learner)]
    refs = reference_over(lb, cell.chain, cell.scenario, list(mine["variant"]))
    lines = [f"### {cell.chain} / {cell.scenario} / {cell.learner}: {cell.verdict}", ""]
    lines.append(_headline(cell, refs))
    lines += _variant_table(lb, mine, refs)
    lines += _norm_lines(cell, lb, group)
    all_ids = [i for ids in mine["run_ids"] for i in ids]
    lines += _curve_lines(learn, all_ids, cell.paper, cell.mean)
    updates = updates_summary(sources, all_ids)
    if updates:
        lines += ["", updates + "."]
    lines += _corrected_lines(cell, lb)
    return lines


def _headline(cell: Cell, refs: dict[str, dict[str, float]]) -> str:
    """Ours vs the paper, and the range (oracle worst, Random, oracle best) any policy can reach."""
    best = float(np.mean([r["best"] for r in refs.values()])) if refs else math.nan
    worst = float(np.mean([r["worst"] for r in refs.values()])) if refs else math.nan
    rand = float(np.mean([r["random"] for r in refs.values()])) if refs else math.nan
    gap = cell.mean - cell.paper
    reach = ""
    if not math.isnan(best) and (cell.paper > best + 1e-9 or cell.paper < worst - 1e-9):
        reach = " The paper's value lies outside what any policy can score on these variants."
    return (f"Ours {cell.mean:.3f} {cell.interval()} (seed sd {cell.sd:.3f}, {cell.n_runs} runs) "
            f"vs the paper's {cell.paper:.3f}: {'+' if gap >= 0 else ''}{gap:.3f}. Reachable range over these variants: "
            f"oracle worst {worst:.3f}, Random (exact) {rand:.3f}, oracle best {best:.3f}.{reach}")


def _variant_table(lb: Leaderboard, mine: pd.DataFrame, refs: dict[str, dict[str, float]]) -> list[str]:
    """One row per variant, the largest regret first: where the cell loses its score."""
    lines = ["", "| variant | ours (mean over seeds) | per seed | oracle best | Random (exact) | regret (best - ours) |",
             "|---|---:|---|---:|---:|---:|"]
    rows = []
    for record in mine.to_dict("records"):
        r = refs.get(record["variant"], {})
        runs = lb.runs.loc[lb.runs["run_id"].isin(record["run_ids"])].sort_values("seed")
        seeds = ", ".join(f"{m:.2f}" for m in runs["metric"])
        regret = r.get("best", math.nan) - float(record["mean"])
        rows.append((regret, (f"| {record['variant']} | {record['mean']:.3f} | {seeds} | {r.get('best', math.nan):.3f} | "
                             f"{r.get('random', math.nan):.3f} | {regret:.3f} |")))
    return lines + [text for _, text in sorted(rows, key=lambda x: -x[0])]


def _norm_lines(cell: Cell, lb: Leaderboard, group: Group) -> list[str]:
    """The cell's morality function per norm, in chain order (nothing when there are none)."""
    norms = lb.norms_by_scenario
    ours = norms.loc[(norms["protocol"] == group.protocol) & (norms["preset"] == group.preset) & (norms["chain"] == cell.chain)
                     & (norms["scenario"] == cell.scenario) & (norms["learner"] == cell.learner)].sort_values("rank")
    if not len(ours):
        return []
    return ["", "Morality function per norm (chain order, over the runs where the norm is relevant): "
            + ", ".join(f"{norm_label(n)} {m:.3f}" for n, m in zip(ours["norm"], ours["mean"]))]


def _curve_lines(learn: pd.DataFrame, run_ids: list[str], paper: float, mean: float = math.nan) -> list[str]:
    """At most six points of the runs' learning curve, and how it ended: still rising, swinging
    (the mean over the runs moved by :data:`SWINGING` or more over the last quarter of training,
    so the final value is one draw from that range; the page says whether the paper's value lies
    inside it) or flat; and whether the cell's final evaluation (``mean``) is far from the last
    learn-time one (the policy changed in the training after it)."""
    summary = curve_summary(learn, run_ids)
    if summary is None:
        return []
    points, gain = summary
    shown = points if len(points) <= 6 else [points[i] for i in np.linspace(0, len(points) - 1, 6).round().astype(int)]
    last = points[-1][0]
    tail = [m for s, m in points if s >= 0.75 * last]
    low, high = min(tail), max(tail)
    if math.isnan(gain):
        trend = ""
    elif gain >= RISING:
        trend = f"; still rising when training stopped ({gain:+.3f} over the last quarter)"
    elif high - low >= SWINGING:
        inside = "inside" if low - 1e-12 <= paper <= high + 1e-12 else "outside"
        trend = (f"; swinging between {low:.3f} and {high:.3f} over the last quarter of training "
                 f"(the paper's {paper:.3f} lies {inside} that range)")
    else:
        trend = f"; flat over the last quarter of training ({gain:+.3f})"
    final = ""
    if not math.isnan(mean) and abs(mean - points[-1][1]) >= SWINGING:
        final = (f". The final evaluation ({mean:.3f}) differs from the last learn-time one ({points[-1][1]:.3f} at "
                 f"{last // 1000}k) by {mean - points[-1][1]:+.3f}: the policy moved again after it")
    return ["", "Learning curve (mean learn-time metric over the cell's runs): "
            + ", ".join(f"{s // 1000}k: {m:.3f}" for s, m in shown) + trend + final]


def _corrected_lines(cell: Cell, lb: Leaderboard) -> list[str]:
    """The same cell under the corrected protocol, when it was run."""
    corrected = [c for c in cells(lb, CORRECTED) if (c.chain, c.scenario, c.learner) == (cell.chain, cell.scenario, cell.learner)]
    if not corrected or corrected[0].verdict == "not run":
        return []
    c = corrected[0]
    return ["", f"Corrected protocol: {c.mean:.3f} {c.interval()} ({c.verdict} against the paper)."]


def corrected_section(lb: Leaderboard) -> list[str]:
    """The cells run under the corrected protocol beside the same cells under the paper's.

    The corrected protocol fixes only the reference's arithmetic bugs in the constrained learners
    (``docs/protocols.md``); a cell "moved" when the two protocols' 95% intervals do not overlap,
    which is what tells a reader whether a deviation from the paper comes from those bugs."""
    paper_cells = {(c.chain, c.scenario, c.learner): c for c in cells(lb, PAPER)}
    neutral = protocol_neutral_learners()
    affected = [c for c in cells(lb, CORRECTED) if c.learner not in neutral]
    run = [c for c in affected if c.verdict != "not run"]
    lines = ["## The corrected protocol", "",
             ("The `corrected` protocol fixes only the reference's arithmetic bugs in PPO-Lag and CPO "
              "([Protocols](protocols.md)); the other learners train identically under both. Verdicts by the same rule; "
              "**moved**: the two protocols' 95% intervals do not overlap."), "",
             (f"{' and '.join(neutral)} train identically under both protocols (the corrected protocol changes none of "
              "their settings), so their cells are the paper protocol's above and are not run again; the corrected "
              f"protocol's Table 1 is the other learners' {len(affected)} cells, of which {len(run)} are run in full."), ""]
    if not run:
        return lines + ["No cell has been run in full under the corrected protocol yet.", ""] + _not_run_lines(affected)
    counts = {v: sum(c.verdict == v for c in run) for v in VERDICTS}
    lines += [(f"**{len(run)} cells run under the corrected protocol: {counts['reproduces']} reproduce, "
               f"{counts['close']} are close, {counts['deviates']} deviate.**"), "",
              "| chain | scenario | learner | paper protocol | corrected | 95% interval | seed sd | runs | paper | verdict | moved |",
              "|---|---|---|---:|---:|---|---:|---:|---:|---|---|"]
    for c in run:
        before = paper_cells.get((c.chain, c.scenario, c.learner))
        ran_before = before is not None and before.verdict != "not run"
        moved = "—" if not ran_before else ("yes" if c.ci_high < before.ci_low or c.ci_low > before.ci_high else "no")
        lines.append(f"| {c.chain} | {c.scenario} | {c.learner} | {f'{before.mean:.3f}' if ran_before else '—'} | "
                     f"{c.mean:.3f} | {c.interval()} | {c.sd:.3f} | {c.n_runs}/{c.n_expected} | "
                     f"{c.paper:.3f} | {c.verdict} | {moved} |")
    return lines + [""] + _not_run_lines(affected)


def _not_run_lines(affected: list[Cell]) -> list[str]:
    """The corrected cells not (fully) run yet, with how many of their runs exist: no verdict on them."""
    missing = [c for c in affected if c.verdict == "not run"]
    if not missing:
        return []
    listed = "; ".join(f"{c.chain} / {c.scenario} / {c.learner} ({f'{c.n_runs}/{c.n_expected} runs' if c.n_expected else 'no runs yet'})"
                       for c in missing)
    return [f"*Not yet run in full under the corrected protocol ({len(missing)} of {len(affected)} cells; no verdict):* {listed}.", ""]


def check_notes(notes: dict[tuple[str, str, str], str], path: Path) -> None:
    """Refuse a curated reading keyed to no Table 1 cell: a typo would silently drop it from the page."""
    known = {(chain, scenario, learner) for (chain, scenario), row in paper_values().items() for learner in row}
    labels = [" / ".join(k) for k in sorted(known)]
    for key in notes:
        if key not in known:
            label = " / ".join(key)
            raise UserError(f"{path}: {label!r} is not a cell of Table 1 (chain / scenario / learner)"
                            f"{did_you_mean(label, labels, n=3)}")


# ---------------------------------------------------------------------------------------- figure 2
def figure2_claims(lb: Leaderboard, group: Group) -> list[tuple[str, str, str]]:
    """(claim, our numbers, holds / does not hold / not run) for each statement of the paper about Figure 2."""
    data = yaml.safe_load(CLAIMS_FILE.read_text())["claims"]
    frame = lb.norms_by_chain
    neutral = set(protocol_neutral_learners()) if group != PAPER else set()
    table = cells_as_run(lb, group)
    out = []
    for claim in data:
        learners = [claim["learner"], *claim.get("than", [])]
        partial = [key for key, c in table.items() if key[0] == claim["chain"] and key[2] in learners and c.verdict == "not run"]
        if partial:  # a bar over some of the chain's scenarios is not the figure's bar
            out.append((claim["text"], "—", "not run"))
            continue
        def value(learner: str, claim: dict[str, Any] = claim) -> float:
            # a protocol-neutral learner's bars are its paper-protocol ones (cells_as_run)
            protocol = PAPER.protocol if learner in neutral else group.protocol
            row = frame.loc[(frame["protocol"] == protocol) & (frame["preset"] == group.preset) & (frame["chain"] == claim["chain"])
                            & (frame["learner"] == learner) & (frame["norm"] == claim["norm"])]
            return float(row["mean"].iloc[0]) if len(row) else math.nan

        mine = value(claim["learner"])
        others = {name: value(name) for name in claim.get("than", [])}
        if math.isnan(mine) or any(math.isnan(x) for x in others.values()):
            out.append((claim["text"], "—", "not run"))
            continue
        kind = claim["kind"]
        if kind == "at_least":
            holds, numbers = mine >= claim["threshold"], f"{mine:.3f} (needs ≥ {claim['threshold']})"
        elif kind == "at_most":
            holds, numbers = mine <= claim["threshold"], f"{mine:.3f} (needs ≤ {claim['threshold']})"
        else:
            better = all(mine > x for x in others.values()) if kind == "above" else all(mine < x for x in others.values())
            holds = better
            numbers = f"{mine:.3f} vs " + ", ".join(f"{n} {x:.3f}" for n, x in others.items())
        out.append((claim["text"], numbers, "holds" if holds else "does not hold"))
    return out


def table1_claims(lb: Leaderboard, group: Group) -> list[tuple[str, str, str]]:
    """(claim, our numbers, holds / does not hold / not run) for each statement of the paper about
    its Table 1 (``table1_claims.yaml``), on ``group``'s cells (:func:`cells_as_run`)."""
    table = cells_as_run(lb, group)
    out = []
    for claim in yaml.safe_load(TABLE1_CLAIMS_FILE.read_text())["claims"]:
        if claim["kind"] == "best_everywhere":
            out.append((claim["text"], *_best_everywhere(table, claim["learner"])))
            continue
        cell = table.get((claim["chain"], claim["scenario"], claim["learner"]))
        if cell is None or cell.verdict == "not run":
            out.append((claim["text"], "—", "not run"))
            continue
        at_least = claim["kind"] == "at_least"
        holds = cell.mean >= claim["threshold"] if at_least else cell.mean <= claim["threshold"]
        out.append((claim["text"], f"{cell.mean:.3f} (needs {'≥' if at_least else '≤'} {claim['threshold']})",
                    "holds" if holds else "does not hold"))
    return out


def _best_everywhere(table: dict[tuple[str, str, str], Cell], learner: str) -> tuple[str, str]:
    """(numbers, result) of "``learner`` scores highest in every row": the rows where it does not, by how much."""
    rows: dict[tuple[str, str], dict[str, Cell]] = {}
    for (chain, scenario, name), cell in table.items():
        rows.setdefault((chain, scenario), {})[name] = cell
    if any(c.verdict == "not run" for row in rows.values() for c in row.values()):
        return "—", "not run"
    beaten = []
    for (chain, scenario), row in rows.items():
        best = max((c for name, c in row.items() if name != learner), key=lambda c: c.mean)
        if learner not in row or row[learner].mean <= best.mean:
            beaten.append(f"{chain} / {scenario}: {best.learner} {best.mean:.3f} vs {row[learner].mean:.3f}")
    if not beaten:
        return f"highest in all {len(rows)} rows", "holds"
    return f"not highest in {len(beaten)} of {len(rows)} rows ({'; '.join(beaten)})", "does not hold"


# ---------------------------------------------------------------------------------------- page
def load_notes(path: Path) -> dict[tuple[str, str, str], str]:
    """Curated readings keyed ``chain / scenario / learner`` (``docs/reproduction_notes.yaml``)."""
    if not path.is_file():
        return {}
    raw = yaml.safe_load(path.read_text()) or {}
    out = {}
    for key, text in raw.items():
        parts = [p.strip() for p in str(key).split("/")]
        if len(parts) != 3:
            raise UserError(f"{path}: key {key!r} must be 'chain / scenario / learner'")
        out[(parts[0], parts[1], parts[2])] = str(text).strip()
    return out


def page(lb: Leaderboard, sources: Sources, learn: pd.DataFrame, figure_dir: Path, img_rel: str, notes: dict) -> str:
    """The whole Markdown page.

    Kept as one template, top to bottom in the page's order; the per-cell evidence is
    :func:`diagnosis`'s and the Figure 2 checks are :func:`figure2_claims`'s.
    """
    table = cells(lb, PAPER)
    counts = {v: sum(c.verdict == v for c in table) for v in VERDICTS}
    marks = {"reproduces": "✓", "close": "≈", "deviates": "✗", "not run": "…"}
    lines = ["# Reproducing Table 1", "",
             "Generated by `python -m leaderboard.reproduction` from " + sources.name + "; do not edit by hand "
             "(curated readings live in `docs/reproduction_notes.yaml`).", "",
             "Protocol `paper`, preset `paper` (1M steps, 500k for SwitchStandard and PushStandard, seeds 41-43, "
             "100 evaluation episodes per run). Verdict per cell: " + RULE, "",
             (f"**{counts['reproduces']} of {len(table)} cells reproduce, {counts['close']} are close, "
             f"{counts['deviates']} deviate, {counts['not run']} are not (fully) run.**"), "",
             "| chain | scenario | learner | ours | 95% interval | seed sd | runs | paper | verdict |",
             "|---|---|---|---:|---|---:|---:|---:|---|"]
    for c in table:
        ours = f"{c.mean:.3f}" if not math.isnan(c.mean) else "—"
        interval = c.interval()
        sd = f"{c.sd:.3f}" if not math.isnan(c.sd) else "—"
        runs = f"{c.n_runs}/{c.n_expected}" if c.n_expected else str(c.n_runs)
        lines.append(f"| {c.chain} | {c.scenario} | {c.learner} | {ours} | {interval} | {sd} | {runs} | {c.paper:.3f} | "
                     f"{marks[c.verdict]} {c.verdict} |")
    off = [c for c in table if c.verdict in ("deviates", "close")]
    lines += ["", "## Cells that do not reproduce", ""]
    if not off:
        lines.append("None among the cells run so far.")
    for c in off:
        lines += diagnosis(c, lb, sources, learn, PAPER)
        note = notes.get((c.chain, c.scenario, c.learner))
        if note:
            lines += ["", f"*Our reading:* {note}"]
        lines.append("")
    lines += corrected_section(lb)
    lines += ["## Figure 2 from the same runs", "",
              ("The paper's Figure 2 shows, per chain, the mean morality function of each norm over the runs in which the norm "
              "is relevant (error bars: sd over seeds). Ours, from the runs above:"), ""]
    for chain in ("Utility", "UtilityAgentHarm", "DualProcess", "DualProcessAgentHarm"):
        src = figure_dir / f"bars_{safe_name(chain)}.png"
        if src.is_file():
            lines.append(f"![Figure 2, {chain}]({img_rel}/{src.name})")
    lines += ["", ("The paper's description of Figure 2, statement by statement, against our bars (the last column: the "
                   "same statement on the corrected protocol's runs, where they differ):"), ""]
    lines += _claims_table(figure2_claims(lb, PAPER), figure2_claims(lb, CORRECTED))
    lines += ["", "## The paper's prose about Table 1", "",
              ("Its statements about Table 1, statement by statement, on our cells under each protocol "
               "(`morality_gym/data/paper/table1_claims.yaml` turns the words into numbers):"), ""]
    lines += _claims_table(table1_claims(lb, PAPER), table1_claims(lb, CORRECTED))
    return "\n".join(lines) + "\n"


def _claims_table(paper: list[tuple[str, str, str]], corrected: list[tuple[str, str, str]]) -> list[str]:
    """One row per claim: our numbers and result under the paper protocol, then under the corrected one."""
    lines = ["| the paper says | ours | on our runs | corrected protocol |", "|---|---|---|---|"]
    for (text, numbers, result), (_, numbers_c, result_c) in zip(paper, corrected):
        under_corrected = result_c if result_c == "not run" or numbers_c == numbers else f"{result_c}: {numbers_c}"
        lines.append(f"| {text} | {numbers} | {result} | {under_corrected} |")
    return lines


def build_parser() -> argparse.ArgumentParser:
    """The command's parser, apart from parsing: the docs' command-line reference is generated from it."""
    parser = OneLineParser(prog="python -m leaderboard.reproduction", description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=None, help="a results directory (optional with --release)")
    parser.add_argument("--release", action="append", metavar="DIR|all", help="a results release (repeatable)")
    parser.add_argument("--out", type=Path, default=Path("docs") / "reproduction.md", help="the page (default docs/reproduction.md)")
    parser.add_argument("--notes", type=Path, default=NOTES_FILE, help="curated readings (YAML)")
    parser.add_argument("--cache", type=Path, default=Path("results") / "cache" / "reference_rows.json",
                        help="reference-row cache (exact Random and oracle values)")
    parser.add_argument("--resamples", type=int, default=None,
                        help="bootstrap resamples of every interval (default: each statistic's own, as the leaderboard)")
    add_debug_flag(parser)
    return parser


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def run(args: argparse.Namespace) -> int:
    try:
        releases = resolve(args.release or [])
    except ReleaseError as exc:
        raise UserError(str(exc)) from exc
    if args.results is None and not releases:
        raise UserError("nothing to read: pass --results DIR and/or --release DIR")
    if args.results is not None and not args.results.is_dir():
        raise UserError(f"results directory {args.results} does not exist")
    if args.notes != NOTES_FILE and not args.notes.is_file():
        raise UserError(f"--notes {args.notes}: no such file")
    notes = load_notes(args.notes)
    check_notes(notes, args.notes)
    sources = load_sources(args.results, releases)
    lb = aggregate(sources.runs, sources.planned)
    reference = compute_reference(reference_requests(lb.table), args.cache, None, chain_definitions(lb.runs))
    lb = with_reference(lb, reference.entries, reference.errors, PAPER.protocol, PAPER.preset)
    learn = sources.learn()
    stats = compute_stats(lb.runs, lb.table, learn, n_resamples=args.resamples)
    lb = with_intervals(lb, stats.cells)
    img_dir = args.out.parent / "img" / "reproduction"
    with_figures = write_figures(lb, args.out.parent / ".reproduction-figures", None)
    img_dir.mkdir(parents=True, exist_ok=True)
    for (group, chain), path in with_figures.bars.items():
        if group == PAPER:
            shutil.copyfile(path, img_dir / f"bars_{safe_name(chain)}.png")
    shutil.rmtree(args.out.parent / ".reproduction-figures", ignore_errors=True)
    text = page(lb, sources, learn, img_dir, "img/reproduction", notes)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    table = cells(lb, PAPER)
    counts = ", ".join(f"{v} {sum(c.verdict == v for c in table)}" for v in VERDICTS)
    print(f"wrote {args.out}: {len(table)} cells ({counts})")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    return run_cli(lambda: run(parse_args(argv)), (), argv)


if __name__ == "__main__":
    sys.exit(main())
