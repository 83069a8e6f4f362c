"""A submitted policy that does not answer (issue 33): ``leaderboard.submit --timeout SECONDS``.

A policy that never answered hung ``leaderboard.submit`` forever, with no progress and no way to
bound it. Now each answer of a callable policy has a time limit (default 60 s, ``--timeout``):
past it, one line names the policy, the env and the stage and request of the evaluation, exit 2,
and nothing of the run is written. The policies below hang for real (``time.sleep``).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
POLICIES = '''
import time

calls = 0


def never(obs):
    time.sleep(3600)


def later(obs):
    """Answers 200 times (the first observation, the stationarity check), then hangs in the evaluation."""
    global calls
    calls += 1
    if calls > 200:
        while True:  # a busy loop, not a sleep: interrupted all the same
            pass
    return 1
'''


def submit(results: Path, policy: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "leaderboard.submit", policy, "--name", "Stuck", "--results", str(results),
                           "--chain", "utility", "--scenario", "switch_standard", "--variant", "HumanA", "--preset", "smoke",
                           *args], cwd=REPO, check=False, capture_output=True, text=True, timeout=600)


@pytest.fixture
def policies(tmp_path: Path) -> Path:
    path = tmp_path / "stuck.py"
    path.write_text(POLICIES)
    return path


def one_line(proc: subprocess.CompletedProcess[str]) -> str:
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, proc.stderr
    return lines[0]


@pytest.mark.parametrize(("attribute", "stage"), [("never", "SwitchStandard-HumanA-v1, first observation"),
                                                  ("later", "SwitchStandard-HumanA-v1, seed 41, Monte-Carlo evaluation")])
def test_a_policy_that_does_not_answer_is_one_line_and_writes_nothing(policies: Path, tmp_path: Path, attribute: str,
                                                                       stage: str) -> None:
    results = tmp_path / "r"
    line = one_line(submit(results, f"{policies}:{attribute}", "--timeout", "0.5"))
    assert line.startswith(f"error: policy {policies}:{attribute} did not answer within 0.5 s on {stage}"), line
    assert "--timeout SECONDS" in line
    assert not list(results.rglob("*.parquet")) and not list(results.rglob("*.gif"))


def test_the_time_limit_must_be_a_positive_number(policies: Path, tmp_path: Path) -> None:
    for value in ("0", "-1", "soon", "inf"):
        out = submit(tmp_path / "r", f"{policies}:never", "--timeout", value)
        assert out.returncode == 2 and "--timeout" in out.stderr and "Traceback" not in out.stderr, out.stderr
    assert not (tmp_path / "r").exists()


def test_a_policy_that_answers_in_time_is_evaluated_as_before(tmp_path: Path) -> None:
    rule = tmp_path / "rule.py"
    rule.write_text("def act(obs):\n    return 1\n")
    out = submit(tmp_path / "r", f"{rule}:act", "--timeout", "30", "--no-gif")
    assert out.returncode == 0, out.stderr
    assert len(list((tmp_path / "r" / "runs").glob("*.parquet"))) == 1
