"""``leaderboard.reproduction``: the verdict rule, the evidence of a deviating cell, Figure 2's claims,
and the page as a whole, on a synthetic paper-preset Table 1 (all 70 cells, three seeds)."""

from __future__ import annotations

import json
import math
import re
import string
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

from leaderboard.judging.baseline_facts import baseline_facts, fill_reading
from leaderboard.judging.protocol_change import BASELINE_SECTION, corrected_section
from leaderboard.judging.verdicts import CORRECTED, PAPER, cells, judge, protocol_neutral_learners, verdict
from leaderboard.outputs.intervals import with_intervals
from leaderboard.reproduction import NOTES_FILE, Readings, check_notes, figure2_claims, load_notes, page, table1_claims
from leaderboard.runs.aggregate import aggregate, compute_reference, csv_rows, reference_requests, with_reference
from leaderboard.runs.sources import load_sources
from leaderboard.stats import compute_stats
from leaderboard.stats.cells import bold_cells, cell_intervals
from morality_gym.clitools import UserError
from morality_gym.norms.chain import builtin_chains
from tests.stats_data import synthetic_runs


def test_verdict_rule() -> None:
    assert verdict(0.50, 0.45, 0.55, 0.02, 0.52, True) == "reproduces"  # inside the interval
    assert verdict(0.50, 0.48, 0.52, 0.03, 0.55, True) == "close"  # outside it, within 2 sd
    assert verdict(0.50, 0.48, 0.52, 0.01, 0.55, True) == "deviates"
    assert verdict(0.50, 0.45, 0.55, 0.02, 0.52, False) == "not run"  # never a verdict on a partial cell
    assert verdict(math.nan, math.nan, math.nan, math.nan, 0.52, True) == "not run"
    # the paper prints three decimals: every run at 0.01904 reproduces its 0.019, one at 0.0196 does not
    assert verdict(0.01904, 0.01904, 0.01904, 0.0, 0.019, True) == "reproduces"
    assert verdict(0.0196, 0.0196, 0.0196, 0.0, 0.019, True) == "deviates"
    assert verdict(0.50, 0.48, 0.5195, 0.0, 0.52, True) == "reproduces"  # 0.52 stands for up to 0.5205


