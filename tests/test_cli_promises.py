"""The command lines keep the README's promises about errors and what they print (issue #22).

A user's mistake (a value of the wrong type, a bad chain file, a policy that raises at any step)
is one line and exit code 2; every entry point answers ``--version``; ``eval`` says which seed a
Monte-Carlo answer came from and ``leaderboard.submit`` what it stored. Every case goes through
the real command line.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from morality_gym.results.schema import run_files

REPO = Path(__file__).resolve().parents[1]
SELECTION = ["--chain", "utility", "--scenario", "switch_standard", "--variant", "HumanA"]
#: Policies for SwitchStandard (the agent starts in column 2 of 6, obs[1] == 2/6).
POLICIES = """
import numpy as np

from morality_gym import TrolleyEnv

CALLS = [0]
_START = TrolleyEnv("SwitchStandard-HumanA-v1").reset()[0]
TABLE = {tuple(np.round(_START, 6).tolist()): [0, 0, 0, 1, 0, 0]}  # the start only: RIGHT, then no entry


def moves_then_raises(obs):
    if obs[1] != 2 / 6:  # the agent has moved: from the second step of an episode on
        raise ValueError("no plan for this square")
    return 3


def raises_late(obs):  # answers every state twice (the stationarity check), then fails mid-evaluation
    CALLS[0] += 1
    if CALLS[0] > 600:
        return 1 / 0
    return 4


def lever(obs):
    return 5 if obs[5] == 0 else 4
