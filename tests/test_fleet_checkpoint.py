"""Fleet checkpoints: a fleet interrupted and resumed from its checkpoint ends bit for bit where
the uninterrupted fleet ends, and a checkpoint that does not fit is never used.

* Per learner and protocol: a fleet of two runs (different variants and chains) trains five
  updates with learn-time evaluations; another is interrupted after its third update's progress
  report (its checkpoint holds update 2), and a freshly built fleet resumes from the file. Their
  final training states (networks, every optimiser's moments and step counts, multipliers,
  generators, simulator, cost memory, diagnostics, evaluation rows and seed counters) are equal
  with ``torch.equal`` / ``==``. The global RNGs are set differently before each, which shows that
  training does not depend on them.
* The comparison can fail: a resume that skips the numpy generators does not match.
* A checkpoint of another key or fleet is discarded with a warning, a damaged file set aside
  (tests/test_fleet_damage.py has the rest), and training starts over.
* The sweep around it (runners.execute.jobs) is tested in tests/test_fleet_sweep.py's style at the end.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th

import morality_gym
from morality_gym.baselines.fleet import FleetCheckpoint, FleetRun, FleetTrainer, build_fleet
from morality_gym.baselines.fleet import state as fleet_state
from morality_gym.baselines.fleet import streams as fleet_streams
from morality_gym.baselines.specs import LearnerSpec
from tests.test_fleet import ROLLOUT, small_spec  # the fleet tests' small learners

UPDATES = 5
EVAL_EVERY = 700  # evaluations at steps 0, 704, 1400, 2104: before and after the interruption
RUNS = [("PushOrSwitch-Human-v1", "DualProcess", 3), ("PushOrSwitch-Animal-v1", "Utility", 4)]
KEY = {"runs": ["a", "b"], "commit": "abc"}
CASES = [("ppo", "paper"), ("ppo_shaped", "paper"), ("ppo_lag", "paper"), ("ppo_lag", "corrected"), ("cpo", "paper"),
         ("cpo", "corrected")]


class Interrupted(Exception):
    """Stands for the kill of a worker."""


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tests/conftest.py


def make_fleet(spec: LearnerSpec, protocol: str) -> FleetTrainer:
    return build_fleet(spec, [FleetRun(morality_gym.bind_chain(chain, env), seed) for env, chain, seed in RUNS], protocol)


class Trainer:
    """One fleet's training as a caller drives it: its evaluation rows (kept in the checkpoint as
    the caller's extra data, as runners.execute.jobs keeps them) and an optional interruption."""

    def __init__(self, spec: LearnerSpec, protocol: str, global_seed: int) -> None:
        th.manual_seed(global_seed)  # training must not depend on the global RNGs
        np.random.seed(global_seed)
        self.fleet = make_fleet(spec, protocol)
        self.rows: list[tuple[int, dict[str, Any]]] = []
        self.resumed_at: int | None = None

    def learn(self, path: Path | None = None, stop_at: int | None = None, key: dict[str, Any] = KEY) -> FleetTrainer:
        def progress(steps: int, total: int) -> None:
            if stop_at is not None and steps >= stop_at:
                raise Interrupted

        def resume(steps: int, extra: Any) -> None:
            self.resumed_at = steps
            self.rows[:] = [(k, row) for k, row in extra["rows"]]

        checkpoint = None if path is None else FleetCheckpoint(path, every_s=0.0, key=key,
                                                               extra=lambda: {"rows": self.rows}, on_resume=resume)
        self.fleet.learn(UPDATES * ROLLOUT, eval_every=EVAL_EVERY, eval_episodes=2,
                         on_eval=lambda k, row: self.rows.append((k, row)), on_progress=progress, checkpoint=checkpoint)
        return self.fleet


