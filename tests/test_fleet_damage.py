"""Issue 46, item 2: a damaged fleet checkpoint is never trusted, and a run that goes non-finite fails alone.

* A checkpoint carries the SHA-256 of its contents: one flipped bit is found on load, and the
  file is set aside (renamed, one warning) instead of resuming with a changed weight.
* A checkpoint that reads and matches its digest but holds a NaN weight for one run, or a
  simulator state outside its tables, is set aside too, and the fleet trains from the start to
  exactly what an undamaged fleet trains.
* A run whose training goes non-finite fails alone with its own error; the five healthy runs of
  its fleet end with the very bits of an undamaged fleet's.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th

import morality_gym
from morality_gym.baselines.fleet import FleetCheckpoint, FleetRun, FleetTrainer, build_fleet
from tests.test_fleet import ROLLOUT, small_spec
from tests.test_fleet_checkpoint import KEY, Interrupted, Trainer, _checkpointed, assert_identical, final_state

LOGGER = "morality_gym.baselines.fleet.checkpoint"
SIX = [(env, chain, seed) for env in ("PushOrSwitch-Human-v1", "PushOrSwitch-Animal-v1")
       for chain, seed in (("DualProcess", 3), ("Utility", 4), ("DualProcess", 5))]
POISONED = 2


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tests/conftest.py


def _warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == LOGGER]


def _set_aside(path: Path, caplog: pytest.LogCaptureFixture, why: str) -> Trainer:
    """A fleet given the damaged ``path`` sets it aside with one warning naming ``why`` and trains
    from step 0 to what a fleet without any checkpoint trains."""
    spec = small_spec("ppo")
    fresh = Trainer(spec, "paper", 1)
    caplog.clear()  # what the test's own set-up logged
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        fresh.learn(path)
    warnings = _warnings(caplog)
    assert len(warnings) == 1 and why in warnings[0] and "set aside as fleet.pt.damaged, training from the start" in warnings[0], warnings
    assert fresh.resumed_at is None
    assert path.with_name("fleet.pt.damaged").exists()
    plain = Trainer(spec, "paper", 1)
    plain.learn()
    assert_identical(final_state(plain), final_state(fresh))
    return fresh


def _write_state(path: Path, state: dict[str, Any], monkeypatch: pytest.MonkeyPatch) -> None:
    """Write ``state`` as a checkpoint through FleetCheckpoint itself (so its digest is right)."""
    fleet = Trainer(small_spec("ppo"), "paper", 1).fleet
    fleet.num_timesteps = int(state["num_timesteps"])
    monkeypatch.setattr(fleet, "state_dict", lambda: state)
    path.unlink()
    FleetCheckpoint(path, every_s=0.0, key=KEY, extra=lambda: {"rows": []}).write(fleet)


def _saved_state(path: Path) -> dict[str, Any]:
    """The fleet state of a checkpoint of update 1, read back from a fleet restored from it."""
    fleet = Trainer(small_spec("ppo"), "paper", 1).fleet
    fleet.total_timesteps = 5 * ROLLOUT
    fleet._start_evaluations(700, 2, None)
    fleet._start_training()
    assert FleetCheckpoint(path, every_s=0.0, key=KEY, on_resume=lambda steps, extra: None).restore(fleet)
    return fleet.state_dict()


@pytest.mark.slow
def test_one_flipped_bit_in_a_weight_is_found_and_the_file_set_aside(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    _, path = _checkpointed(tmp_path)
    data = bytearray(path.read_bytes())
    data[len(data) * 2 // 3] ^= 0x01  # inside the stored tensors: torch.load alone reads this without complaint
    path.write_bytes(bytes(data))
    _set_aside(path, caplog, "SHA-256")


@pytest.mark.slow
def test_a_checkpoint_with_a_nan_weight_for_one_run_is_set_aside(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    _, path = _checkpointed(tmp_path)
    state = _saved_state(path)
    state["nets"]["pi"][0][1, 0, 0] = float("nan")
    _write_state(path, state, monkeypatch)
    _set_aside(path, caplog, "holds a non-finite value (nets.pi[0])")


@pytest.mark.slow
def test_a_checkpoint_with_a_simulator_state_out_of_range_is_set_aside(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    _, path = _checkpointed(tmp_path)
    state = _saved_state(path)
    state["env"]["sim"]["state"][3] = 10**6
    _write_state(path, state, monkeypatch)
    _set_aside(path, caplog, "simulator state: copy 3 holds 1000000, outside")


def _six(spec: Any) -> FleetTrainer:
    return build_fleet(spec, [FleetRun(morality_gym.bind_chain(chain, env), seed) for env, chain, seed in SIX], "paper")


def _poison_after(fleet: FleetTrainer, update: int, run: int) -> None:
    """Make ``run``'s policy weights NaN at the end of update ``update`` (a learning rate gone wrong, say)."""
    train = fleet._train
    count = [0]

    def poisoned() -> None:
        train()
        count[0] += 1
        if count[0] == update:
            with th.no_grad():
                fleet.nets.params("pi")[0][run, 0, 0] = float("nan")

    fleet._train = poisoned  # type: ignore[method-assign]


