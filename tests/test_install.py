"""``pip install .`` (not editable) gives a package that works from any directory.

The wheel is built from a copy of this checkout (so that the build never writes ``build/`` into
the repository, nor picks up a stale one) and installed, without dependencies, into a fresh
virtual environment created ``--without-pip``. The machine has no internet, and reinstalling
torch, SB3, MLflow, ... would take minutes, so the fresh environment borrows the dependencies
from this test's own environment through a ``.pth`` line naming its site-packages. Python does
not process ``.pth`` files found in a directory that a ``.pth`` line adds, so this environment's
editable install of MoralityGym stays out: the test checks that ``morality_gym``, ``runners``
and ``leaderboard`` are imported from the fresh environment, i.e. from the wheel alone.

Then, from a directory outside the repository, as a user would: the CLI (``python -m
morality_gym`` and the ``morality-gym`` script), a smoke sweep (which needs the Hydra
configuration and the scenario files as package data), an unknown algo (the error must list the
installed algos), and the leaderboard (which needs the paper's Table 1 data), which must write
its site next to the results, not into the installed package.
"""

from __future__ import annotations

import os
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: Not copied for the build: environments, VCS data, outputs and build leftovers.
_SKIP_TOP = {".venv", ".git", ".make", "results", "build", "dist", "outputs", "multirun", "mlruns"}
_SKIP_ANY = ("__pycache__", "*.egg-info", ".pytest_cache", ".ruff_cache")

pytestmark = pytest.mark.slow


def _source_copy(dest: Path) -> Path:
    def ignore(directory: str, names: list[str]) -> set[str]:
        skipped = set(shutil.ignore_patterns(*_SKIP_ANY)(directory, names))
        if Path(directory) == REPO:
            skipped |= _SKIP_TOP & set(names)
        if Path(directory) == REPO / "leaderboard":
            skipped |= {"site"} & set(names)  # a built site, not source
        return skipped

    shutil.copytree(REPO, dest, symlinks=True, ignore=ignore)
    return dest


def _run(cmd: list[str], cwd: Path, env: dict[str, str], timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout, check=False)


def _ok(out: subprocess.CompletedProcess[str], what: str) -> str:
    assert out.returncode == 0, f"{what} failed (exit {out.returncode}):\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}"
    return out.stdout + out.stderr


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str], Path]:
    """(python of a fresh venv holding only the wheel, its environment, a working directory outside the repo)."""
    tmp = tmp_path_factory.mktemp("install")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env["MORALITY_GYM_SCENARIOS"] = ""
    src = _source_copy(tmp / "src")
    wheels = tmp / "wheels"
    _ok(_run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "--no-build-isolation", "--no-index",
              "-q", "-w", str(wheels)], tmp, env), "pip wheel .")
    (wheel,) = wheels.glob("morality_gym-*.whl")

    venv = tmp / "venv"
    _ok(_run([sys.executable, "-m", "venv", "--without-pip", str(venv)], tmp, env), "python -m venv")
    python = venv / "bin" / "python"
    purelib = Path(_ok(_run([str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], tmp, env),
                       "sysconfig").strip())
    (purelib / "_morality_gym_test_dependencies.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    _ok(_run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index", "-q",
              str(wheel)], tmp, env), "pip install the wheel")

    work = tmp / "work"  # outside the repository: nothing can be found relative to a checkout
    work.mkdir()
    code = "import morality_gym, runners, leaderboard; print(morality_gym.__file__, runners.__file__, leaderboard.__file__)"
    where = _ok(_run([str(python), "-c", code], work, env), "import")
    for path in where.split():
        assert Path(path).is_relative_to(purelib), f"{path} is not the installed wheel's (expected under {purelib})"
    return python, env, work


def test_the_wheel_ships_every_file_read_at_run_time(installed: tuple[Path, dict[str, str], Path]) -> None:
    python, env, work = installed
    code = ("from runners.compose.search_path import CONF_DIR; from morality_gym.paper import TABLE1_FILE;"
            "from morality_gym.envs.registry import BUILTIN_DIR; from morality_gym.norms.chain import BUILTIN_DIR as C;"
            "[print(p) for p in (CONF_DIR, TABLE1_FILE, BUILTIN_DIR, C)]")
    out = _ok(_run([str(python), "-c", code], work, env), "paths")
    conf, table1, scenarios, chains = (Path(p) for p in out.split())
    for path in (conf, table1, scenarios, chains):
        assert not path.resolve().is_relative_to(REPO), f"{path} points into the checkout"
    assert table1.is_file()
    assert {p.relative_to(conf).as_posix() for p in conf.rglob("*.yaml")} == {
        p.relative_to(REPO / "conf").as_posix() for p in (REPO / "conf").rglob("*.yaml")}
    assert {p.name for p in scenarios.glob("*.yaml")} == {p.name for p in (REPO / "morality_gym/data/scenarios").glob("*.yaml")}
    assert {p.name for p in chains.glob("*.yaml")} == {p.name for p in (REPO / "morality_gym/data/chains").glob("*.yaml")}


