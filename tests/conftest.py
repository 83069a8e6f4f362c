"""Shared test fixtures: where the reference's shared material lives, and common env helpers."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
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


@pytest.fixture()
def isolated_scenarios() -> Iterator[None]:
    """Scenarios a test registers in this process (``add_scenario_dir``, ``load_split``) are forgotten
    after it: the registry is the process's, and the tests that count the 98 built-in envs run
    later in the same process (:func:`scenario_registry_restored`)."""
    with scenario_registry_restored():
        yield


@contextlib.contextmanager
def scenario_registry_restored() -> Iterator[None]:
    """Restores, on leaving, the scenario table, the user directories, the cached state graphs and
    Gymnasium's MoralityGym ids as they were on entering (for module-scoped fixtures too)."""
    import gymnasium as gym

    from morality_gym.envs import registry

    registry.scenarios()  # loaded before the snapshot, so the snapshot is the whole table
    scenarios, dirs, graphs = dict(registry._scenarios), list(registry._extra_dirs), dict(registry._graphs)
    gym_ids = {k for k in gym.envs.registry if k.startswith("MoralityGym/")}
    # loading a folder also lists it for child processes (sweeps, builds): forget that too
    listed = os.environ.get(registry.SCENARIOS_ENV)
    yield
    if listed is None:
        os.environ.pop(registry.SCENARIOS_ENV, None)
    else:
        os.environ[registry.SCENARIOS_ENV] = listed
    with registry._lock:
        registry._scenarios.clear()
        registry._scenarios.update(scenarios)
        registry._extra_dirs[:] = dirs
    with registry._graphs_lock:
        registry._graphs.clear()
        registry._graphs.update(graphs)
    for key in [k for k in gym.envs.registry if k.startswith("MoralityGym/") and k not in gym_ids]:
        del gym.envs.registry[key]


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook, which reads the marks into node ids
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Groups for pytest-xdist (``make test`` runs ``-n 2 --dist loadgroup``).

    Why groups: a module's tests stay on one worker, so its module fixtures (a trained fleet, a
    built board) are made once, not once per worker; and every SLURM test goes to one worker,
    because the cluster is the machine's, not the process's (two workers would start and stop the
    same daemons under each other)."""
    for item in items:
        group = "slurm" if item.get_closest_marker("slurm") else item.nodeid.split("::", 1)[0]
        item.add_marker(pytest.mark.xdist_group(group))
