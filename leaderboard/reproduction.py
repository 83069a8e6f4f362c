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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from leaderboard.judging.baseline_facts import baseline_facts, fill_reading
from leaderboard.judging.cell_evidence import (
    curve_summary,
    read_updates,
    reference_over,
    updates_summary,
    variant_records,
)
from leaderboard.judging.protocol_change import BASELINE_SECTION, baseline_section, corrected_section
from leaderboard.judging.verdicts import (
    CORRECTED,
    PAPER,
    RULE,
    VARIANT_RULE,
    Cell,
    CellKey,
    Judgement,
    count_verdicts,
    judge,
)
from leaderboard.outputs.intervals import with_intervals
from leaderboard.outputs.paper_figures import norm_label, write_figures
from leaderboard.runs.aggregate import (
    Group,
    Leaderboard,
    aggregate,
    chain_definitions,
    compute_reference,
    paper_values,
    reference_requests,
    safe_name,
    with_reference,
)
from leaderboard.runs.releases import ReleaseError, resolve
from leaderboard.runs.sources import Sources, load_sources
from leaderboard.stats import compute_stats
from leaderboard.stats.cells import RESAMPLING, SEED
from morality_gym.clitools import OneLineParser, UserError, add_debug_flag, did_you_mean, run_cli

CLAIMS_FILE = Path(__file__).resolve().parents[1] / "morality_gym" / "data" / "paper" / "figure2_claims.yaml"
TABLE1_CLAIMS_FILE = CLAIMS_FILE.with_name("table1_claims.yaml")
NOTES_FILE = Path(__file__).resolve().parents[1] / "docs" / "reproduction_notes.yaml"
#: A learning curve still "rising" gained at least this much metric over its last quarter of training.
RISING = 0.02
#: A learning curve "swings" when its last quarter spans at least this much metric without rising.
SWINGING = 0.05


# ---------------------------------------------------------------------------------------- evidence
def diagnosis(cell: Cell, lb: Leaderboard, sources: Sources, learn: pd.DataFrame, group: Group,
              corrected: Cell | None = None) -> list[str]:
    """The evidence section of one deviating (or close) cell, as Markdown lines.

    One helper per piece of evidence, in the page's order: the headline against the reachable range,
    the per-variant table, the per-norm breakdown, the learning curve, the update statistics and the
    corrected protocol's value (``corrected``: the same cell under it).
    """
    mine = variant_records(lb, group, cell.chain, cell.scenario, cell.learner)
    refs = reference_over(lb, cell.chain, cell.scenario, list(mine["variant"]))
    lines = [f"### {cell.chain} / {cell.scenario} / {cell.learner}: {cell.verdict_text}", ""]
    lines.append(_headline(cell, refs))
    lines += _variant_table(lb, mine, refs)
    lines += _norm_lines(cell, lb, group)
    all_ids = [i for ids in mine["run_ids"] for i in ids]
    lines += _curve_lines(learn, all_ids, cell.paper, cell.mean)
    updates = updates_summary(read_updates(sources, all_ids))
    if updates:
        lines += ["", updates + "."]
    lines += _corrected_lines(corrected)
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


def _corrected_lines(corrected: Cell | None) -> list[str]:
    """The same cell under the corrected protocol, when it was run."""
    if corrected is None or corrected.verdict == "not run":
        return []
    return ["", f"Corrected protocol: {corrected.mean:.3f} {corrected.interval()} ({corrected.verdict_text} against the paper)."]


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
def figure2_claims(lb: Leaderboard, judged: Judgement, group: Group) -> list[tuple[str, str, str]]:
    """(claim, our numbers, holds / does not hold / not run) for each statement of the paper about Figure 2."""
    data = yaml.safe_load(CLAIMS_FILE.read_text())["claims"]
    neutral = set(judged.neutral) if group != PAPER else set()
    table = judged.as_run(group)
    out = []
    for claim in data:
        learners = [claim["learner"], *claim.get("than", [])]
        partial = [key for key, c in table.items() if key[0] == claim["chain"] and key[2] in learners and c.verdict == "not run"]
        bars = {name: _norm_bar(lb.norms_by_chain, group, neutral, claim, name) for name in learners}
        if partial or any(math.isnan(x) for x in bars.values()):  # a bar over some of the chain's scenarios is not the figure's bar
            out.append((claim["text"], "—", "not run"))
            continue
        out.append((claim["text"], *_claim_verdict(claim, bars[claim["learner"]], {n: bars[n] for n in learners[1:]})))
    return out