def test_cli_from_outside_the_repository(installed: tuple[Path, dict[str, str], Path]) -> None:
    python, env, work = installed
    out = _ok(_run([str(python), "-m", "morality_gym", "list"], work, env), "morality_gym list")
    assert "SwitchStandard-HumanA-v1" in out and len(out.split()) == 98
    script = python.parent / "morality-gym"
    out = _ok(_run([str(script), "list", "scenarios"], work, env), "morality-gym list scenarios")
    assert "PushOrSwitch" in out
    out = _ok(_run([str(python), "-m", "morality_gym", "eval", "--scenario", "SwitchStandard", "--variant", "HumanA",
                    "--chain", "Utility", "--policy", "random", "--episodes", "2", "--json"], work, env), "morality_gym eval")
    assert "SwitchStandard-HumanA-v1" in out


def test_sweep_and_leaderboard_from_outside_the_repository(installed: tuple[Path, dict[str, str], Path]) -> None:
    python, env, work = installed
    out = _run([str(python), "-m", "runners.sweep", "algo=not_an_algo", "chain=utility", "results_dir=r"], work, env)
    assert out.returncode == 2 and "not_an_algo" in out.stderr, out.stderr
    for algo in ("cpo", "ppo_lag", "ppo_shaped", "random"):  # the installed algos are listed
        assert algo in out.stderr, out.stderr

    results = work / "results"
    _ok(_run([str(python), "-m", "runners.sweep", "algo=random", "chain=utility", "scenario=[switch_standard]",
              "preset=smoke", "mlflow=false", "gif=false", f"results_dir={results}"], work, env), "smoke sweep")
    assert len([p for p in (results / "runs").glob("*.parquet") if ".learn." not in p.name]) == 12  # 12 variants, seed 41
    assert not (work / "outputs").exists(), "Hydra wrote an outputs/ directory into the working directory"

    out = _ok(_run([str(python), "-m", "leaderboard.build", "--results", str(results)], work, env), "leaderboard.build")
    assert (results / "site" / "index.html").is_file(), out
    table = (results / "table1.md").read_text()
    assert "| Utility | SwitchStandard |" in table and "paper 0.297" in table  # the paper's Random, from package data
    site_packages = Path(_ok(_run([str(python), "-c", "import leaderboard; print(leaderboard.__file__)"], work, env),
                             "import").strip()).parent
    assert not (site_packages / "site").exists(), "the leaderboard wrote into the installed package"


def test_inspect_finds_the_installed_tasks_by_their_entry_point(installed: tuple[Path, dict[str, str], Path]) -> None:
    """``inspect eval morality_gym/utility`` works from anywhere once the package is installed (the
    ``inspect_ai`` entry point), here with Inspect's mock model answering STAY."""
    pytest.importorskip("inspect_ai", reason="the llm extra (make test installs it)")
    python, env, work = installed
    code = """
from inspect_ai import eval as inspect_eval
from inspect_ai.model import ModelOutput, ModelUsage, get_model
import morality_gym.llm.inspect_tasks as tasks

def answer(messages, tools, tool_choice, config):
    out = ModelOutput.from_content(model="mockllm/model", content="ACTION: STAY")
    out.usage = ModelUsage(input_tokens=1, output_tokens=1, total_tokens=2)
    return out

[log] = inspect_eval("morality_gym/utility", task_args={"env": "SwitchStandard-HumanA-v1", "episodes": 2},
                     model=get_model("mockllm/model", custom_outputs=answer), log_dir="logs", display="none")
print(tasks.__file__, log.status, len(log.samples))
"""
    out = _ok(_run([str(python), "-c", code], work, env), "inspect eval morality_gym/utility")
    path, status, samples = out.split()[-3:]
    assert not Path(path).resolve().is_relative_to(REPO) and (status, samples) == ("success", "2")
