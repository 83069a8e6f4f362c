"""What depends on where a module lies on disk, not on what it imports.

Grouping ``runners/`` into folders (issue 50, item 4) moved two modules one folder deeper, and two
paths computed from ``__file__`` silently pointed at files that do not exist: the fleet
checkpoints' code fingerprint hashed no file at all (so a checkpoint would resume under changed
training code), and a manifest recorded ``runners/compose/sweep.py`` as the sweep's program.
"""

from __future__ import annotations

from pathlib import Path

import morality_gym
import runners.sweep
from morality_gym.results.recording import versions
from runners.compose.command_line import PROGRAM
from runners.execute.run import code_fingerprint, training_code


def test_the_training_code_fingerprint_hashes_the_morality_gym_package(tmp_path: Path) -> None:
    package = Path(morality_gym.__file__).resolve().parent
    assert any(package.rglob("*.py"))
    assert training_code() == code_fingerprint(package, versions())
    assert training_code() != code_fingerprint(tmp_path / "no_package", versions())  # the versions alone


def test_a_manifest_names_the_file_python_m_runners_sweep_runs() -> None:
    assert Path(PROGRAM).resolve() == Path(runners.sweep.__file__).resolve()
    assert Path(PROGRAM).is_file()
