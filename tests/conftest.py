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


@pytest.fixture(scope="module")
def one_torch_thread():
    """Small networks: one torch thread is fastest and keeps runs reproducible on a 2-core machine.

    Modules that train use it with ``pytestmark = pytest.mark.usefixtures("one_torch_thread")``.
    """
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


from tests.slurm_cluster import slurm_cluster  # noqa: F401 - session fixture for the SLURM tests