def _norm_bar(frame: pd.DataFrame, group: Group, neutral: set[str], claim: dict[str, Any], learner: str) -> float:
    """The Figure 2 bar a claim reads: ``learner``'s mean morality function of the claim's norm under its chain.

    A protocol-neutral learner's bars are its paper-protocol ones (:meth:`Judgement.as_run`)."""
    protocol = PAPER.protocol if learner in neutral else group.protocol
    row = frame.loc[(frame["protocol"] == protocol) & (frame["preset"] == group.preset) & (frame["chain"] == claim["chain"])
                    & (frame["learner"] == learner) & (frame["norm"] == claim["norm"])]
    return float(row["mean"].iloc[0]) if len(row) else math.nan


def _claim_verdict(claim: dict[str, Any], mine: float, others: dict[str, float]) -> tuple[str, str]:
    """(our numbers, holds / does not hold) of one claim of kind at_least, at_most, above or below."""
    kind = claim["kind"]
    if kind == "at_least":
        holds, numbers = mine >= claim["threshold"], f"{mine:.3f} (needs ≥ {claim['threshold']})"
    elif kind == "at_most":
        holds, numbers = mine <= claim["threshold"], f"{mine:.3f} (needs ≤ {claim['threshold']})"
    else:
        holds = all(mine > x for x in others.values()) if kind == "above" else all(mine < x for x in others.values())
        numbers = f"{mine:.3f} vs " + ", ".join(f"{n} {x:.3f}" for n, x in others.items())
    return numbers, "holds" if holds else "does not hold"


def table1_claims(judged: Judgement, group: Group) -> list[tuple[str, str, str]]:
    """(claim, our numbers, holds / does not hold / not run) for each statement of the paper about
    its Table 1 (``table1_claims.yaml``), on ``group``'s cells (:meth:`Judgement.as_run`)."""
    table = judged.as_run(group)
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


def _best_everywhere(table: dict[CellKey, Cell], learner: str) -> tuple[str, str]:
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
@dataclass(frozen=True)
class Readings:
    """The curated readings of ``docs/reproduction_notes.yaml``: per Table 1 cell, and per section of
    the page that ends in a reading (:data:`SECTION_READINGS`)."""

    cells: dict[tuple[str, str, str], str] = field(default_factory=dict)
    sections: dict[str, str] = field(default_factory=dict)


#: The sections of the page a reading may be keyed to, by the key the notes file uses.
SECTION_READINGS = (BASELINE_SECTION,)


def load_notes(path: Path) -> Readings:
    """Curated readings keyed ``chain / scenario / learner``, or by a section's name (:data:`SECTION_READINGS`)."""
    if not path.is_file():
        return Readings()
    raw = yaml.safe_load(path.read_text()) or {}
    out = Readings()
    for key, text in raw.items():
        if str(key) in SECTION_READINGS:
            out.sections[str(key)] = str(text).strip()
            continue
        parts = [p.strip() for p in str(key).split("/")]
        if len(parts) != 3:
            sections = ", ".join(repr(s) for s in SECTION_READINGS)
            raise UserError(f"{path}: key {key!r} must be 'chain / scenario / learner' or a section ({sections})"
                            f"{did_you_mean(str(key), list(SECTION_READINGS), n=1)}")
        out.cells[(parts[0], parts[1], parts[2])] = str(text).strip()
    return out