def assert_identical(a: Any, b: Any, where: str = "state") -> None:
    """``a`` and ``b`` equal bit for bit (tensors with ``torch.equal``; NaN equals NaN), except
    wall-clock readings (``wall_time_s``, ``elapsed_s``)."""
    if isinstance(a, th.Tensor):
        assert isinstance(b, th.Tensor) and a.dtype == b.dtype and th.equal(a, b), where
    elif isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), (where, a.keys(), getattr(b, "keys", lambda: b)())
        for key in a:
            if key not in ("wall_time_s", "elapsed_s"):
                assert_identical(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), (where, len(a), len(b))
        for i, (x, y) in enumerate(zip(a, b)):
            assert_identical(x, y, f"{where}[{i}]")
    elif isinstance(a, float) and math.isnan(a):
        assert isinstance(b, float) and math.isnan(b), where
    else:
        assert a == b and type(a) is type(b), (where, a, b)


def final_state(trainer: Trainer) -> dict[str, Any]:
    """Everything that must match: the training state, the exported single-run learners and the rows."""
    fleet = trainer.fleet
    exported = []
    for learner in fleet.learners():
        policy = learner.model.policy
        optimisers = [getattr(policy, name) for name in ("optimizer", "critic_optimizer") if hasattr(policy, name)]
        exported.append({
            "params": [p.detach().clone() for p in policy.parameters()],
            "adam": [{k: v for k, v in opt.state[p].items()} for opt in optimisers for p in policy.parameters() if p in opt.state],
            "updates": fleet_state.plain_data(learner.update_diagnostics()),
            "steps": learner.trained_steps,
        })
    return {"fleet": fleet.state_dict(), "exported": exported, "rows": fleet_state.plain_data(trainer.rows)}


def interrupted_and_resumed(spec: LearnerSpec, protocol: str, path: Path) -> Trainer:
    first = Trainer(spec, protocol, global_seed=11)
    with pytest.raises(Interrupted):
        first.learn(path, stop_at=3 * ROLLOUT)
    assert path.exists() and not path.with_name(path.name + ".tmp").exists()
    resumed = Trainer(spec, protocol, global_seed=12345)
    resumed.learn(path)
    assert resumed.resumed_at == 2 * ROLLOUT  # the checkpoint of update 2 (update 3's was never written)
    return resumed


@pytest.mark.slow
@pytest.mark.parametrize(("name", "protocol"), CASES)
def test_a_resumed_fleet_ends_bit_for_bit_as_the_uninterrupted_one(name: str, protocol: str, tmp_path: Path) -> None:
    spec = small_spec(name)
    whole = Trainer(spec, protocol, global_seed=7)
    whole.learn()
    resumed = interrupted_and_resumed(spec, protocol, tmp_path / "fleet.pt")
    assert [r["step"] for k, r in whole.rows if k == 0] == [0, 704, 1400, 2104]
    if name in ("ppo_lag", "cpo"):
        assert len(whole.fleet.update_logs[0]) == UPDATES
    assert_identical(final_state(whole), final_state(resumed))


