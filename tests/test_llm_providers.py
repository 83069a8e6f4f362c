"""``leaderboard.llm run`` with a provider that cannot run here, and the bound on model calls (issue 33).

The ``llm`` extra installs Inspect, not the providers' SDKs: ``--model openai/...`` without the
``openai`` package printed Inspect's 4-line message and exited 1. Now: one line naming the package
to install, exit 2, nothing written. Each case runs only where the package is indeed missing.
Inspect bounds no model call by default; ``run --timeout`` is passed on as Inspect's ``timeout``
and ``attempt_timeout``.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def llm(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "leaderboard.llm", *args], cwd=REPO, check=False, capture_output=True,
                          text=True, timeout=600)


def one_line(out: subprocess.CompletedProcess[str]) -> str:
    assert out.returncode == 2, out.stdout + out.stderr
    assert "Traceback" not in out.stderr, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    return lines[0]


@pytest.mark.parametrize(("model", "package"), [("openai/gpt-4o-mini", "openai"), ("anthropic/claude-3-5-haiku-latest", "anthropic")])
def test_a_missing_provider_package_is_one_line_naming_it(tmp_path: Path, model: str, package: str) -> None:
    if importlib.util.find_spec(package) is not None:
        pytest.skip(f"{package} is installed here: its absence cannot be shown")
    out = llm("run", "--model", model, "--name", "Hosted", "--env", "SwitchStandard-HumanA-v1", "--episodes", "1",
              "--results", str(tmp_path / "r"), "--log-dir", str(tmp_path / "logs"))
    assert one_line(out) == f"error: --model {model}: the provider needs a package that is not installed: pip install {package}"
    assert not (tmp_path / "r").exists() and not (tmp_path / "logs").exists()


def test_an_unknown_provider_is_one_line(tmp_path: Path) -> None:
    out = llm("run", "--model", "nosuch/model", "--name", "Hosted", "--results", str(tmp_path / "r"),
              "--log-dir", str(tmp_path / "logs"))
    line = one_line(out)
    assert line.startswith("error: --model nosuch/model: ") and "not recognized" in line and "openai/gpt-4o-mini" in line


def test_the_model_call_bound_is_passed_to_inspect_and_checked(tmp_path: Path) -> None:
    for value in ("0", "-3", "never"):
        out = llm("run", "--model", "mockllm/model", "--script", "examples/llm/lever_once.txt", "--name", "Mock",
                  "--timeout", value, "--results", str(tmp_path / "r"))
        assert out.returncode == 2 and "--timeout" in out.stderr, out.stderr
    out = llm("run", "--model", "mockllm/model", "--script", "examples/llm/lever_once.txt", "--name", "Mock", "--timeout", "30",
              "--env", "SwitchStandard-HumanA-v1", "--episodes", "1", "--results", str(tmp_path / "r"),
              "--log-dir", str(tmp_path / "logs"), "--display", "none")
    assert out.returncode == 0, out.stderr
    from inspect_ai.log import read_eval_log

    [log] = sorted((tmp_path / "logs").glob("*.eval"))
    config = read_eval_log(str(log)).plan.config
    assert (config.timeout, config.attempt_timeout) == (30, 30)