def page(lb: Leaderboard, judged: Judgement, sources: Sources, learn: pd.DataFrame, figure_dir: Path, img_rel: str,
         notes: Readings, resampling: str = SEED) -> str:
    """The whole Markdown page.

    Kept as one template, top to bottom in the page's order; the per-cell evidence is
    :func:`diagnosis`'s and the Figure 2 checks are :func:`figure2_claims`'s.
    """
    table = judged.paper
    counts = count_verdicts(table)
    marks = {"reproduces": "✓", "close": "≈", "deviates": "✗", "not run": "…"}
    lines = ["# Reproducing Table 1", "",
             "Generated by `python -m leaderboard.reproduction` from " + sources.name + "; do not edit by hand "
             "(curated readings live in `docs/reproduction_notes.yaml`).", "",
             "Protocol `paper`, preset `paper` (1M steps, 500k for SwitchStandard and PushStandard, seeds 41-43, "
             "100 evaluation episodes per run). Verdict per cell: " + (RULE if resampling == SEED else VARIANT_RULE), "",
             (f"**{counts['reproduces']} of {len(table)} cells reproduce, {counts['close']} are close, "
             f"{counts['deviates']} deviate, {counts['not run']} are not (fully) run.**" + _borderline_text(table)), "",
             "| chain | scenario | learner | ours | 95% interval, or per-seed means | seed sd | runs | paper | verdict |",
             "|---|---|---|---:|---|---:|---:|---:|---|"]
    for c in table:
        ours = f"{c.mean:.3f}" if not math.isnan(c.mean) else "—"
        interval = c.interval()
        sd = f"{c.sd:.3f}" if not math.isnan(c.sd) else "—"
        runs = f"{c.n_runs}/{c.n_expected}" if c.n_expected else str(c.n_runs)
        lines.append(f"| {c.chain} | {c.scenario} | {c.learner} | {ours} | {interval} | {sd} | {runs} | {c.paper:.3f} | "
                     f"{marks[c.verdict]} {c.verdict_text} |")
    off = [c for c in table if c.verdict in ("deviates", "close")]
    lines += ["", "## Cells that do not reproduce", ""]
    if not off:
        lines.append("None among the cells run so far.")
    for c in off:
        lines += diagnosis(c, lb, sources, learn, PAPER, judged.cell(CORRECTED, c.key))
        note = notes.cells.get((c.chain, c.scenario, c.learner))
        if note:
            lines += ["", f"*Our reading:* {note}"]
        lines.append("")
    lines += corrected_section(judged)
    reading = notes.sections.get(BASELINE_SECTION)
    facts = baseline_facts(lb, judged, sources) if reading else {}
    # the reading's numbers are facts of both protocols' runs: without them there is nothing to fill in
    reading = fill_reading(reading, facts, f"the {BASELINE_SECTION!r} reading") if facts else None
    lines += baseline_section(lb, judged, sources, reading)
    lines += ["## Figure 2 from the same runs", "",
              ("The paper's Figure 2 shows, per chain, the mean morality function of each norm over the runs in which the norm "
              "is relevant (error bars: sd over seeds). Ours, from the runs above:"), ""]
    for chain in ("Utility", "UtilityAgentHarm", "DualProcess", "DualProcessAgentHarm"):
        src = figure_dir / f"bars_{safe_name(chain)}.png"
        if src.is_file():
            lines.append(f"![Figure 2, {chain}]({img_rel}/{src.name})")
    lines += ["", ("The paper's description of Figure 2, statement by statement, against our bars (the last column: the "
                   "same statement on the corrected protocol's runs, where they differ):"), ""]
    lines += _claims_table(figure2_claims(lb, judged, PAPER), figure2_claims(lb, judged, CORRECTED))
    lines += ["", "## The paper's prose about Table 1", "",
              ("Its statements about Table 1, statement by statement, on our cells under each protocol "
               "(`morality_gym/data/paper/table1_claims.yaml` turns the words into numbers):"), ""]
    lines += _claims_table(table1_claims(judged, PAPER), table1_claims(judged, CORRECTED))
    return "\n".join(lines) + "\n"