"""


def cli(*argv: str, timeout: int = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", *argv], cwd=REPO, check=False, capture_output=True, text=True,
                          timeout=timeout)


def one_line_exit_2(out: subprocess.CompletedProcess[str], *fragments: str) -> None:
    assert out.returncode == 2, (out.returncode, out.stderr[-2000:])
    lines = [line for line in out.stderr.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in out.stderr, out.stderr
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


@pytest.fixture()
def policies(tmp_path: Path) -> Path:
    path = tmp_path / "policies.py"
    path.write_text(POLICIES)
    return path


# ---------------------------------------------------------------------------------------- sweep values
SWEEP = ["runners.sweep", "algo=random", "chain=utility", "scenario=switch_standard", "dry_run=true", "mlflow=false"]


@pytest.mark.parametrize(
    ("override", "fragments"),
    [
        ("seed=abc", ["seed: expected an integer >= 0, got 'abc'"]),
        ("seed=1.5", ["seed: expected an integer >= 0, got 1.5"]),
        ("seed=[41,x]", ["seed: expected an integer >= 0, got 'x'"]),
        ("variant=1", ["variant: '1' is not a variant of the selected scenarios", "valid: AnimalA"]),
        ("variant={a:1}", ["variant: expected a variant name or a list of them"]),
    ],
)
def test_a_sweep_value_of_the_wrong_type_is_one_line(tmp_path: Path, override: str, fragments: list[str]) -> None:
    out = cli(*SWEEP, f"results_dir={tmp_path}", override)
    one_line_exit_2(out, "configuration error:", *fragments)


def test_a_device_rate_that_is_not_a_mapping_is_one_line_naming_its_key(tmp_path: Path) -> None:
    """The typed schema (DeviceRate) refuses it while composing, so the planner keeps no check of its own."""
    sweep = [a if a != "algo=random" else "algo=ppo" for a in SWEEP]
    out = cli(*sweep, f"results_dir={tmp_path}", "algo.ppo.planning.devices.cuda=5")
    one_line_exit_2(out, "configuration error:", "algo.ppo.planning.devices.cuda (command line)",
                    "int is not a subclass of DeviceRate")


def test_a_sweep_names_the_bad_norm_of_a_users_chain_file(tmp_path: Path) -> None:
    chain = tmp_path / "my_chain.yaml"
    chain.write_text("name: Mine\nnorms:\n  - n_human_harmm\n  - push\n")
    out = cli(*[a for a in SWEEP if not a.startswith("chain=")], f"chain={chain}", f"results_dir={tmp_path}")
    one_line_exit_2(out, f"chain={chain}: norms[0]: unknown norm 'n_human_harmm'", "Did you mean n_human_harm")
    missing = cli(*[a for a in SWEEP if not a.startswith("chain=")], f"chain={tmp_path / 'nope.yaml'}", f"results_dir={tmp_path}")
    one_line_exit_2(missing, "does not exist")


def test_an_algo_file_whose_class_cannot_be_imported_is_one_line_in_all(tmp_path: Path) -> None:
    """Hydra logged its own three lines on stdout before our one line on stderr."""
    (tmp_path / "conf" / "algo").mkdir(parents=True)
    (tmp_path / "conf" / "algo" / "mine.yaml").write_text("# @package algo.mine\n_target_: no_such_module.Learner\n")
    out = cli("runners.sweep", f"--config-dir={tmp_path / 'conf'}", "algo=mine", *SWEEP[2:], f"results_dir={tmp_path}")
    one_line_exit_2(out, "algo=mine", "cannot import 'no_such_module.Learner'")
    assert out.stdout.strip() == ""


def test_a_sweep_on_a_skipped_scenario_file_says_why(tmp_path: Path) -> None:
    (tmp_path / "scenarios").mkdir()
    (tmp_path / "scenarios" / "broken.yaml").write_text("name: Broken\nrewards: {step: -1}\n")
    out = subprocess.run([sys.executable, "-m", "runners.sweep", "algo=random", "chain=utility", "scenario=Broken",
                          "dry_run=true", "mlflow=false", f"results_dir={tmp_path}"], cwd=REPO, check=False,
                         capture_output=True, text=True, timeout=300,
                         env={**os.environ, "MORALITY_GYM_SCENARIOS": str(tmp_path / "scenarios")})
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    last = out.stderr.strip().splitlines()[-1]  # after the one-line warning of the skipped file
    assert last.startswith("configuration error: scenario=Broken: the file defining it") and "add 'layout:'" in last


# ---------------------------------------------------------------------------------------- policies
@pytest.mark.parametrize(("policy", "error"), [("moves_then_raises", "the policy raised ValueError: no plan for this square"),
                                             ("raises_late", "the policy raised ZeroDivisionError"),
                                             ("TABLE", "the policy table has no entry for the observation [")])
def test_eval_reports_a_policy_that_fails_mid_episode_on_one_line(policies: Path, policy: str, error: str) -> None:
    out = cli("morality_gym", "eval", "--policy", f"{policies}:{policy}", *SELECTION, "--episodes", "5", "--seed", "0")
    one_line_exit_2(out, f"policy {policies}:{policy} failed while evaluating SwitchStandard-HumanA-v1", error)


def test_submit_reports_a_policy_that_raises_mid_evaluation_and_writes_nothing(policies: Path, tmp_path: Path) -> None:
    results = tmp_path / "results"
    out = cli("leaderboard.submit", f"{policies}:raises_late", "--name", "Late", *SELECTION, "--preset", "smoke",
              "--no-gif", "--results", str(results))
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert "failed while evaluating SwitchStandard-HumanA-v1, seed 41: the policy raised ZeroDivisionError" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1 and run_files(results) == []


def test_play_reports_a_policy_that_raises_mid_episode(policies: Path) -> None:
    out = cli("morality_gym", "play", "SwitchStandard-HumanA-v1", "--policy", f"{policies}:moves_then_raises",
              "--delay", "0")
    one_line_exit_2(out, "the policy raised ValueError: no plan for this square")


@pytest.mark.parametrize("command", [["morality_gym", "eval", *SELECTION, "--episodes", "2"],
                                     ["morality_gym", "play", "SwitchStandard-HumanA-v1", "--policy", "random"]])
def test_a_negative_seed_is_a_usage_error(command: list[str]) -> None:
    one_line_exit_2(cli(*command, "--seed", "-1"), "--seed: must be an integer >= 0, got -1")


# ---------------------------------------------------------------------------------------- what is printed
def test_eval_without_a_seed_says_which_it_drew_and_that_seed_repeats_it(policies: Path) -> None:
    first = cli("morality_gym", "eval", *SELECTION, "--episodes", "20", "--json")
    assert first.returncode == 0, first.stderr
    drawn = json.loads(first.stdout)
    assert drawn["seed_drawn"] is True and isinstance(drawn["seed"], int)
    again = json.loads(cli("morality_gym", "eval", *SELECTION, "--episodes", "20", "--json", "--seed", str(drawn["seed"])).stdout)
    assert again["seed_drawn"] is False and again["mean_metric"] == drawn["mean_metric"]
    table = cli("morality_gym", "eval", *SELECTION, "--episodes", "5")
    assert "a seed drawn at random (" in table.stdout and "repeats this evaluation" in table.stdout


def test_submit_prints_the_scores_it_stored(policies: Path, tmp_path: Path) -> None:
    results = tmp_path / "results"
    argv = ["leaderboard.submit", f"{policies}:lever", "--name", "Lever", *SELECTION[:4], "--variant", "HumanA",
            "--variant", "HumanB", "--preset", "smoke", "--no-gif", "--results", str(results)]
    out = cli(*argv)
    assert out.returncode == 0, out.stderr
    assert "Utility / SwitchStandard-HumanA-v1: metric 1.0000 over 1 seed(s), exact 1.0000" in out.stdout
    assert "Utility / SwitchStandard: mean metric 1.0000 over 2 variant(s) x 1 seed(s)" in out.stdout
    again = cli(*argv)  # nothing new is written; the stored scores are shown again
    assert "0 run(s), 2 already present" in again.stdout.replace("wrote ", "")
    assert "SwitchStandard-HumanB-v1: metric 1.0000" in again.stdout


ENTRY_POINTS = ["morality_gym", "runners.sweep", "runners.table1", "runners.migrate", "runners.cache", "leaderboard.build",
                "leaderboard.submit", "leaderboard.compare", "leaderboard.engines", "leaderboard.screenshot"]


@pytest.mark.parametrize("module", ENTRY_POINTS)
def test_every_entry_point_answers_version(module: str) -> None:
    out = cli(module, "--version", timeout=120)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"python -m {module} (morality-gym "), out.stdout
    if module == "runners.sweep":
        assert "Hydra 1." in lines[0]


def test_did_you_mean_names_the_closest_choices_or_nothing() -> None:
    from morality_gym.clitools import did_you_mean

    assert did_you_mean("utilty", ["utility", "dual_process"]) == " (did you mean 'utility'?)"
    assert did_you_mean("HumanA", ["HumanAnimal", "HumanA1", "Robot"], n=3, quote=False) == " (did you mean HumanA1, HumanAnimal?)"
    assert did_you_mean("zzz", ["utility"]) == ""


def test_eval_table_explains_its_column_codes() -> None:
    """Issue 36: the eval table's norm codes (APHH, MHH, ...) are spelt out under it, in the chain's order."""
    out = subprocess.run([sys.executable, "-m", "morality_gym", "eval", "--policy", "random", "--chain", "DualProcess",
                          "--scenario", "PushOrSwitch", "--variant", "Human", "--exact"], cwd=REPO, check=False,
                         capture_output=True, text=True, timeout=300, env={**os.environ, "COLUMNS": "400"})
    assert out.returncode == 0, out.stderr
    legend = next(line for line in (out.stdout + out.stderr).splitlines() if line.startswith("columns: "))
    assert "APHH = Avoid personal human harm; MHH = Min humans harmed; APAH = " in legend
    assert "return = mean episode return" in legend and "± s.e." not in legend  # exact: no standard error
