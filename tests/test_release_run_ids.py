"""The shipped releases' runs keep their ids when the configuration is resolved once (issue 34).

Each ``releases/<name>/runs.parquet`` records each run's id and its resolved configuration.
A run is found on disk by its id, so the one resolved run configuration
(:class:`morality_gym.results.run_config.RunConfig`) must give every recorded run its recorded id: read back
from its record, and built afresh by resolving the Table 1 sweep through the layers of
:func:`runners.compose.sweep_config.learner_layers` (algo file < protocol < preset < command line).
"""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from morality_gym.results.identity import SUBMITTED_ALGO, run_identity
from morality_gym.results.run_config import RunConfig
from runners.compose.search_path import CONF_DIR
from runners.compose.sweep_config import validate
from runners.plan.runs import expand_sweep

#: Every release shipped in the repository: a new one is checked without editing this test.
RELEASES = sorted((Path(__file__).resolve().parents[1] / "releases").glob("*/runs.parquet"))


def _runs(submitted: bool) -> list[tuple[str, str, dict]]:
    """(run id, protocol, recorded config) of the shipped releases' sweep runs, or of their submitted ones."""
    assert RELEASES, "no release is shipped in releases/"
    out = []
    for path in RELEASES:
        table = pq.read_table(path, columns=["run_id", "protocol", "algo", "config"])
        out += [(run_id, protocol, json.loads(config)) for run_id, protocol, algo, config in
                zip(table.column("run_id").to_pylist(), table.column("protocol").to_pylist(),
                    table.column("algo").to_pylist(), table.column("config").to_pylist())
                if (algo == SUBMITTED_ALGO) == submitted]
    return out


@pytest.fixture(scope="module")
def release() -> list[tuple[str, str, dict]]:
    """The sweep runs of every shipped release (a submitted entry's runs, e.g. a language model's
    column, were planned by no sweep: :func:`test_a_submitted_run_keeps_the_id_of_its_config`)."""
    return _runs(submitted=False)


def test_a_submitted_run_keeps_the_id_of_its_config() -> None:
    """A submitted run's id is its recorded config's, provenance left out (leaderboard.llm, leaderboard.submit)."""
    for run_id, _, config in _runs(submitted=True):
        assert run_identity(config) == run_id


def test_a_recorded_config_reads_back_with_its_run_id(release: list[tuple[str, str, dict]]) -> None:
    assert len(release) > 2000
    for run_id, _, config in release:
        run = RunConfig.from_json(config)
        assert run.run_id == run_id
        assert run.to_json() == config


@pytest.mark.parametrize("protocol", ["paper", "corrected"])
def test_resolving_table1_gives_the_release_its_run_ids(release: list[tuple[str, str, dict]], protocol: str) -> None:
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=["experiment=table1", "preset=paper", f"protocol={protocol}", "mlflow=false"],
                      return_hydra_config=True)
    planned = {r.run_id: r.config for r in expand_sweep(validate(cfg))}
    recorded = {run_id: config for run_id, p, config in release if p == protocol}
    assert recorded, f"the release has no {protocol} runs"
    missing = sorted(set(recorded) - set(planned))
    assert not missing, f"{len(missing)} {protocol} runs of the release get another id now, e.g. {missing[:3]}"
    for run_id, config in recorded.items():
        assert planned[run_id].to_json() == config
