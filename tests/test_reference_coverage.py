"""Reference rows (Random exact, Oracle best/worst) are over exactly the variants their cells cover,
and a user's chain gets them too (issue #22).

A ``variant=[HumanA,HumanB]`` sweep showed the 12-variant means (Random exact 0.280, Oracle best
0.976) beside cells over two variants, and normalised them with those; a sweep with a chain file
got "1 failed" reference rows and no reason. Both through the real sweep and build commands.
"""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from leaderboard.runs.aggregate import compute_reference
from leaderboard.stats.ranking import ranking_rows
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.oracle import oracle
from morality_gym.norms.chain import parse_chain

REPO = Path(__file__).resolve().parents[1]
VARIANTS = ["HumanA", "HumanB"]
#: A chain of the user's: it cannot score the animal or robot variants (none of its norms is relevant there).
MY_CHAIN = "name: HumanFirst\nabbreviation: HF\nnorms:\n  - n_human_harm\n  - push\n"


def cli(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", *argv], cwd=REPO, check=False, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    root = tmp_path_factory.mktemp("coverage")
    chain = root / "human_first.yaml"
    chain.write_text(MY_CHAIN)
    for selection in ("chain=utility", f"chain={chain}"):
        out = cli("runners.sweep", "algo=random", selection, "scenario=switch_standard", f"variant=[{','.join(VARIANTS)}]",
                  "preset=smoke", "mlflow=false", "gif=false", f"results_dir={root / 'results'}")
        assert out.returncode == 0, out.stderr[-3000:]
    build = cli("leaderboard.build", "--results", str(root / "results"))
    assert build.returncode == 0, build.stderr[-3000:]
    return root / "results", build.stdout


def _rows(results: Path, chain: str) -> dict[str, dict[str, str]]:
    with (results / "table1.csv").open() as fh:
        return {r["learner"]: r for r in csv.DictReader(fh) if r["chain"] == chain and r["scenario"] == "SwitchStandard"}


@pytest.mark.slow
@pytest.mark.parametrize("chain", ["Utility", "HumanFirst"])
def test_references_are_over_the_variants_the_cells_cover(built: tuple[Path, str], chain: str) -> None:
    results, _ = built
    rows = _rows(results, chain)
    ids = [f"SwitchStandard-{v}-v1" for v in VARIANTS]
    target = chain if chain == "Utility" else parse_chain(yaml.safe_load(MY_CHAIN), source="test")
    random_exact = sum(exact_evaluate("random", e, target, max_steps=200, beta=0.1).metric for e in ids) / 2
    best = sum(oracle(e, target, beta=0.1, max_steps=200).best.metric for e in ids) / 2
    assert float(rows["Random (exact)"]["mean"]) == pytest.approx(random_exact, abs=1e-6)
    assert float(rows["Oracle best"]["mean"]) == pytest.approx(best, abs=1e-6)
    if chain == "Utility":  # the numbers of the issue: 0.2685 and 1.0 (the 12-variant means are 0.280, 0.976)
        assert random_exact == pytest.approx(0.2685, abs=1e-4) and best == pytest.approx(1.0)
    for learner in ("Random (exact)", "Oracle best", "Oracle worst"):
        assert rows[learner]["n_variants"] == "2" and rows[learner]["n_variants_expected"] == "12"
        assert rows[learner]["complete"] == "False"
        assert "over the 2 of 12 variants the row's runs cover (HumanA, HumanB)" in rows[learner]["incomplete_reason"]


@pytest.mark.slow
def test_a_users_chain_gets_reference_rows_and_failures_say_why(built: tuple[Path, str], tmp_path: Path) -> None:
    _, summary = built
    assert "reference rows: 2 computed, 0 from cache" in summary and "failed" not in summary.split("reference rows:")[1].split("\n")[0]
    # A row that cannot be computed is named with its reason (here: a scenario nobody registered).
    result = compute_reference([("Utility", "NoSuchScenario", 0.1, 200)], tmp_path / "cache.json")
    assert result.errors and "NoSuchScenario" in next(iter(result.errors.values()))


def test_a_row_whose_learners_cover_different_variants_is_not_normalised() -> None:
    """One reference cannot be over the variants of two cells that differ: such a row keeps its raw
    metric in the ranking but gets no normalised score (it would be normalised by other variants)."""
    runs = pd.DataFrame([
        {"protocol": "paper", "preset": "smoke", "chain": "Utility", "scenario": "SwitchStandard", "learner": learner,
         "variant": variant, "seed": 41, "metric": 0.5, "ok": True}
        for learner, variants in (("Random", VARIANTS), ("Lever", VARIANTS[:1])) for variant in variants
    ])
    references = {("Utility", "SwitchStandard"): (0.2685, 1.0)}
    rows = ranking_rows(runs, references)
    assert not rows["normalised"].iloc[0] and "cover different variants" in rows["note"].iloc[0]
    assert rows["in_metric"].iloc[0]
    even = ranking_rows(runs.loc[runs["variant"] == "HumanA"], references)
    assert even["normalised"].iloc[0]


@pytest.mark.slow
@pytest.mark.parametrize(("flag", "value", "hint"), [("--protocol", "papr", "did you mean paper?"), ("--preset", "smok", "did you mean smoke?")])
def test_a_primary_table_choice_no_sweep_has_is_one_line(built: tuple[Path, str], tmp_path: Path, flag: str, value: str,
                                                         hint: str) -> None:
    """Sibling found while checking the build's options: a misspelt --protocol/--preset was accepted and chose nothing."""
    results, _ = built
    out = cli("leaderboard.build", "--results", str(results), "--out", str(tmp_path), "--no-reference", flag, value)
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2 and len(lines) == 1 and "Traceback" not in out.stderr, out.stderr
    assert lines[0].startswith(f"error: {flag} {value}: no sweep in the results has it ({hint})")