@pytest.mark.slow
def test_the_comparison_fails_when_a_part_of_the_state_is_not_restored(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The equality above is not vacuous: a resume that keeps the fresh fleet's numpy generators
    (minibatch order) ends elsewhere."""
    spec = small_spec("ppo")
    whole = Trainer(spec, "paper", global_seed=7)
    whole.learn()
    monkeypatch.setattr(fleet_streams, "_load_random_state", lambda rng, state: None)
    resumed = interrupted_and_resumed(spec, "paper", tmp_path / "fleet.pt")
    with pytest.raises(AssertionError):
        assert_identical(final_state(whole), final_state(resumed))


def test_a_checkpoint_restores_into_the_optimisers_buffers_in_place(tmp_path: Path) -> None:
    """The networks' parameters stay views into their optimiser's flat buffer after a restore
    (the fused Adam steps the buffer; a copy would silently stop training)."""
    spec = small_spec("ppo_lag")
    path = tmp_path / "fleet.pt"
    with pytest.raises(Interrupted):
        Trainer(spec, "paper", 1).learn(path, stop_at=2 * ROLLOUT)
    resumed = Trainer(spec, "paper", 1)
    fleet = resumed.fleet
    before = [p.data_ptr() for p in fleet.nets.params("pi", "vf", "cf")] + [fleet.lagrange.data_ptr()]  # type: ignore[attr-defined]
    with pytest.raises(Interrupted):
        resumed.learn(path, stop_at=2 * ROLLOUT)  # restored at update 1, trained update 2
    assert resumed.resumed_at == ROLLOUT and fleet.num_timesteps == 2 * ROLLOUT
    assert [p.data_ptr() for p in fleet.nets.params("pi", "vf", "cf")] + [fleet.lagrange.data_ptr()] == before  # type: ignore[attr-defined]
    flat = fleet.actor_optimizer.flat  # type: ignore[attr-defined]
    assert fleet.nets.params("pi")[0].untyped_storage().data_ptr() == flat.untyped_storage().data_ptr()


# ---------------------------------------------------------------------------------- refused files
def _checkpointed(tmp_path: Path, name: str = "ppo") -> tuple[LearnerSpec, Path]:
    """A checkpoint of update 1 of a small fleet."""
    spec = small_spec(name)
    path = tmp_path / "fleet.pt"
    with pytest.raises(Interrupted):
        Trainer(spec, "paper", 1).learn(path, stop_at=2 * ROLLOUT)
    assert path.exists()
    return spec, path


def _starts_over(spec: LearnerSpec, path: Path, caplog: pytest.LogCaptureFixture, expected: str,
                 outcome: str = "discarded, training from the start", **learn: Any) -> None:
    """A fleet given ``path`` discards it (or sets it aside) with one warning naming ``expected``
    and ``outcome``, and trains from step 0."""
    fresh = Trainer(spec, "paper", 1)
    with caplog.at_level(logging.WARNING, logger="morality_gym.baselines.fleet.checkpoint"), pytest.raises(Interrupted):
        fresh.learn(path, stop_at=ROLLOUT, **learn)
    warnings = [r.getMessage() for r in caplog.records if r.name == "morality_gym.baselines.fleet.checkpoint"]
    assert len(warnings) == 1 and outcome in warnings[0] and expected in warnings[0], warnings
    assert fresh.resumed_at is None and fresh.fleet.num_timesteps == ROLLOUT
    assert [r["step"] for k, r in fresh.rows if k == 0] == [0]  # evaluated at step 0 again


@pytest.mark.slow
def test_a_checkpoint_of_another_commit_is_discarded(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    spec, path = _checkpointed(tmp_path)
    _starts_over(spec, path, caplog, "commit: saved 'abc', now 'def'", key={**KEY, "commit": "def"})


@pytest.mark.slow
def test_a_checkpoint_of_another_fleet_is_discarded(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    _, path = _checkpointed(tmp_path)
    other = small_spec("ppo", n_epochs=3)  # another learner under one key
    _starts_over(other, path, caplog, "does not fit this fleet (spec differs")


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["truncated", "garbage", "empty"])
def test_a_damaged_checkpoint_is_discarded(tmp_path: Path, caplog: pytest.LogCaptureFixture, damage: str) -> None:
    spec, path = _checkpointed(tmp_path)
    data = path.read_bytes()
    path.write_bytes({"truncated": data[: len(data) // 2], "garbage": b"not a checkpoint" * 10, "empty": b""}[damage])
    _starts_over(spec, path, caplog, "cannot be read", outcome="set aside as fleet.pt.damaged, training from the start")
    assert path.with_name("fleet.pt.damaged").exists()  # kept for a look, never read again


def test_a_state_that_fails_half_way_leaves_the_fleet_at_step_0(tmp_path: Path) -> None:
    """A state whose identity fits but whose parts do not (a damaged file): the fleet's own state
    is put back, nothing of the bad one stays."""
    fleet = make_fleet(small_spec("ppo"), "paper")
    fleet.learn(ROLLOUT)
    state = fleet.state_dict()
    fresh = make_fleet(small_spec("ppo"), "paper")
    fresh.total_timesteps = fleet.total_timesteps
    fresh._start_evaluations(0, 10, None)
    fresh._start_training()
    before = fresh.state_dict()
    state["env"]["sim"]["state"] = state["env"]["sim"]["state"][:1]  # the nets and optimisers load, the simulator fails
    with pytest.raises(ValueError, match="simulator state"):
        fresh.load_state_dict(state)
    assert_identical(before, fresh.state_dict())


# ---------------------------------------------------------------------------------- the sweep
SWEEP = ["algo=ppo_lag", "chain=utility", "scenario=[switch_standard]", "preset=smoke", "seed=[1]",
         "variant=[HumanA,HumanB,AnimalA]", "preset.budget=8192", "preset.learn_eval_every=3000"]
#: What two trainings of the same runs may differ in: when and where they ran.
TIMING = ["wall_time_s", "cpu_time_s", "hostname", "started_at", "finished_at"]


def _sweep_config(tmp_path: Path, *overrides: str) -> Any:
    from tests.test_fleet_sweep import _sweep_config as compose

    return compose(tmp_path, *overrides)


def _recorded(results: Path) -> dict[str, Any]:
    """Every run's row, learn-time evaluations and diagnostics, without the timing columns."""
    from morality_gym.results.schema import read_learn, read_runs, read_updates

    runs = read_runs(results).drop(columns=TIMING).sort_values("run_id").reset_index(drop=True)
    learn = read_learn(results).drop(columns=["wall_time_s"]).sort_values(["run_id", "step"]).reset_index(drop=True)
    updates = {r: read_updates(results, r).reset_index(drop=True) for r in runs.run_id}
    return {"runs": runs, "learn": learn, "updates": updates}


def assert_same_records(a: dict[str, Any], b: dict[str, Any]) -> None:
    import pandas as pd

    pd.testing.assert_frame_equal(a["runs"], b["runs"], check_exact=True)
    pd.testing.assert_frame_equal(a["learn"], b["learn"], check_exact=True)
    assert a["updates"].keys() == b["updates"].keys()
    for run_id in a["updates"]:
        pd.testing.assert_frame_equal(a["updates"][run_id], b["updates"][run_id], check_exact=True)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[Any], dict[str, Any]]:
    """The sweep's runs and what an uninterrupted fleet job records for them."""
    from runners.execute.jobs import execute_job
    from runners.plan.fleets import make_jobs
    from runners.plan.runs import expand_sweep

    tmp = tmp_path_factory.mktemp("whole")
    runs = expand_sweep(_sweep_config(tmp, *SWEEP))
    (job,) = make_jobs(runs, "fleet", 36, 1)
    summaries = list(execute_job(job.items, tmp / "r", gif=False, engine="fleet", checkpoint_every_s=1e-6))
    assert [s["status"] for s in summaries] == ["ok"] * 3
    assert not list((tmp / "r" / "checkpoints").glob("*.pt"))  # removed once every run was recorded
    return runs, _recorded(tmp / "r")


