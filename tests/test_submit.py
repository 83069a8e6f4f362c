"""``python -m leaderboard.submit``: an external policy scored into a results directory and shown
by ``python -m leaderboard.build`` as an entry of its own (real Parquet files, real builds)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest

from morality_gym.baselines.policy_ref import load_policy
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.montecarlo import evaluate
from morality_gym.results.schema import run_files, run_schema

REPO = Path(__file__).resolve().parent.parent
ENV = "SwitchStandard-HumanA-v1"
#: A hand-written rule for SwitchStandard: pull the lever while it is in state 0 (the agent starts
#: next to it; ``obs[4:6]`` is the lever's one-hot state), then wait: a fixed function of the observation.
RULE = """
import numpy as np


def act(obs):
    obs = np.asarray(obs)
    return 5 if obs[5] == 0 else 4


def cautious(obs):
    p = np.full(6, 0.02)
    p[4] = 0.9
    return p


COUNT = [0]


def restless(obs):
    COUNT[0] += 1
    return COUNT[0] % 6


def nine(obs):
    return 9


def picky(obs):
    if obs[5] == 1:
        raise KeyError("lever pulled")
    return 5
"""
SELECTION = ["--chain", "utility", "--scenario", "switch_standard", "--variant", "HumanA"]


def submit(results: Path, policy: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "leaderboard.submit", policy, "--results", str(results), *args],
                          cwd=REPO, check=False, capture_output=True, text=True, timeout=600)


def build(results: Path, site: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "leaderboard.build", "--results", str(results), "--site", str(site),
                           "--no-reference"], cwd=REPO, check=False, capture_output=True, text=True, timeout=600)


def runs_of(results: Path) -> pd.DataFrame:
    return pd.concat([pq.read_table(p).to_pandas() for p in run_files(results)], ignore_index=True)


@pytest.fixture()
def rule(tmp_path: Path) -> Path:
    path = tmp_path / "my_rule.py"
    path.write_text(RULE)
    return path


def test_submit_build_resubmit_and_supersede(rule: Path, tmp_path: Path) -> None:
    results, site = tmp_path / "results", tmp_path / "site"
    out = submit(results, f"{rule}:act", "--name", "Lever rule", "--submitter", "ada", *SELECTION)
    assert out.returncode == 0, out.stderr
    assert "wrote 3 run(s), 0 already present" in out.stdout

    # Schema-valid rows, one per seed of the paper preset, with the paper's final evaluation.
    files = run_files(results)
    assert len(files) == 3
    for path in files:
        table = pq.read_table(path)
        assert table.schema == run_schema(["n_human_harm", "n_animal_harm", "n_robot_harm"])  # Utility's norms
    runs = runs_of(results).sort_values("seed")
    assert list(runs["seed"]) == [41, 42, 43]
    assert set(runs["algo"]) == {"submitted"} and set(runs["learner"]) == {"Lever rule"}
    assert set(runs["protocol"]) == {"paper"} and set(runs["preset"]) == {"paper"}
    assert set(runs["eval_episodes"]) == {100} and set(runs["max_steps"]) == {200} and set(runs["beta"]) == {0.1}
    policy = load_policy(f"{rule}:act").policy
    for row in runs.to_dict("records"):
        direct = evaluate(policy, ENV, "Utility", n_episodes=100, seed=row["seed"], max_steps=200, keep_episodes=False)
        assert row["metric"] == direct.metric and row["mean_return"] == direct.mean_return
        assert row["mf_n_human_harm"] == direct.functions["n_human_harm"]
        assert row["exact_metric"] == pytest.approx(exact_evaluate(policy, ENV, "Utility").metric, abs=1e-12)
        config = json.loads(row["config"])
        assert config["policy"]["stationary"] is True and config["policy"]["attribute"] == "act"
        assert config["provenance"]["submitter"] == "ada" and config["provenance"]["policy"] == f"{rule}:act"
        assert config["policy"]["sha256"] == load_policy(f"{rule}:act").sha256()
        assert row["git_commit"] and row["started_at"].endswith("+00:00")
        assert (results / row["gif_path"]).is_file()

    # The leaderboard shows it as an entry of its own, marked as submitted.
    done = build(results, site)
    assert done.returncode == 0, done.stderr + done.stdout
    html = (site / "index.html").read_text()
    row = re.search(r'<tr [^>]*data-learner="Lever rule"[^>]*>(.*?)</tr>', html).group(1)
    assert '<td class="learner">' in row and 'class="badge submitted" title="external policy submitted by ada' in row
    assert 'class="badge submitted"' not in html.replace(row, "").split("<tbody>")[1].split("</tbody>")[0]
    assert "| Lever rule (submitted) |" in (results / "table1.md").read_text()
    csv = pd.read_csv(results / "table1.csv")
    cell = csv.loc[csv["learner"] == "Lever rule"].iloc[0]
    assert cell["mean"] == pytest.approx(runs["metric"].mean(), abs=1e-12) and cell["n_runs"] == 3

    # The same file, name and cell again: nothing new, nothing rewritten.
    before = {p.name: p.read_bytes() for p in run_files(results)}
    again = submit(results, f"{rule}:act", "--name", "Lever rule", "--submitter", "bob", *SELECTION)
    assert again.returncode == 0 and "wrote 0 run(s), 3 already present" in again.stdout
    assert {p.name: p.read_bytes() for p in run_files(results)} == before

    # A changed file: new runs, counted; the old ones are reported as superseded.
    rule.write_text(RULE.replace("else 4", "else 2"))
    changed = submit(results, f"{rule}:act", "--name", "Lever rule", *SELECTION)
    assert changed.returncode == 0 and "wrote 3 run(s), 0 already present" in changed.stdout
    assert len(run_files(results)) == 6
    rebuilt = build(results, site)
    assert rebuilt.returncode == 0, rebuilt.stderr
    assert "3 superseded" in rebuilt.stdout
    new_policy = load_policy(f"{rule}:act").policy
    expected = sum(evaluate(new_policy, ENV, "Utility", n_episodes=100, seed=s, max_steps=200).metric for s in (41, 42, 43)) / 3
    csv = pd.read_csv(results / "table1.csv")
    assert csv.loc[csv["learner"] == "Lever rule", "mean"].iloc[0] == pytest.approx(expected, abs=1e-12)


def test_probabilities_non_stationary_policies_and_cells(rule: Path, tmp_path: Path) -> None:
    results = tmp_path / "results"
    out = submit(results, f"{rule}:cautious", "--name", "Cautious", "--preset", "smoke", "--no-gif",
                 "--chain", "Utility", "--chain", "DP", "--scenario", "SwitchStandard", "--scenario", "push_or_switch",
                 "--variant", "HumanA", "--variant", "Human")
    assert out.returncode == 0, out.stderr
    runs = runs_of(results)
    cells = set(zip(runs["chain"], runs["env_id"]))
    assert cells == {(c, e) for c in ("Utility", "DualProcess") for e in ("SwitchStandard-HumanA-v1", "PushOrSwitch-Human-v1")}
    assert runs["gif_path"].isna().all() and runs["exact_metric"].notna().all()

    moving = submit(results, f"{rule}:restless", "--name", "Restless", "--preset", "smoke", "--no-gif", *SELECTION)
    assert moving.returncode == 0, moving.stderr
    assert "not stationary" in moving.stdout
    row = runs_of(results).query("learner == 'Restless'").iloc[0]
    assert pd.isna(row["exact_metric"]) and json.loads(row["config"])["policy"]["stationary"] is False
    assert 0 <= row["metric"] <= 1


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["{rule}:act", "--name", "x", "--chain", "utilty"], "utilty"),
        (["{rule}:act", "--name", "x", "--chain", "utility", "--scenario", "switch_standrd"], "Did you mean"),
        (["{rule}:act", "--name", "x", *SELECTION[:4], "--variant", "HumanZ"], "--variant HumanZ"),
        (["{rule}:actt", "--name", "x", *SELECTION], "did you mean act?"),
        (["no_such_policy_module:act", "--name", "x", *SELECTION], "cannot import module"),
        (["{rule}:nine", "--name", "x", *SELECTION], "the policy returned action 9"),
        (["{rule}:picky", "--name", "x", *SELECTION], "failed on a reachable state of SwitchStandard-HumanA-v1 (KeyError"),
        (["{rule}:act", "--name", "PPO", *SELECTION], "name of a baseline"),
        (["{rule}:act", "--name", "x", "--preset", "papr", *SELECTION], "did you mean paper?"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(rule: Path, tmp_path: Path, args: list[str], message: str) -> None:
    results = tmp_path / "results"
    argv = [a.format(rule=rule) for a in args]
    out = subprocess.run([sys.executable, "-m", "leaderboard.submit", *argv, "--results", str(results)],
                         cwd=REPO, check=False, capture_output=True, text=True, timeout=300)
    assert out.returncode == 2, out.stderr
    assert message in out.stderr and len(out.stderr.strip().splitlines()) == 1 and "Traceback" not in out.stderr
    assert not results.exists() or run_files(results) == []


@pytest.mark.browser
def test_the_submitted_entry_is_visible_in_a_browser(rule: Path, tmp_path: Path) -> None:
    """The row of a submission, with its badge, is on the page Chromium renders (and filterable)."""
    import tempfile

    from leaderboard.screenshot import CHROMIUM, launch_browser

    if not CHROMIUM.is_file():
        pytest.skip(f"Debian's chromium is not installed at {CHROMIUM}")
    sync_api = pytest.importorskip("playwright.sync_api")
    results, site = tmp_path / "results", tmp_path / "site"
    assert submit(results, f"{rule}:act", "--name", "Lever rule", "--preset", "smoke", "--no-gif", *SELECTION).returncode == 0
    assert submit(results, "random", "--name", "Coin flipper", "--preset", "smoke", "--no-gif", *SELECTION).returncode == 0
    assert build(results, site).returncode == 0
    with tempfile.TemporaryDirectory(prefix="lb-chromium-") as profile, sync_api.sync_playwright() as pw:
        context = launch_browser(pw, Path(profile))
        try:
            page = context.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.goto((site / "index.html").resolve().as_uri())
            row = page.locator('#table1 tbody tr[data-learner="Lever rule"]')
            assert row.is_visible()
            badge = row.locator("td.learner .badge.submitted")
            assert badge.is_visible() and badge.inner_text() == "submitted"
            assert "submitted by" in (badge.get_attribute("title") or "")
            page.select_option('select[data-filter="learner"]', "Coin flipper")
            assert not row.is_visible()
            assert page.locator('#table1 tbody tr[data-learner="Coin flipper"] .badge.submitted').is_visible()
            assert errors == []
        finally:
            context.close()


def test_a_submission_records_its_budget_and_another_budget_is_not_compared(rule: Path, tmp_path: Path) -> None:
    """Issue 45: submitted runs recorded budget 0, so a 2,048-step policy stood beside 1M-step baselines
    and the paper's values with a Δ. ``--budget`` is recorded; at another budget than the preset's
    (paper: 500,000 for SwitchStandard) the cell is not comparable: no Δ, no best."""
    results = tmp_path / "results"
    out = submit(results, f"{rule}:act", "--name", "Short", "--budget", "2048", "--no-gif", *SELECTION)
    assert out.returncode == 0, out.stderr
    assert f"now: make leaderboard RESULTS={results}" in out.stdout  # the site the user has, with the releases
    runs = runs_of(results)
    assert set(runs["budget"]) == {2048} and set(runs["total_steps"]) == {2048}
    assert {json.loads(c)["budget"] for c in runs["config"]} == {2048}
    out = submit(results, f"{rule}:act", "--name", "Rule", "--no-gif", *SELECTION)  # not trained: comparable
    assert out.returncode == 0, out.stderr
    done = build(results, tmp_path / "site")
    assert done.returncode == 0, done.stderr
    table = pd.read_csv(results / "table1.csv", keep_default_na=False)
    short, plain = (table.loc[table["learner"] == name].iloc[0] for name in ("Short", "Rule"))
    assert short["delta_note"] == "not comparable: trained 2,048 steps" and short["delta"] == ""
    assert plain["delta_note"] == ""  # no paper value of its own, and nothing to mark
    index = (tmp_path / "site" / "index.html").read_text()
    assert '<span class="paper nc">not comparable: trained 2,048 steps</span>' in index
    negative = submit(results, f"{rule}:act", "--name", "Short", "--budget", "-1", *SELECTION)
    assert negative.returncode == 2 and "--budget" in negative.stderr and "Traceback" not in negative.stderr
