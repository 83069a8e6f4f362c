"""Issue 46, item 8: the leftovers and small ones of the fault trial, one test each.

* ``release create`` builds its tables inside the release's own temporary folder (removed by the
  next ``create`` after a ``kill -9``), not in a ``/tmp/release-build-*`` nothing removed;
* action tensors of shape (2, 2) for 4 copies are refused, not flattened;
* a non-ASCII ``results_dir`` gets a hint to quote it, not Hydra's lexer error alone;
* the failed-run list prints ``[nan, ...]`` as it is (rich markup ate it);
* an LLM run whose every answer fell back says so on the command line;
* ``generate --count 100000000`` is refused up front with the size it would take.
"""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import torch as th
from rich.console import Console

from morality_gym.envs.trolley import InvalidActionError
from tests.leaderboard_data import REPO


def test_release_tables_are_built_inside_the_releases_own_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from leaderboard import release

    seen: list[Path] = []

    def build(cmd: list[str], **_: Any) -> subprocess.CompletedProcess[str]:
        where = Path(cmd[cmd.index("--out") + 1])
        seen.append(where)
        for name in release.TABLES:
            (where / name).write_text("table")
        return subprocess.CompletedProcess(cmd, 0, "", "")

    monkeypatch.setattr(release.subprocess, "run", build)
    out = tmp_path / ".paper-v1.create-abc"
    out.mkdir()
    release.write_tables(tmp_path / "results", out)
    assert len(seen) == 1 and seen[0].parent == out  # removed with the release's folder after a kill
    assert sorted(p.name for p in out.iterdir()) == sorted(release.TABLES)  # and removed by itself otherwise


def test_actions_of_the_wrong_shape_are_refused_not_flattened() -> None:
    from morality_gym.envs.torch_vector import TorchTrolleyVectorEnv
    from morality_gym.envs.vector import TrolleyVecEnv, TrolleyVectorEnv

    torch_env = TorchTrolleyVectorEnv("SwitchStandard-HumanA-v1", 4)
    torch_env.reset(seed=0)
    with pytest.raises(InvalidActionError, match=r"expected 4 actions \(one per copy\), got shape \(2, 2\)"):
        torch_env.step(th.zeros((2, 2), dtype=th.int64))
    torch_env.step(th.zeros((4, 1), dtype=th.int64))  # a policy's (n, 1) sample is still taken
    gym_env = TrolleyVectorEnv("SwitchStandard-HumanA-v1", 4)
    gym_env.reset(seed=0)
    with pytest.raises(ValueError, match=r"expected 4 actions, got an array of shape \(2, 2\)"):
        gym_env.step(np.zeros((2, 2), dtype=np.int64))
    sb3_env = TrolleyVecEnv("SwitchStandard-HumanA-v1", 4)
    sb3_env.reset()
    with pytest.raises(ValueError, match=r"shape \(2, 2\)"):
        sb3_env.step(np.zeros((2, 2), dtype=np.int64))
    sb3_env.step(np.zeros((4, 1), dtype=np.int64))


def test_a_non_ascii_results_dir_gets_a_hint_to_quote_it() -> None:
    from runners.compose.command_line import compose_sweep
    from runners.compose.sweep_config import ConfigError

    with pytest.raises(ConfigError, match=r"results_dir: the value '/tmp/résultats' .* quote it .*\"results_dir='/tmp/résultats'\""):
        compose_sweep(["results_dir=/tmp/résultats"], "config")


def test_the_failed_run_list_keeps_brackets(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from runners import sweep

    error = "ValueError: expected probabilities, got [nan, 0.5, nan] [bold]x[/bold]"
    monkeypatch.setattr(sweep, "finished_status", lambda results, run_id: "failed")
    monkeypatch.setattr(sweep, "read_table_or_quarantine",
                        lambda results, path, columns: SimpleNamespace(column=lambda name: [SimpleNamespace(as_py=lambda: error)]))
    run = SimpleNamespace(run_id="abc", config=SimpleNamespace(algo=SimpleNamespace(label="PPO"), env_id="E", chain={"name": "C"}, seed=1))
    out = io.StringIO()
    console = Console(file=out, width=300, color_system=None)
    assert sweep.report(SimpleNamespace(runs=[run]), SimpleNamespace(results_dir=tmp_path), console, 1.0) == 1  # type: ignore[arg-type]
    assert "abc PPO E C seed 1: " + error in out.getvalue()


def test_an_llm_run_whose_every_answer_fell_back_says_so(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    from leaderboard import llm

    fell_back = SimpleNamespace(record={"length": 7, "fallbacks": 7})
    answered = SimpleNamespace(record={"length": 7, "fallbacks": 2})
    assert llm.fallback_only(fell_back) and not llm.fallback_only(answered)  # type: ignore[arg-type]
    monkeypatch.setattr(llm, "import_logs", lambda *a, **k: {"written": 3, "present": 0, "episodes": 3, "fallback_only": 3})
    args = llm.parse_args(["import", str(tmp_path / "x.eval"), "--name", "Mine", "--results", str(tmp_path / "r")])
    assert llm.run(args) == 0
    err = capsys.readouterr().err
    assert "warning: in every episode(s) no answer of the model was used" in err and "--fallback" in err
    monkeypatch.setattr(llm, "import_logs", lambda *a, **k: {"written": 3, "present": 0, "episodes": 3, "fallback_only": 0})
    llm.run(args)
    assert "warning" not in capsys.readouterr().err


def test_generate_refuses_a_count_that_cannot_fit_before_writing(tmp_path: Path) -> None:
    out = tmp_path / "gen"
    proc = subprocess.run([sys.executable, "-m", "morality_gym", "generate", "--count", "100000000", "--out", str(out)],
                          cwd=REPO, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--count 100,000,000: the dilemmas would take about 2.4 TB" in lines[0], proc.stderr
    assert not [p for p in out.iterdir()]