@pytest.mark.slow
def test_a_fleet_killed_while_recording_resumes_at_the_end_of_training(
    tmp_path: Path, uninterrupted: tuple[list[Any], dict[str, Any]], caplog: pytest.LogCaptureFixture
) -> None:
    """The checkpoint written when training ends: a worker killed after recording one run builds
    the whole fleet again, restores it at its last step (no training) and records the other two."""
    from runners.execute.jobs import execute_job

    runs, expected = uninterrupted
    results = tmp_path / "r"
    items = [(r.run_id, r.config) for r in runs]
    job = execute_job(items, results, gif=False, engine="fleet", checkpoint_every_s=1e-6)
    assert next(job)["status"] == "ok"
    job.close()  # the kill: the other runs are never recorded
    assert len(list((results / "checkpoints").glob("*.pt"))) == 1
    with caplog.at_level(logging.WARNING):
        summaries = list(execute_job(items, results, gif=False, engine="fleet", checkpoint_every_s=1e-6))
    assert [s.get("skipped", False) for s in summaries] == [True, False, False]
    assert "fleet of 3 runs resumed at 8,192 of 8,192 steps from" in caplog.text
    assert_same_records(expected, _recorded(results))
    assert not list((results / "checkpoints").iterdir())
    from morality_gym.results.schema import read_runs

    assert read_runs(results).started_at.nunique() == 1  # the resumed runs started when the fleet did


