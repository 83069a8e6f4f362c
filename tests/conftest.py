"""Shared test fixtures: where the reference's shared material lives, and common env helpers."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MORALITY_GYM_SHARED", REPO.parent / "shared"))


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` (the spec and conformance traces); tests that need it skip when it is absent."""
    if not (SHARED / "conformance" / "INDEX.json").is_file():
        pytest.skip(f"reference material not found at {SHARED} (set MORALITY_GYM_SHARED); a user's clone has none")
    return SHARED


from tests.slurm_cluster import slurm_cluster  # noqa: E402,F401 - session fixture for the SLURM tests