@pytest.fixture(scope="module")
def reference_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One reference-rows cache for the module: the exact Random and oracle rows of Table 1 depend only
    on (chain, scenario, beta, max_steps) and the chains' norms, the same for the synthetic board and
    the shipped release, so they are computed once (~10-15 s) and read back after (a cached entry
    equals a computed one: tests/test_build_cache.py::test_computed_reference_rows_equal_the_cached_ones)."""
    return tmp_path_factory.mktemp("ref") / "reference_rows.json"


@pytest.fixture(scope="module")
def board(reference_cache: Path):
    runs, learn = synthetic_runs(seeds=(41, 42, 43), preset="paper")
    runs["config"] = [json.dumps({"learner": name}) for name in runs["learner"]]
    # one cell pushed far below the paper on two variants: its diagnosis must name them first
    sel = (runs["chain"] == "Utility") & (runs["scenario"] == "Switch5") & (runs["learner"] == "CPO")
    bad = sel & runs["variant"].isin(["Human", "HumanAnimal"])
    runs.loc[bad, "metric"] = 0.05
    lb = aggregate(runs, {})
    # the chains' definitions, as a build passes those of real runs: entries that carry them serve the
    # release's page below too (an entry without them is computed again for runs that define their chain)
    reference = compute_reference(reference_requests(lb.table), reference_cache, None, builtin_chains())
    lb = with_reference(lb, reference.entries, reference.errors, "paper", "paper")
    stats = compute_stats(lb.runs, lb.table, learn, n_resamples=200)
    return with_intervals(lb, stats.cells), learn


def test_every_cell_gets_a_verdict_and_the_page_explains_the_deviations(board, tmp_path: Path) -> None:
    lb, learn = board
    table = cells(lb, PAPER)
    assert len(table) == 70 and all(c.verdict in ("reproduces", "close", "deviates") for c in table)
    cpo = next(c for c in table if (c.chain, c.scenario, c.learner) == ("Utility", "Switch5", "CPO"))
    assert cpo.verdict == "deviates" and cpo.mean < cpo.paper
    sources = load_sources(None, [])
    text = page(lb, judge(lb), sources, learn, tmp_path, "img", Readings(cells={("Utility", "Switch5", "CPO"): "A curated reading."}))
    counts = {v: sum(c.verdict == v for c in table) for v in ("reproduces", "close", "deviates")}
    assert f"**{counts['reproduces']} of 70 cells reproduce, {counts['close']} are close, {counts['deviates']} deviate" in text
    assert text.count("\n| ") >= 70
    section = text.split("### Utility / Switch5 / CPO: deviates")[1].split("###")[0]
    assert "Reachable range over these variants: oracle worst" in section
    variant_rows = [line for line in section.splitlines() if line.startswith("| ") and "variant" not in line and "---" not in line]
    assert {variant_rows[0].split("|")[1].strip(), variant_rows[1].split("|")[1].strip()} == {"Human", "HumanAnimal"}
    assert "Learning curve (mean learn-time metric over the cell's runs): 0k:" in section
    assert "*Our reading:* A curated reading." in section
    assert "Morality function per norm" in section


def test_three_seed_cells_print_their_seeds_and_a_knife_edge_verdict_is_marked(board, tmp_path: Path) -> None:
    lb, learn = board
    table = cells(lb, PAPER)
    # three seeds: no interval, the per-seed means instead, and "reproduces" means within their range
    c = table[0]
    assert c.seed_range and c.interval().startswith("seeds ") and len(c.interval().split(",")) == 3
    assert not any(cell.borderline for cell in table)  # exact bounds: no bootstrap seed can flip a verdict
    text = page(lb, judge(lb), load_sources(None, []), learn, tmp_path, "img", Readings())
    assert "No verdict is borderline" in text and f"| {c.interval()} |" in text
    # under the old rule the bounds are bootstrap quantiles with a Monte Carlo error: put the paper's value
    # of one cell 1.5 errors inside its lower bound (less the rounding) and it is marked, on the page and in the CSV
    stats = compute_stats(lb.runs, lb.table, None, n_resamples=200, resampling="variant")
    old = with_intervals(lb, stats.cells)
    key = (old.table["protocol"] == "paper") & (old.table["chain"] == c.chain) & (old.table["scenario"] == c.scenario) \
        & (old.table["learner"] == c.learner)
    row = old.table.loc[key].iloc[0]
    assert row["ci_low_mcse"] > 0
    table_edge = old.table.copy()
    table_edge.loc[key, "paper"] = row["ci_low"] - 0.0005 + 1.5 * row["ci_low_mcse"]
    table_edge.loc[key, "delta"] = row["mean"] - table_edge.loc[key, "paper"]
    edged = with_intervals(replace(old, table=table_edge), stats.cells)
    assert bool(edged.table.loc[key, "borderline"].iloc[0]) and int(edged.table["borderline"].sum()) >= 1
    assert "borderline" in csv_rows(edged.table, PAPER).columns


def test_figure2_claims_are_checked_against_the_bars(board) -> None:
    lb, _ = board
    claims = figure2_claims(lb, judge(lb), PAPER)
    assert len(claims) == 12 and all(result in ("holds", "does not hold") for _, _, result in claims)
    by_text = {text: (numbers, result) for text, numbers, result in claims}
    # synthetic PPO Shaped is the best on its top norm everywhere (level 0.95 vs <= 0.80)
    numbers, result = by_text["U: PPO Shaped achieves the highest score in minimising harm to humans"]
    assert result == "holds" and "vs CPO" in numbers
    frame = lb.norms_by_chain
    ppo = frame.loc[(frame["chain"] == "Utility") & (frame["learner"] == "PPO") & (frame["norm"] == "n_human_harm"), "mean"]
    expected = "holds" if float(ppo.iloc[0]) <= 0.1 else "does not hold"
    assert by_text["U: standard PPO almost completely fails on Min Humans Harmed, scoring close to zero"][1] == expected


def test_the_protocol_neutral_learners_come_from_the_protocol_files() -> None:
    """conf/protocol/corrected.yaml overrides PPO-Lag and CPO and Random's evaluation stream, nothing of PPO's."""
    assert protocol_neutral_learners() == ["PPO", "PPO Shaped"]


def test_table1_claims_are_checked_against_the_cells(board) -> None:
    lb, _ = board
    claims = {text: (numbers, result) for text, numbers, result in table1_claims(judge(lb), PAPER)}
    assert len(claims) == 3 and all(result in ("holds", "does not hold") for _, result in claims.values())
    # the verdict against the cells, worked out by hand
    table = judge(lb).as_run(PAPER)
    rows = {(c, s) for c, s, _ in table}
    beaten = [r for r in rows if max(table[(*r, n)].mean for n in ("Random", "PPO", "PPO Lag", "CPO")) >= table[(*r, "PPO Shaped")].mean]
    numbers, result = claims["PPO Shaped consistently achieves the highest score in all tested scenarios"]
    assert (result == "holds") == (not beaten)
    expected = f"highest in all {len(rows)} rows" if not beaten else f"not highest in {len(beaten)} of {len(rows)} rows ("
    assert numbers.startswith(expected)
    # under the corrected protocol nothing of Random, PPO Lag or CPO was run: no verdict, but PPO's own cell is its paper one
    corrected = {text: (numbers, result) for text, numbers, result in table1_claims(judge(lb), CORRECTED)}
    assert corrected["PPO Shaped consistently achieves the highest score in all tested scenarios"] == ("—", "not run")
    key = "PushOrSwitchSelfSacrifice (DPAH): standard PPO's performance collapses (0.192)"
    assert corrected[key] == claims[key]


def test_figure2_claims_under_the_corrected_protocol_take_protocol_neutral_bars_from_the_paper_protocol(board) -> None:
    lb, _ = board
    paper = {text: (numbers, result) for text, numbers, result in figure2_claims(lb, judge(lb), PAPER)}
    corrected = {text: (numbers, result) for text, numbers, result in figure2_claims(lb, judge(lb), CORRECTED)}
    only_ppo = "U: standard PPO almost completely fails on Min Humans Harmed, scoring close to zero"
    assert corrected[only_ppo] == paper[only_ppo]  # PPO trains identically under both protocols
    with_cpo = "DP: CPO scores near-perfect on the top utilitarian norm, Min Humans Harmed"
    assert corrected[with_cpo] == ("—", "not run")  # no corrected CPO runs in this board


def test_the_corrected_section_lists_the_cells_not_yet_run(board) -> None:
    lb, _ = board
    text = "\n".join(corrected_section(judge(lb)))
    assert "PPO and PPO Shaped train identically under both protocols" in text
    assert "the other learners' 42 cells, of which 0 are run in full" in text
    assert "*Not yet run in full under the corrected protocol (42 of 42 cells; no verdict):*" in text
    assert "Utility / Switch5 / CPO (no runs yet)" in text


def test_notes_keys_are_checked(tmp_path: Path) -> None:
    good = tmp_path / "notes.yaml"
    good.write_text("Utility / Switch5 / CPO: text\n")
    assert load_notes(good) == Readings(cells={("Utility", "Switch5", "CPO"): "text"})
    bad = tmp_path / "bad.yaml"
    bad.write_text("Utility Switch5 CPO: text\n")
    with pytest.raises(UserError, match="must be 'chain / scenario / learner' or a section"):
        load_notes(bad)
    assert load_notes(tmp_path / "absent.yaml") == Readings()


def test_a_reading_may_be_keyed_to_a_section(tmp_path: Path) -> None:
    notes = tmp_path / "notes.yaml"
    notes.write_text("Choosing a baseline: >-\n  In plain words.\nUtility / Switch5 / CPO: text\n")
    assert load_notes(notes) == Readings({("Utility", "Switch5", "CPO"): "text"}, {"Choosing a baseline": "In plain words."})
    notes.write_text("Choosing a basline: words\n")
    with pytest.raises(UserError, match="did you mean 'Choosing a baseline'"):
        load_notes(notes)


def test_notes_must_name_a_cell_of_table1(tmp_path: Path) -> None:
    check_notes({("Utility", "Switch5", "CPO"): "text"}, tmp_path / "notes.yaml")
    with pytest.raises(UserError, match=r"'Utility / Swich5 / CPO' is not a cell of Table 1.*did you mean 'Utility / Switch5 / CPO'"):
        check_notes({("Utility", "Swich5", "CPO"): "text"}, tmp_path / "notes.yaml")


def test_corrected_section_sets_each_corrected_cell_beside_the_paper_protocol(tmp_path: Path) -> None:
    runs, learn = synthetic_runs(seeds=(41, 42, 43), protocols=("paper", "corrected"), learners=("CPO",), preset="paper")
    runs["config"] = [json.dumps({"learner": name}) for name in runs["learner"]]
    # under the corrected protocol, Utility / Switch5 moves far up; every other run scores as under the paper protocol
    paper_metric = dict(zip(runs["run_id"], runs["metric"]))
    corrected = runs["protocol"] == "corrected"
    runs.loc[corrected, "metric"] = [paper_metric["paper" + i[len("corrected"):]] for i in runs.loc[corrected, "run_id"]]
    moved = (runs["protocol"] == "corrected") & (runs["chain"] == "Utility") & (runs["scenario"] == "Switch5")
    runs.loc[moved, "metric"] = 0.999
    lb = aggregate(runs, {})
    stats = compute_stats(lb.runs, lb.table, learn, n_resamples=200)
    lb = with_intervals(lb, stats.cells)
    text = "\n".join(corrected_section(judge(lb)))
    rows = {line.split("|")[2].strip(): line for line in text.splitlines() if line.startswith("| ") and "---" not in line}
    assert "**14 cells run under the corrected protocol:" in text  # one CPO cell per Table 1 row
    assert rows["Switch5"].rstrip().endswith("| up |")
    same = [line for name, line in rows.items() if name not in ("Switch5", "scenario")]
    assert len(same) >= 10 and all(line.rstrip().endswith("| no |") for line in same)
    empty = aggregate(runs.loc[runs["protocol"] == "paper"], {})
    assert "No cell has been run in full under the corrected protocol yet." in corrected_section(judge(empty))


@pytest.mark.parametrize(
    "curve, paper, expected",
    [
        ([0.1, 0.5, 0.6, 0.7, 0.8], 0.8, "still rising when training stopped (+0.200 over the last quarter)"),
        ([0.1, 0.6, 0.83, 0.72, 0.79], 0.786, ("swinging between 0.720 and 0.830 over the last quarter of training "
                                               "(the paper's 0.786 lies inside that range)")),
        ([0.1, 0.6, 0.83, 0.72, 0.79], 0.9, "(the paper's 0.900 lies outside that range)"),
        ([0.1, 0.6, 0.70, 0.71, 0.71], 0.9, "flat over the last quarter of training (+0.010)"),
    ],
)
def test_learning_curve_says_how_training_ended(curve: list[float], paper: float, expected: str) -> None:
    from leaderboard.reproduction import _curve_lines

    steps = [0, 250_000, 750_000, 875_000, 1_000_000]
    learn = pd.DataFrame({"run_id": "a", "step": steps, "metric": curve, "exact_metric": curve})
    assert expected in _curve_lines(learn, ["a"], paper)[1]


def test_learning_curve_flags_a_final_evaluation_far_from_the_last_learn_time_one() -> None:
    from leaderboard.reproduction import _curve_lines

    learn = pd.DataFrame({"run_id": "a", "step": [0, 500_000, 1_000_000], "metric": [0.1, 0.8, 0.795]})
    line = _curve_lines(learn, ["a"], 0.786, mean=0.699)[1]
    assert "The final evaluation (0.699) differs from the last learn-time one (0.795 at 1000k) by -0.096" in line
    assert "final evaluation" not in _curve_lines(learn, ["a"], 0.786, mean=0.78)[1]


ROOT = Path(__file__).resolve().parents[1]
def test_the_committed_reproduction_page_is_what_the_shipped_releases_make(tmp_path: Path, reference_cache: Path) -> None:
    """docs/reproduction.md says what the shipped releases' runs say, verdicts and evidence included: a
    change to the verdict rule, the evidence or the curated readings that is not regenerated fails here,
    and so does a release shipped without regenerating it (python -m leaderboard.reproduction --release all)."""
    from leaderboard.reproduction import main

    out = tmp_path / "docs" / "reproduction.md"
    code = main(["--release", "all", "--out", str(out), "--cache", str(reference_cache)])
    assert code == 0
    committed = (ROOT / "docs" / "reproduction.md").read_text()
    assert out.read_text() == committed, "docs/reproduction.md is stale: regenerate it from the release"
    assert "as the release keeps them" in committed  # shares from thinned update diagnostics say so
    # the reference's KL early stop (docs/protocols.md#ppo-lag-kl-early-stop-sums-over-states) shows in the release's own update records: the paper
    # protocol's PPO-Lag stops after one pass on almost every update, the corrected one rarely does
    lag = [line.split("|") for line in committed.split("| PPO Lag: chain |")[1].split("\n\n")[0].splitlines()[2:]]
    one_pass = {(row[1].strip(), row[2].strip()): float(row[6].strip().rstrip("%")) for row in lag}
    assert {protocol for _, protocol in one_pass} == {"paper", "corrected"}
    assert all(share >= 90 if protocol == "paper" else share <= 50 for (_, protocol), share in one_pass.items())
    for image in sorted((out.parent / "img" / "reproduction").iterdir()):
        assert (ROOT / "docs" / "img" / "reproduction" / image.name).is_file(), f"{image.name} is not committed"


def test_the_claims_the_corrected_protocol_changes_are_named_in_one_line() -> None:
    from leaderboard.reproduction import _claims_changed

    paper = [("A holds", "0.9", "holds"), ("B holds", "0.2", "does not hold"), ("C", "0.5", "holds")]
    same = [("A holds", "0.91", "holds"), ("B holds", "0.3", "does not hold"), ("C", "—", "not run")]
    assert _claims_changed(paper, same) == ("**Under the corrected protocol, none of the 2 statements checked comes out "
                                            "differently; 1 cannot be checked on the corrected protocol's runs yet (not run).**")
    flipped = [("A holds", "0.4", "does not hold"), ("B holds", "0.3", "does not hold"), ("C", "0.6", "holds")]
    assert _claims_changed(paper, flipped) == ("**Under the corrected protocol, 1 of the 3 statements checked comes out "
                                               "differently:** \"A holds\" (holds → does not hold).")


# ---------------------------------------------------------------------------------------- the baseline reading
def _baseline_reading() -> str:
    return load_notes(NOTES_FILE).sections[BASELINE_SECTION]


#: Digits the reading may carry by hand: names, not counts.
NAMED_DIGITS = ("Figure 2", "1M steps", "OmniSafe's case 0")
#: Each "only" of the reading that is no count, with why it needs no fact: Random's corrected runs
#: differ from its paper-protocol ones by their final evaluation's stream alone, by the protocol files
#: (test_the_protocol_neutral_learners_come_from_the_protocol_files: Random is not protocol-neutral for that reason alone).
DESIGN_ONLY = ("differ only by that redrawn evaluation stream",)


def test_the_baseline_reading_types_no_number_by_hand() -> None:
    """Every count and number of "Choosing a baseline" is a {fact} computed from the runs
    (leaderboard.judging.baseline_facts): a digit typed into the reading would drift from the tables."""
    reading = _baseline_reading()
    text = " ".join("".join(literal for literal, *_ in string.Formatter().parse(reading)).split())  # the words around the facts
    for phrase in NAMED_DIGITS + DESIGN_ONLY:
        text = text.replace(phrase, "")
    typed = re.findall(r"(?<![A-Za-z])\d[\d.,%]*", text)
    assert not typed, f"numbers typed by hand into the 'Choosing a baseline' reading: {typed}"
    assert not re.search(r"\bonly\b", text), "an 'only' of the reading that is no fact"


def test_the_baseline_facts_are_computed_from_the_runs() -> None:
    """On a synthetic board under both protocols where the corrected runs equal the paper protocol's but
    for PPO Lag on Utility / Switch5 (far up): the facts say so, and the reading names no fact that is not computed."""
    runs, _ = synthetic_runs(seeds=(41, 42, 43), protocols=("paper", "corrected"), preset="paper", learn=False)
    runs["config"] = [json.dumps({"learner": name}) for name in runs["learner"]]
    paper_metric = dict(zip(runs["run_id"], runs["metric"]))
    corrected = runs["protocol"] == "corrected"
    runs.loc[corrected, "metric"] = [paper_metric["paper" + i[len("corrected"):]] for i in runs.loc[corrected, "run_id"]]
    up = corrected & (runs["learner"] == "PPO Lag") & (runs["chain"] == "Utility") & (runs["scenario"] == "Switch5")
    runs.loc[up, "metric"] = 0.999
    lb = aggregate(runs, {})
    lb = with_intervals(lb, bold_cells(cell_intervals(lb.runs)))
    facts = baseline_facts(lb, judge(lb), load_sources(None, []))
    assert facts["lag_utility_moved_up"] == "1 of 6" and facts["lag_dp_moved"] == "0 of 3"
    assert facts["random_moved"] == "0 of 14" and facts["random_largest_change"].startswith("+0.000")
    assert facts["cpo_deon_rise"] == "0 of 6" and facts["cpo_utility_same_runs"].split(" of ")[0] == facts["cpo_utility_same_runs"].split(" of ")[1]
    assert "Utility / Switch5" in facts["lag_above_random_rows"]
    assert facts["reproduce_random_paper"] == facts["reproduce_random_corrected"]
    filled = fill_reading(_baseline_reading(), facts, "notes")
    assert "{" not in filled and "1 of 6 cells moved up" in filled
    with pytest.raises(UserError, match=r"names \{lag_utility_moved_upp\}, which is no fact of the page.*lag_utility_moved_up"):
        fill_reading("It moved in {lag_utility_moved_upp}.", facts, "notes")