@pytest.mark.slow
def test_a_killed_fleet_sweep_resumes_its_training_from_the_checkpoint(tmp_path: Path) -> None:
    """SIGKILL a sweep once its fleet has checkpointed; the next sweep forms the same fleet,
    resumes it (a log line says where) and records exactly what an uninterrupted sweep records.

    The uninterrupted sweep runs in a fresh process too, not in this test process: the learn-time
    exact evaluation's last bit can depend on what its process evaluated before (a CI run of the
    whole suite, where other tests' scenarios came first in this process, differed in one
    ``exact_metric`` in the 16th digit), and the claim is about the sweep, not about pytest's process."""
    import os
    import signal
    import time

    from tests.test_fleet_sweep import _sweep

    args = [*SWEEP, "launcher.workers=1", "checkpoint_every_s=0.000001"]
    whole = _sweep(tmp_path / "whole", *args)
    assert whole.returncode == 0, whole.stderr
    expected = _recorded(tmp_path / "whole")
    results = tmp_path / "r"
    first = _sweep(results, *args, background=True)
    deadline = time.monotonic() + 120
    while not list((results / "checkpoints").glob("*.pt")):
        assert first.poll() is None and time.monotonic() < deadline, first.stdout.read() if first.stdout else ""
        time.sleep(0.02)
    os.killpg(first.pid, signal.SIGKILL)
    first.wait(timeout=30)
    assert not (results / "runs").exists() or not list((results / "runs").glob("*.parquet"))
    second = _sweep(results, *args)
    assert second.returncode == 0, second.stderr
    assert "1 fleet(s) resume their training from a checkpoint" in " ".join(second.stderr.split()), second.stderr  # the plan
    resumed = [line for line in second.stderr.splitlines() if "resumed at" in line]
    assert len(resumed) == 1 and resumed[0].startswith("fleet of 3 runs resumed at ") and "of 8,192 steps from" in resumed[0]
    assert int(resumed[0].split("resumed at ")[1].split(" of")[0].replace(",", "")) < 8192  # killed while training
    assert_same_records(expected, _recorded(results))
    assert not list((results / "checkpoints").iterdir())


def test_make_jobs_forms_a_checkpointed_fleet_again(tmp_path: Path) -> None:
    from runners.plan.fleets import make_jobs
    from runners.plan.runs import expand_sweep

    runs = expand_sweep(_sweep_config(tmp_path, "algo=ppo", "chain=utility", "scenario=[switch_standard]", "preset=smoke", "seed=[1,2]"))
    assert len(runs) == 24
    ids = [r.run_id for r in runs]
    fleet = (ids[3], ids[17], ids[5])  # not a chunk the plan would cut
    jobs = make_jobs(runs, "fleet", fleet_size=10, workers=1, checkpointed=[fleet])
    assert sorted(r.run_id for j in jobs for r in j.runs) == sorted(ids)  # every run once
    assert [r.run_id for r in jobs[0].runs] == [ids[3], ids[5], ids[17]] and jobs[0].engine == "fleet"  # first, in plan order
    assert sorted(len(j.runs) for j in jobs[1:]) == [7, 7, 7]  # the other 21 runs cut as before
    # a fleet with a run not to do (finished), or of two groups, is not formed; no checkpoint: as before
    assert make_jobs(runs[1:], "fleet", 10, 1, checkpointed=[(ids[0], ids[1])]) == make_jobs(runs[1:], "fleet", 10, 1)
    assert make_jobs(runs, "fleet", 10, 3) == make_jobs(runs, "fleet", 10, 3, checkpointed=[])


