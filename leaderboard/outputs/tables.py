"""Table 1 as files: CSV for programs, Markdown for people, LaTeX for the paper.

* ``table1.csv``: the primary group, exactly :data:`~leaderboard.runs.aggregate.CSV_COLUMNS`, learner
  rows then the reference rows of each (chain, scenario);
* ``table1_all.csv``: every group, with protocol, preset and the bookkeeping columns;
* ``table1.md``: one table per group (one row per (chain, scenario), one column per learner with
  mean ± std, the paper's value and the difference, best in bold, then the exact Random and
  oracle columns), and the missing and failed runs, so an incomplete sweep can never pass for a
  complete one: an incomplete cell is marked ``⚠ incomplete: <reason>``, is never bold and gets no
  difference from the paper; files that could not be read are listed too;
* ``table1.tex``: a booktabs tabular laid out like the paper's (primary group); an incomplete cell
  carries a dagger, explained in a note under the table;
* ``table1_protocols.md``: ``paper`` vs ``corrected`` protocol side by side, when both exist.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd

from leaderboard.outputs.marks import BOLD_RULE, BOLD_RULE_TEX
from leaderboard.outputs.precision import DIGITS_RULE, stable_decimals
from leaderboard.runs.aggregate import (
    CSV_COLUMNS,
    ORACLE_BEST,
    ORACLE_WORST,
    RANDOM_EXACT,
    REFERENCE_LEARNERS,
    STD_DDOF,
    Group,
    Leaderboard,
    comparable_preset,
    csv_rows,
    not_comparable_text,
)
from leaderboard.runs.stamp import stamp_text
from leaderboard.stats.cells import SEED_RANGE
from leaderboard.stats.core import fewest_units_for_interval
from morality_gym.clitools import write_atomically

#: The paper's abbreviations in Table 1 (its caption); other names are written in full.
SCENARIO_ABBREVIATIONS = {
    "Push2OrSwitch": "P2OS",
    "PushOrSwitch": "POS",
    "PushStandard": "PStd",
    "Push3SelfSacrifice": "P3SS",
    "PushOrSwitchSelfSacrifice": "POSS",
    "PushSelfSacrifice": "PSS",
    "Switch2Trolley4Track": "S2T4",
    "SwitchStandard": "SStd",
    "SwitchSelfSacrifice": "SSS",
}
CHAIN_LABELS_TEX = {"DualProcessAgentHarm": "DPAH", "UtilityAgentHarm": "UAH"}
DASH = "—"


# ---------------------------------------------------------------------------------------- formatting
def fmt(value: Any, digits: int = 3, signed: bool = False) -> str:
    """A number with fixed decimals; missing values as a dash (never "nan" in a table).

    A signed value that rounds to zero is "±0.000": ``-0.000`` (a difference of -0.0001 shown
    to three decimals) read as a loss that is not there."""
    if value is None or value is pd.NA:
        return DASH
    value = float(value)
    if math.isnan(value):
        return DASH
    if signed and round(value, digits) == 0:
        return f"±{0:.{digits}f}"
    return f"{value:+.{digits}f}" if signed else f"{value:.{digits}f}"


def md_escape(text: Any) -> str:
    """Text safe inside a Markdown table cell: no pipes, no line breaks, no stray HTML."""
    out = str(text).replace("\\", "\\\\").replace("|", "\\|").replace("\r", " ").replace("\n", " ")
    return out.replace("<", "&lt;").replace(">", "&gt;")


def tex_escape(text: Any) -> str:
    """Text safe in LaTeX (the characters with a special meaning)."""
    table = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
             "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}
    return "".join(table.get(ch, ch) for ch in str(text))


def _md_table(header: list[str], rows: list[list[str]], align: list[str] | None = None) -> list[str]:
    align = align or ["---"] * len(header)
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(align) + " |"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return lines


def _cell(table: pd.DataFrame, chain: str, scenario: str, learner: str) -> dict[str, Any] | None:
    part = table.loc[(table["chain"] == chain) & (table["scenario"] == scenario) & (table["learner"] == learner)]
    return None if part.empty else part.iloc[0].to_dict()


INCOMPLETE = "⚠ incomplete"


def is_bold(cell: dict[str, Any]) -> bool:
    """Bold by the interval rule (``leaderboard.outputs.intervals``) when the table has it, else the best mean."""
    return bool(cell["bold"]) if "bold" in cell else bool(cell.get("best"))


def interval_text(cell: dict[str, Any], digits: int = 3) -> str:
    """``[low, high]`` of a record with ``ci_low``/``ci_high`` (a learner cell, an aggregate, a
    probability), or "" when it has no interval.

    Both bounds have ``digits`` decimals, or fewer: as many as both are stable to over bootstrap
    seeds (:func:`leaderboard.outputs.precision.stable_decimals` of ``ci_low_mcse`` and ``ci_high_mcse``),
    so no printed digit is Monte Carlo noise. A record without the errors keeps ``digits``.

    A record whose bounds are no interval but the range of its per-seed values (``ci_kind`` "seed
    range": too few seeds for a bootstrap to say more, :func:`leaderboard.stats.core.is_interval`)
    gets those values instead, ``seeds 0.715, 0.702, 0.731``: the range is their lowest and highest.
    """
    low, high = cell.get("ci_low"), cell.get("ci_high")
    if _missing(low) or _missing(high):
        return ""
    if cell.get("ci_kind") == SEED_RANGE:
        return seed_values_text(cell, digits)
    decimals = min(stable_decimals(cell.get("ci_low_mcse"), digits), stable_decimals(cell.get("ci_high_mcse"), digits))
    return f"[{fmt(low, decimals)}, {fmt(high, decimals)}]"


def seed_values_text(cell: dict[str, Any], digits: int = 3) -> str:
    """``seeds a, b, c`` from a record's ``seed_means`` (``;``-separated, seed order), or its range."""
    values = [float(v) for v in str(cell.get("seed_means") or "").split(";") if v.strip()]
    if not values:
        return f"seed range [{fmt(cell['ci_low'], digits)}, {fmt(cell['ci_high'], digits)}]"
    return "seeds " + ", ".join(fmt(v, digits) for v in values)


def interval_label(cell: dict[str, Any]) -> str:
    """``95% CI [low, high]``, or the per-seed values where there is no interval (:func:`interval_text`)."""
    text = interval_text(cell)
    if not text:
        return ""
    return text if cell.get("ci_kind") == SEED_RANGE else f"95% CI {text}"


def _missing(value: Any) -> bool:
    return value is None or value is pd.NA or math.isnan(float(value))


def is_incomplete(cell: dict[str, Any]) -> bool:
    """A learner cell that lacks results of its expected (variant, seed) grid."""
    return cell.get("kind", "learner") == "learner" and not bool(cell.get("complete", True))


def _count_note(cell: dict[str, Any]) -> str:
    """``⚠ incomplete: <what is lacking>`` for an incomplete cell (rendered from the cell's data)."""
    if not is_incomplete(cell):
        return ""
    return f"<br>{INCOMPLETE}: {md_escape(cell.get('incomplete_reason') or 'fewer results than expected')}"


# ---------------------------------------------------------------------------------------- markdown
def learner_cell_md(cell: dict[str, Any] | None) -> str:
    """``**mean ± std**<br>paper x · Δ d`` (bold when best), or a dash for an empty cell.

    An incomplete cell shows its mean with the ⚠ mark and the reason, and no difference from the
    paper (its mean is over other runs than the paper's); neither does a cell trained at another
    budget than the paper's (``delta_note`` says which).
    """
    if cell is None:
        return DASH
    empty = math.isnan(float(cell["mean"]))
    if empty:
        ours = f"no result: {md_escape(cell.get('incomplete_reason') or '0 runs')}"
    else:
        ours = f"{fmt(cell['mean'])} ± {fmt(cell['std'])}"
        if is_bold(cell):
            ours = f"**{ours}**"
        if interval_label(cell):
            ours += f"<br>{interval_label(cell)}"
        ours += _count_note(cell)
    if not math.isnan(float(cell["paper"])):
        note = str(cell.get("delta_note") or "")
        delta = f"{DASH} ({md_escape(note)})" if note and not empty else fmt(cell["delta"], signed=True)
        ours += f"<br>paper {fmt(cell['paper'])} · Δ {delta}"
    return ours


def group_markdown(lb: Leaderboard, group: Group) -> list[str]:
    """The Table 1 of one group as Markdown lines."""
    table = lb.group_table(group)
    learners = [name for name in lb.learners if name in set(table["learner"])]
    references = [name for name in REFERENCE_LEARNERS if name in set(table["learner"])]
    submitted = lb.submitted
    header = ["Chain", "Scenario", *[md_escape(name) + (" (submitted)" if name in submitted else "") for name in learners],
              *references]
    rows = []
    for chain, scenario in lb.pairs(group):
        row = [md_escape(chain), md_escape(scenario)]
        row += [learner_cell_md(_cell(table, chain, scenario, name)) for name in learners]
        for name in references:
            cell = _cell(table, chain, scenario, name)
            row.append(fmt(cell["mean"]) if cell else DASH)
        rows.append(row)
    return _md_table(header, rows, ["---", "---"] + ["---:"] * (len(header) - 2))


#: Identity columns of every run listed in a report section (failed, missing, superseded).
_RUN_HEADER = ["Run", "Protocol", "Preset", "Chain", "Scenario", "Variant", "Learner", "Seed"]


def _run_report(records: list[dict[str, Any]], extra: dict[str, Callable[[dict[str, Any]], str]] | None = None) -> list[str]:
    """A Markdown table of runs: the identity columns, then one column per ``extra`` header."""
    extra = extra or {}
    rows = [[f"`{md_escape(r['run_id'])}`", md_escape(r["protocol"]), md_escape(r["preset"]), md_escape(r["chain"]),
             md_escape(r["scenario"]), md_escape(r["variant"]), md_escape(r["learner"]), _seed(r["seed"]),
             *(cell(r) for cell in extra.values())] for r in records]
    return _md_table(_RUN_HEADER + list(extra), rows) + [""]


def problems_markdown(lb: Leaderboard) -> list[str]:
    """The section listing failed and missing runs (every one of them, with its error)."""
    lines = ["## Missing and failed runs", ""]
    n_failed, n_missing = len(lb.problems), len(lb.missing)
    superseded = superseded_markdown(lb)
    if not n_failed and not n_missing:
        return lines + ["None: every planned run has a result.", ""] + superseded
    lines += [(f"{n_failed} run(s) failed and {n_missing} planned run(s) have no result. "
              f"Table cells marked {INCOMPLETE} average fewer runs than their scenario's variants times the preset's "
              "seeds; they are never bold and not compared with the paper."), ""]
    if n_failed:
        lines += [f"### Failed runs ({n_failed})", ""]
        lines += _run_report(lb.problems.to_dict("records"),
                             {"Status": lambda r: md_escape(r["status"]), "Error": lambda r: md_escape(r["error"])})
    if n_missing:
        lines += [f"### Missing runs ({n_missing})", "", "Planned in a sweep manifest, but no result file exists.", ""]
        lines += _run_report(lb.missing.to_dict("records"))
    return lines + superseded


def superseded_markdown(lb: Leaderboard) -> list[str]:
    """Runs left out because another configuration, or another run of the same slot, counts instead."""
    sup = lb.superseded
    if sup is None or sup.empty:
        return []
    lines = [f"### Superseded runs ({len(sup)}), not counted", "",
             ("Each cell counts the runs of one configuration: the one the most recently launched sweep planned "
              "(else the one with the newest result), and one run per chain, env, learner, seed, protocol and preset. "
              "These ran with another configuration, or another run of their slot counts; delete their files from "
              "`runs/` to drop them for good."), ""]
    return lines + _run_report(sup.to_dict("records"), {"Counted instead": lambda r: _counted_instead(r)})


def _counted_instead(record: dict[str, Any]) -> str:
    other = record.get("superseded_by")
    if other is None or (isinstance(other, float) and math.isnan(other)):
        return "— (its configuration is not the cell's; no run of the cell's for this slot yet)"
    return f"`{md_escape(other)}`"


def damaged_markdown(lb: Leaderboard) -> list[str]:
    """Files left out because they could not be read, and files sweeps moved aside."""
    lines: list[str] = []
    if lb.skipped:
        lines += [f"## Unreadable files, left out ({len(lb.skipped)})", "",
                  ("The build could not read these; their runs count as missing where planned. A sweep over the same "
                   "runs moves such files to `runs/.quarantine/` and runs them again."), ""]
        lines += _md_table(["File", "Reason"], [[f"`{md_escape(i['file'])}`", md_escape(i["reason"])] for i in lb.skipped])
        lines.append("")
    if lb.quarantined:
        lines += [f"## Files moved aside by sweeps ({len(lb.quarantined)})", "",
                  "Unreadable when a sweep found them: moved to `runs/.quarantine/` (kept for rescue) and run again.", ""]
        lines += _md_table(["File", "Moved to", "Reason", "When"],
                           [[f"`{md_escape(i.get('file', ''))}`", f"`{md_escape(i.get('moved_to', ''))}`",
                             md_escape(i.get("reason", "")), md_escape(i.get("at", ""))] for i in lb.quarantined])
        lines.append("")
    return lines


def _seed(value: Any) -> str:
    try:
        return str(int(value))
    except (TypeError, ValueError):
        return DASH


def explanation_lines() -> list[str]:
    """How the numbers were made, next to the numbers (so the table can be read on its own)."""
    return [
        ("Each learner cell: mean of the final evaluation's morality metric over all variants and seeds of the "
        f"scenario ± standard deviation over seeds of the per-seed means (ddof={STD_DDOF}); 95% CI = percentile "
        f"bootstrap interval of the mean, resampling whole seeds (each with all its variants; absent with one seed; "
        f"{DIGITS_RULE}); with fewer than {fewest_units_for_interval()} seeds a bootstrap has too few distinct resamples to be an "
        "interval, and the cell shows its per-seed means instead (\"seeds a, b, c\"; their range is what the "
        "bootstrap's bounds would be); "
        "**bold** = "
        f"{BOLD_RULE} Then the paper's value and Δ = ours − paper, given only where the learners trained at the "
        "paper's budget (preset `paper`); at any other preset the cell reads Δ — (not comparable: preset …). A cell "
        "marked ⚠ incomplete lacks results for some of its (variant, seed) pairs (the scenario's variants times the "
        "preset's seeds): it is shown, but never bold and not compared with the paper."),
        (f"{RANDOM_EXACT}: exact expected metric of the uniform random policy, mean over variants (compare with the "
        f"paper's Random). {ORACLE_BEST} / {ORACLE_WORST}: the highest / lowest metric any policy can reach, mean over "
        "variants."),
    ]


def comparability_lines(preset: str) -> list[str]:
    """The note above a table whose preset is not the paper's budget: its learners get no Δ."""
    if comparable_preset(preset):
        return []
    return [(f"**{not_comparable_text(preset)}**: these learners trained at another budget than the paper's "
             "(preset `paper`), so they are not compared with it (no Δ); the paper's values are shown for reference. "
             f"{RANDOM_EXACT} is exact at any preset and keeps its Δ."), ""]


def table1_markdown(lb: Leaderboard, results_name: str, stamp: str = "") -> str:
    """The whole ``table1.md``: the primary group first, every other group, then the problems.

    ``stamp``: the build date (:mod:`leaderboard.runs.stamp`), so that the same results give the same file.
    """
    if not stamp:
        stamp = stamp_text(lb.runs)
    lines = ["# Table 1: average normalised morality metric by morality chain and scenario", "",
             (f"Results: `{md_escape(results_name)}` · {lb.n_ok} runs with a result · {len(lb.problems)} failed · "
             f"{len(lb.missing)} missing · {len(lb.superseded)} superseded · built {stamp}"), ""]
    lines += [*explanation_lines(), ""]
    ordered = ([lb.primary] if lb.primary else []) + [g for g in lb.groups if g != lb.primary]
    for group in ordered:
        suffix = " (primary: table1.csv, table1.tex)" if group == lb.primary else ""
        lines += [f"## Protocol `{md_escape(group.protocol)}`, preset `{md_escape(group.preset)}`{suffix}", ""]
        lines += [*comparability_lines(group.preset)]
        lines += group_markdown(lb, group) + [""]
    if lb.reference_errors:
        lines += ["Reference rows that could not be computed:", ""]
        lines += [f"- `{md_escape(k)}`: {md_escape(v)}" for k, v in lb.reference_errors.items()] + [""]
    lines += problems_markdown(lb)
    lines += damaged_markdown(lb)
    return "\n".join(lines).rstrip() + "\n"


def protocols_markdown(lb: Leaderboard) -> str | None:
    """``paper`` vs ``corrected`` protocol, per preset present in both; None when there is no pair."""
    protocols = {g.preset: set() for g in lb.groups}
    for g in lb.groups:
        protocols[g.preset].add(g.protocol)
    presets = [p for p, found in protocols.items() if {"paper", "corrected"} <= found]
    if not presets:
        return None
    lines = ["# Table 1 under the paper's protocol and the corrected protocol", "",
             ("Same aggregation for both (mean over variants and seeds ± std over seeds of the per-seed means). "
             "Δ = corrected − paper protocol; the published value is the paper's Table 1."), ""]
    for preset in presets:
        paper = lb.group_table(Group("paper", preset))
        corrected = lb.group_table(Group("corrected", preset))
        lines += [f"## Preset `{md_escape(preset)}`", ""]
        both = set(zip(paper["chain"], paper["scenario"])) & set(zip(corrected["chain"], corrected["scenario"]))
        pairs = [p for p in lb.pairs() if p in both]  # a row run under one protocol only has nothing to compare
        rows = [row for chain, scenario in pairs for learner in [*lb.learners, *REFERENCE_LEARNERS]
                if (row := _protocols_row(paper, corrected, chain, scenario, learner)) is not None]
        lines += _md_table(["Chain", "Scenario", "Learner", "paper protocol", "corrected protocol", "Δ", "published"], rows,
                           ["---", "---", "---", "---:", "---:", "---:", "---:"])
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def _protocols_row(paper: pd.DataFrame, corrected: pd.DataFrame, chain: str, scenario: str, learner: str,
                   ) -> list[str] | None:
    """One learner's row of :func:`protocols_markdown` in one Table 1 row; None if it ran under neither protocol."""
    a = _cell(paper, chain, scenario, learner)
    b = _cell(corrected, chain, scenario, learner)
    if a is None and b is None:
        return None
    diff = (b["mean"] - a["mean"]) if a is not None and b is not None else math.nan
    return [md_escape(chain), md_escape(scenario), md_escape(learner), _mean_std(a), _mean_std(b),
            fmt(diff, signed=True), fmt((a or b)["paper"])]


def _mean_std(cell: dict[str, Any] | None) -> str:
    if cell is None or math.isnan(float(cell["mean"])):
        return DASH
    if cell["kind"] == "reference":
        return fmt(cell["mean"])
    mark = f" {INCOMPLETE}" if is_incomplete(cell) else ""
    return f"{fmt(cell['mean'])} ± {fmt(cell['std'])} (n={int(cell['n_runs'])}){mark}"


# ---------------------------------------------------------------------------------------- latex
def table1_latex(lb: Leaderboard, group: Group) -> str:
    """A booktabs tabular in the paper's layout (chain once per block, a rule between chains)."""
    table = lb.group_table(group)
    learners = [name for name in lb.learners if name in set(table["learner"])]
    references = [name for name in REFERENCE_LEARNERS if name in set(table["learner"])]
    columns = learners + references
    lines = _latex_head(group, learners, references)
    previous = None
    incomplete: list[str] = []
    for chain, scenario in lb.pairs(group):
        if previous is not None and chain != previous:
            lines.append("\\midrule")
        label = tex_escape(CHAIN_LABELS_TEX.get(chain, chain)) if chain != previous else ""
        previous = chain
        cells = []
        for name in columns:
            cell = _cell(table, chain, scenario, name)
            cells.append(_latex_cell(cell))
            if cell is not None and not math.isnan(float(cell["mean"])) and is_incomplete(cell):
                incomplete.append(f"{chain} / {scenario} / {cell['learner']}: {cell.get('incomplete_reason', '')}")
        scen = tex_escape(SCENARIO_ABBREVIATIONS.get(scenario, scenario))
        lines.append(f"{label} & {scen} & " + " & ".join(cells) + " \\\\")
    lines += _latex_foot(lb, group, incomplete)
    return "\n".join(lines) + "\n"


def _latex_head(group: Group, learners: list[str], references: list[str]) -> list[str]:
    """The provenance comments, the column spec and the two header rows (Learner | Reference)."""
    columns = learners + references
    return [
        f"% Table 1 ({tex_escape(group.label)}), generated by leaderboard.outputs.tables; needs \\usepackage{{booktabs}}.",
        f"% Mean over variants and seeds; \\scriptsize: std over seeds of the per-seed means (ddof={STD_DDOF}).",
        "\\begin{tabular}{@{} ll " + "r" * len(learners) + ("|" + "r" * len(references) if references else "") + " @{}}",
        "\\toprule",
        f" & & \\multicolumn{{{len(learners)}}}{{c}}{{Learner}}"
        + (f" & \\multicolumn{{{len(references)}}}{{c}}{{Reference}}" if references else "") + " \\\\",
        f"\\cmidrule(l){{3-{2 + len(learners)}}}"
        + (f"\\cmidrule(l){{{3 + len(learners)}-{2 + len(columns)}}}" if references else ""),
        "MC & Scenario & " + " & ".join(tex_escape(c) for c in columns) + " \\\\",
        "\\midrule",
    ]


def _latex_cell(cell: dict[str, Any] | None) -> str:
    """One cell: the mean (bold when best), a learner's std and interval, a dagger when incomplete."""
    if cell is None or math.isnan(float(cell["mean"])):
        return "--"
    text = fmt(cell["mean"])
    if is_bold(cell):
        text = f"\\textbf{{{text}}}"
    if cell["kind"] == "learner" and not math.isnan(float(cell["std"])):
        text += f"\\,{{\\scriptsize$\\pm${fmt(cell['std'])}}}"
    if cell["kind"] == "learner" and interval_text(cell):
        text += f"\\,{{\\scriptsize {interval_text(cell)}}}"  # the space: "\\scriptsizeseeds" would be one undefined control word
    if is_incomplete(cell):
        text += "$^\\dagger$"
    return text


def _latex_foot(lb: Leaderboard, group: Group, incomplete: list[str]) -> list[str]:
    """The closing rules and the notes: interval and bold rule, the dagger, the abbreviations used."""
    lines = ["\\bottomrule", "\\end{tabular}"]
    lines.append(f"\\par\\smallskip{{\\footnotesize Brackets: 95\\% bootstrap interval of the mean (whole seeds "
                 f"resampled, each with all its variants; {tex_escape(DIGITS_RULE)}); with fewer than "
                 f"{fewest_units_for_interval()} seeds, the per-seed means instead; {BOLD_RULE_TEX}}}")
    if not comparable_preset(group.preset):
        lines.append(f"\\par\\smallskip{{\\footnotesize {tex_escape(not_comparable_text(group.preset))}: trained at another "
                     "budget than the paper's (preset paper); not to be compared with the paper's Table 1.}}")
    if incomplete:
        lines.append("\\par\\smallskip{\\footnotesize $^\\dagger$ incomplete: fewer results than the scenario's "
                     "variants times the preset's seeds; not comparable with the paper.}")
        lines += [f"% incomplete: {tex_escape(item)}" for item in incomplete]
    used = sorted({s for _, s in lb.pairs(group) if s in SCENARIO_ABBREVIATIONS})
    if used:
        lines.append("% Abbreviations: " + ", ".join(f"{SCENARIO_ABBREVIATIONS[s]} ({s})" for s in used) + ".")
    return lines


# ---------------------------------------------------------------------------------------- files
def _write_text(path: Path, text: str) -> Path:
    return write_atomically(path, lambda fh: fh.write(text.encode("utf-8")))


def write_tables(lb: Leaderboard, out_dir: Path, results_name: str | None = None, stamp: str = "") -> list[Path]:
    """Write every table file into ``out_dir`` (the results directory); returns the paths written.

    Each file atomically (:func:`~morality_gym.clitools.write_atomically`): a build killed or out
    of disk space leaves each table whole, the previous one or the new one."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    if lb.primary is not None:
        written.append(_write_text(out_dir / "table1.csv", csv_rows(lb.table, lb.primary).to_csv(
            index=False, columns=CSV_COLUMNS, float_format="%.6f", lineterminator="\n")))
    written.append(_write_text(out_dir / "table1_all.csv", lb.table.to_csv(index=False, float_format="%.6f", lineterminator="\n")))
    written.append(_write_text(out_dir / "table1.md", table1_markdown(lb, results_name or out_dir.name, stamp)))
    if lb.primary is not None:
        written.append(_write_text(out_dir / "table1.tex", table1_latex(lb, lb.primary)))
    comparison = protocols_markdown(lb)
    path = out_dir / "table1_protocols.md"
    if comparison is not None:
        written.append(_write_text(path, comparison))
    else:
        path.unlink(missing_ok=True)  # a stale comparison from an earlier build would mislead
    return written
