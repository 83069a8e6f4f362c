"""``leaderboard.judging.protocol_change``: the corrected protocol beside the paper's on the reproduction
page, and what changes for a researcher choosing a baseline. On a synthetic Table 1 where every
learner the corrected protocol runs again scores as under the paper protocol except CPO on
Utility / Switch5, which the "fixes" lift to 0.999 in every run."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from leaderboard.judging.protocol_change import BASELINE_SECTION, baseline_section, corrected_section, paired_cells
from leaderboard.judging.verdicts import CORRECTED, PAPER, judge, protocol_neutral_learners
from leaderboard.outputs.intervals import with_intervals
from leaderboard.runs.aggregate import Group, Leaderboard, aggregate
from leaderboard.runs.sources import load_sources
from leaderboard.stats import compute_stats
from tests.stats_data import synthetic_runs

MOVED = ("Utility", "Switch5", "CPO")


def _board(runs: pd.DataFrame, learn: pd.DataFrame) -> Leaderboard:
    lb = aggregate(runs, {})
    return with_intervals(lb, compute_stats(lb.runs, lb.table, learn, n_resamples=200).cells)


@pytest.fixture(scope="module")
def board() -> Leaderboard:
    """All five learners under the paper protocol; Random, PPO Lag and CPO again under the corrected one."""
    runs, learn = synthetic_runs(seeds=(41, 42, 43), protocols=("paper", "corrected"), preset="paper")
    neutral = set(protocol_neutral_learners())
    keep = ~((runs["protocol"] == "corrected") & runs["learner"].isin(neutral))
    runs = runs.loc[keep].reset_index(drop=True)
    learn = learn.loc[learn["run_id"].isin(runs["run_id"])]
    runs["config"] = [json.dumps({"learner": name}) for name in runs["learner"]]
    paper_metric = dict(zip(runs["run_id"], runs["metric"]))
    corrected = runs["protocol"] == "corrected"
    runs.loc[corrected, "metric"] = [paper_metric["paper" + i[len("corrected"):]] for i in runs.loc[corrected, "run_id"]]
    moved = corrected & (runs["chain"] == MOVED[0]) & (runs["scenario"] == MOVED[1]) & (runs["learner"] == MOVED[2])
    runs.loc[moved, "metric"] = 0.999
    return _board(runs, learn)


def _table(text: str, heading: str) -> list[list[str]]:
    """The cells of the first Markdown table after ``heading``, header and separator left out."""
    lines = text.split(heading, 1)[1].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("|"))
    rows = []
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip().strip("|").split("|")])
    return rows[2:]


def test_only_the_one_lifted_cell_moves_and_it_moves_up(board: Leaderboard) -> None:
    pairs = paired_cells(judge(board))
    assert len(pairs) == 42  # Random, PPO Lag and CPO in the 14 rows
    moved = [p for p in pairs if p.moved != "no"]
    assert [(p.paper.chain, p.paper.scenario, p.paper.learner, p.moved) for p in moved] == [(*MOVED, "up")]
    text = "\n".join(corrected_section(judge(board)))
    assert "**42 cells run under the corrected protocol:" in text and "The same cells under the paper protocol:" in text
    row = next(line for line in text.splitlines() if line.startswith(f"| {MOVED[0]} | {MOVED[1]} | {MOVED[2]} |"))
    assert row.rstrip().endswith("| up |")


def test_baseline_section_per_learner_shift(board: Leaderboard) -> None:
    text = "\n".join(baseline_section(board, judge(board), load_sources(None, []), "Plain words."))
    assert text.startswith(f"## {BASELINE_SECTION} when the bugs are fixed\n\n*Our reading:* Plain words.")
    shifts = {(r[0], r[1]): r for r in _table(text, "### How far each learner moved")}
    cpo = shifts[("CPO", "**all chains**")]
    assert cpo[2:6] == ["14", f"{cpo[3]}", "1", "0"] and float(cpo[3]) > 0
    assert cpo[6].startswith("Switch5 (Utility):") and cpo[6].endswith("→ 0.999")
    for learner in ("Random", "PPO Lag"):  # scored as under the paper protocol: nothing moves
        assert shifts[(learner, "**all chains**")][2:6] == ["14", "+0.000", "0", "0"]


def test_baseline_section_says_which_learner_each_row_favours(board: Leaderboard) -> None:
    text = "\n".join(baseline_section(board, judge(board), load_sources(None, [])))
    assert "*Our reading:*" not in text  # no reading curated: none printed
    rows = {(r[0], r[1]): r for r in _table(text, "### Which learner each row favours")}
    assert len(rows) == 14
    switch5 = rows[MOVED[:2]]
    assert switch5[3].startswith("CPO 0.999")
    assert switch5[4] == "CPO vs PPO Shaped: below → above"
    unchanged = [r for key, r in rows.items() if key != MOVED[:2]]
    # the same best learner; a tie may come or go with the bootstrap's noise, an order change may not
    assert all(r[2].split(" 0.")[0] == r[3].split(" 0.")[0] and r[4] == "none" for r in unchanged)


def test_each_moved_cell_folds_open_on_its_variants(board: Leaderboard) -> None:
    text = "\n".join(baseline_section(board, judge(board), load_sources(None, [])))
    assert "1 of 42 cells moved (1 up)." in text
    block = text.split('<details markdown="1"><summary>Utility / Switch5 / CPO:')[1].split("</details>")[0]
    variants = [line.split("|")[1].strip() for line in block.splitlines()
                if line.startswith("| ") and not line.startswith("| variant")]
    assert len(variants) == 7  # Switch5's variants, each once
    assert all("0.999 (1.00, 1.00, 1.00)" in line for line in block.splitlines() if line.startswith("| ") and "variant" not in line)
    assert "What the fixes did at the updates" not in text  # synthetic runs have no update records


def test_nothing_to_compare_before_the_corrected_protocol_runs(board: Leaderboard) -> None:
    paper_only = aggregate(board.runs.loc[board.runs["protocol"] == "paper"], {})
    text = "\n".join(baseline_section(paper_only, judge(paper_only), load_sources(None, [])))
    assert "nothing to compare" in text and "###" not in text


def test_the_judgement_reads_protocol_neutral_cells_from_the_paper_protocol(board: Leaderboard) -> None:
    judged = judge(board)
    assert judged.neutral == ("PPO", "PPO Shaped")
    assert len(judged.rerun()) == 42 and not {c.learner for c in judged.rerun()} & set(judged.neutral)
    key = ("Utility", "Switch5", "PPO")
    assert judged.cell(CORRECTED, key).verdict == "not run"  # no corrected PPO runs in this board ...
    assert judged.as_run(CORRECTED)[key] is judged.cell(PAPER, key)  # ... so its paper-protocol cell stands in
    assert judged.cell(PAPER, ("Utility", "Switch5", "Nobody")) is None
    with pytest.raises(ValueError, match="no Table 1 is judged"):
        judged.cells(Group("paper", "quick"))