def test_the_checkpoint_interval_is_a_sweep_setting_outside_every_run(tmp_path: Path) -> None:
    from runners.compose.sweep_config import ConfigError
    from runners.plan.runs import expand_sweep

    default = _sweep_config(tmp_path, "algo=[ppo,cpo]", "chain=utility", "scenario=[switch_standard]", "preset=smoke")
    assert default.checkpoint_every_s == 300.0
    for value in ("0", "12.5"):
        other = _sweep_config(tmp_path, "algo=[ppo,cpo]", "chain=utility", "scenario=[switch_standard]", "preset=smoke",
                              f"checkpoint_every_s={value}")
        assert other.checkpoint_every_s == float(value)
        assert [(r.run_id, r.config) for r in expand_sweep(other)] == [(r.run_id, r.config) for r in expand_sweep(default)]
    with pytest.raises(ConfigError, match="checkpoint_every_s: expected a number of seconds >= 0"):
        _sweep_config(tmp_path, "algo=ppo", "checkpoint_every_s=-1")


def test_stale_checkpoints_are_removed_and_only_those(tmp_path: Path) -> None:
    from runners.execute.jobs import execute_job
    from runners.plan.runs import expand_sweep
    from runners.record import fleet_checkpoints as fc

    runs = expand_sweep(_sweep_config(tmp_path, "algo=random", "chain=utility", "scenario=[switch_standard]", "preset=smoke",
                              "variant=[HumanA,HumanB,AnimalA]"))
    results = tmp_path / "r"
    list(execute_job([(r.run_id, r.config) for r in runs[:2]], results, gif=False))  # two runs finish ok
    done = fc.write_fleet_runs(results, [(r.run_id, r.config) for r in runs[:2]])
    open_ = fc.write_fleet_runs(results, [(r.run_id, r.config) for r in runs[1:]])
    for path in (done, open_):
        path.write_bytes(b"state")
    assert sorted(fc.checkpointed_fleets(results)) == sorted([tuple(sorted(r.run_id for r in runs[:2])),
                                                              tuple(sorted(r.run_id for r in runs[1:]))])
    # run 1 of the open fleet is recorded: its run still to do is one, too few to form a fleet again
    assert fc.fleets_to_form(results, [runs[2].run_id]) == []
    assert fc.remove_stale(results) == [done]
    assert not done.exists() and not done.with_suffix(".json").exists() and open_.exists()


def test_a_resumed_fleet_counts_the_time_spent_before_the_kill() -> None:
    """A run's ``wall_time_s`` and ``cpu_time_s`` (compute accounting) include the training before
    the checkpoint: the time spent travels in the checkpoint's extra data."""
    from morality_gym.results.recording import RunClock
    from runners.execute.jobs import FleetTraining

    runs = [("a", {}), ("b", {})]
    before = FleetTraining(runs, RunClock.already_spent("2026-01-01T00:00:00+00:00", 5000.0, 3000.0))  # trained a while
    extra = before._extra()
    assert extra["wall_s"] >= 5000 and extra["cpu_s"] >= 3000 and extra["learn_rows"] == [[], []]
    after = FleetTraining(runs, RunClock.start())
    after._resume(8192, {**extra, "learn_rows": [[{"step": 0}], []]})
    wall, cpu = after.clock.elapsed()
    assert wall >= extra["wall_s"] and cpu >= extra["cpu_s"]
    assert after.clock.started == "2026-01-01T00:00:00+00:00" and after.learn_rows == [[{"step": 0}], []]


def test_the_checkpoint_key_changes_with_the_training_code_only(tmp_path: Path) -> None:
    from runners.execute.run import code_fingerprint

    package = tmp_path / "morality_gym"
    (package / "data").mkdir(parents=True)
    (package / "kernel.py").write_text("STEP = 1\n")
    (package / "data" / "chain.yaml").write_text("norms: [a]\n")
    (package / "README.md").write_text("docs\n")
    first = code_fingerprint(package, "torch 2.13.0")
    (package / "README.md").write_text("other docs\n")
    assert code_fingerprint(package, "torch 2.13.0") == first  # documentation trains nothing
    (package / "data" / "chain.yaml").write_text("norms: [b]\n")
    changed_data = code_fingerprint(package, "torch 2.13.0")
    (package / "kernel.py").write_text("STEP = 2\n")
    changed_code = code_fingerprint(package, "torch 2.13.0")
    assert len({first, changed_data, changed_code, code_fingerprint(package, "torch 2.14.0")}) == 4