def _run_state(fleet: FleetTrainer, k: int) -> dict[str, Any]:
    """Everything of run ``k``: its slices of the networks and optimisers, its generators and its learner."""
    state = fleet.state_dict()
    policy = fleet.learners()[k].model.policy
    return {
        "nets": {h: [t[k] for t in ts] for h, ts in state["nets"].items()},
        "optimisers": {n: {b: v[k] for b, v in o.items()} for n, o in state["optimisers"].items()},
        "extra": {n: v[k] for n, v in state["extra"].items()},
        "torch": state["torch_generators"][k], "numpy": state["np_generators"][k],
        "costs": state["ep_cost_buffers"][k], "updates": state["update_logs"][k], "evals": state["learn_evals"][k],
        "exported": [p.detach().clone() for p in policy.parameters()],
    }


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ppo_lag", "cpo"])
def test_a_run_that_goes_non_finite_fails_alone_and_the_five_others_train_to_the_same_bits(name: str) -> None:
    spec = small_spec(name)
    rows: dict[str, list[tuple[int, dict[str, Any]]]] = {"healthy": [], "poisoned": []}
    healthy = _six(spec)
    healthy.learn(4 * ROLLOUT, eval_every=700, eval_episodes=2, on_eval=lambda k, r: rows["healthy"].append((k, r)))
    poisoned = _six(spec)
    _poison_after(poisoned, 2, POISONED)
    poisoned.learn(4 * ROLLOUT, eval_every=700, eval_episodes=2, on_eval=lambda k, r: rows["poisoned"].append((k, r)))
    assert healthy.failed == {}
    assert list(poisoned.failed) == [POISONED]
    assert "non-finite" in poisoned.failed[POISONED] and "step 1,024" in poisoned.failed[POISONED]
    assert "seed 5" in poisoned.failed[POISONED]
    for k in range(len(SIX)):
        if k != POISONED:
            assert_identical(_run_state(healthy, k), _run_state(poisoned, k), f"run {k}")
    assert_identical([(k, r) for k, r in rows["healthy"] if k != POISONED],
                     [(k, r) for k, r in rows["poisoned"] if k != POISONED], "evaluation rows")
    # the failed run is no longer evaluated, and nothing non-finite is left to checkpoint
    assert max(r["step"] for k, r in rows["poisoned"] if k == POISONED) < 2 * ROLLOUT
    state = poisoned.state_dict()
    assert all(bool(th.isfinite(t).all()) for ts in state["nets"].values() for t in ts)


@pytest.mark.slow
def test_a_fleet_with_a_failed_run_checkpoints_and_resumes_it_as_failed(tmp_path: Path) -> None:
    spec = small_spec("ppo")
    path = tmp_path / "fleet.pt"
    first = _six(spec)
    _poison_after(first, 1, POISONED)

    def stop(steps: int, total: int) -> None:
        if steps >= 2 * ROLLOUT:
            raise Interrupted

    with pytest.raises(Interrupted):
        first.learn(3 * ROLLOUT, on_progress=stop, checkpoint=FleetCheckpoint(path, every_s=0.0, key=KEY))
    resumed = _six(spec)
    resumed.learn(3 * ROLLOUT, checkpoint=FleetCheckpoint(path, every_s=0.0, key=KEY))
    assert list(resumed.failed) == [POISONED] and not path.with_name("fleet.pt.damaged").exists()
    whole = _six(spec)
    _poison_after(whole, 1, POISONED)
    whole.learn(3 * ROLLOUT)
    for k in range(len(SIX)):
        assert_identical(_run_state(whole, k), _run_state(resumed, k), f"run {k}")


def test_a_checkpoint_file_has_a_digest_line_and_no_pickle_of_objects(tmp_path: Path) -> None:
    fleet = Trainer(small_spec("ppo"), "paper", 1).fleet
    fleet.learn(ROLLOUT, checkpoint=FleetCheckpoint(tmp_path / "fleet.pt", every_s=0.0, key=KEY))
    head = (tmp_path / "fleet.pt").read_bytes()[:200].split(b"\n")
    assert head[0] == b"MoralityGym fleet checkpoint" and len(head[1]) == 64
    assert np.all([c in b"0123456789abcdef" for c in head[1]])


@pytest.mark.slow
def test_the_sweep_records_the_non_finite_run_failed_with_its_own_error_and_the_others_ok(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Through runners.execute.jobs: the poisoned run's row is failed with its own error, the other runs'
    rows are the very rows an undamaged fleet job records (timing aside)."""
    from morality_gym.results.schema import read_runs
    from runners.execute.jobs import execute_job
    from runners.plan.fleets import make_jobs
    from runners.plan.runs import expand_sweep
    from tests.test_fleet_checkpoint import SWEEP, TIMING, _sweep_config

    runs = expand_sweep(_sweep_config(tmp_path, *SWEEP))
    (job,) = make_jobs(runs, "fleet", 36, 1)
    healthy = list(execute_job(job.items, tmp_path / "healthy", gif=False, engine="fleet"))
    assert [s["status"] for s in healthy] == ["ok"] * 3
    check = FleetTrainer._fail_non_finite_runs  # called after every update (_train is the subclasses')
    calls = [0]

    def poisoned(self: FleetTrainer) -> None:
        calls[0] += 1
        if calls[0] == 1:  # the first update left run 1 with an infinite weight
            with th.no_grad():
                self.nets.params("pi")[0][1, 0, 0] = float("inf")
        check(self)

    monkeypatch.setattr(FleetTrainer, "_fail_non_finite_runs", poisoned)
    summaries = list(execute_job(job.items, tmp_path / "poisoned", gif=False, engine="fleet"))
    assert [s["status"] for s in summaries] == ["ok", "failed", "ok"]
    rows = read_runs(tmp_path / "poisoned").set_index("run_id")
    assert "training went non-finite" in rows.loc[summaries[1]["run_id"], "error"]
    assert "the other runs of its fleet trained on" in rows.loc[summaries[1]["run_id"], "error"]
    ok = [s["run_id"] for s in summaries if s["status"] == "ok"]
    expected = read_runs(tmp_path / "healthy").set_index("run_id").loc[ok].drop(columns=TIMING)
    import pandas as pd

    pd.testing.assert_frame_equal(rows.loc[ok].drop(columns=TIMING), expected, check_exact=True)