def _borderline_text(table: Sequence[Cell]) -> str:
    """How many verdicts are on a knife edge (the paper's value within Monte Carlo error of a bound), named."""
    edge = [c for c in table if c.borderline]
    if not edge:
        return (" No verdict is borderline (the paper's value within Monte Carlo error of a bound): with three seeds "
                "the bounds are per-seed means, exact." if all(c.seed_range for c in table if c.verdict != "not run")
                else " No verdict is borderline (the paper's value within Monte Carlo error of a bound).")
    named = "; ".join(f"{' / '.join(c.key)} ({c.verdict})" for c in edge)
    return f" Borderline, the paper's value within Monte Carlo error of a bound: {named}."


def _claims_table(paper: list[tuple[str, str, str]], corrected: list[tuple[str, str, str]]) -> list[str]:
    """One row per claim: our numbers and result under the paper protocol, then under the corrected
    one; then, in one line, the claims whose result the corrected protocol changes."""
    lines = ["| the paper says | ours | on our runs | corrected protocol |", "|---|---|---|---|"]
    for (text, numbers, result), (_, numbers_c, result_c) in zip(paper, corrected):
        under_corrected = result_c if result_c == "not run" or numbers_c == numbers else f"{result_c}: {numbers_c}"
        lines.append(f"| {text} | {numbers} | {result} | {under_corrected} |")
    return lines + ["", _claims_changed(paper, corrected)]


def _claims_changed(paper: list[tuple[str, str, str]], corrected: list[tuple[str, str, str]]) -> str:
    """Which statements come out differently under the corrected protocol, and how many cannot be
    checked on it yet: the question a reader of both protocols asks first."""
    checked = [(p, c) for p, c in zip(paper, corrected) if c[2] != "not run" and p[2] != "not run"]
    changed = [f"\"{p[0]}\" ({p[2]} → {c[2]})" for p, c in checked if p[2] != c[2]]
    waiting = len(paper) - len(checked)
    pending = f"; {waiting} cannot be checked on the corrected protocol's runs yet (not run)" if waiting else ""
    if not changed:
        return f"**Under the corrected protocol, none of the {len(checked)} statements checked comes out differently{pending}.**"
    return (f"**Under the corrected protocol, {len(changed)} of the {len(checked)} statements checked come"
            f"{'s' if len(changed) == 1 else ''} out differently{pending}:** {'; '.join(changed)}.")


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
    parser.add_argument("--resampling", choices=RESAMPLING, default=SEED,
                        help="what a cell's bootstrap resamples: whole seeds with all their variants (seed, the default), "
                             "or each variant's seeds on their own (variant, the rule before issue 48, for comparison)")
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
    check_notes(notes.cells, args.notes)
    sources = load_sources(args.results, releases)
    lb = aggregate(sources.runs, sources.planned)
    reference = compute_reference(reference_requests(lb.table), args.cache, None, chain_definitions(lb.runs))
    lb = with_reference(lb, reference.entries, reference.errors, PAPER.protocol, PAPER.preset)
    learn = sources.learn()
    stats = compute_stats(lb.runs, lb.table, learn, n_resamples=args.resamples, resampling=args.resampling)
    lb = with_intervals(lb, stats.cells)
    img_dir = args.out.parent / "img" / "reproduction"
    with_figures = write_figures(lb, args.out.parent / ".reproduction-figures", None)
    img_dir.mkdir(parents=True, exist_ok=True)
    for (group, chain), path in with_figures.bars.items():
        if group == PAPER:
            shutil.copyfile(path, img_dir / f"bars_{safe_name(chain)}.png")
    shutil.rmtree(args.out.parent / ".reproduction-figures", ignore_errors=True)
    judged = judge(lb)
    text = page(lb, judged, sources, learn, img_dir, "img/reproduction", notes, args.resampling)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    counts = ", ".join(f"{v} {n}" for v, n in count_verdicts(judged.paper).items())
    print(f"wrote {args.out}: {len(judged.paper)} cells ({counts})")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    return run_cli(lambda: run(parse_args(argv)), (), argv)


if __name__ == "__main__":
    sys.exit(main())
