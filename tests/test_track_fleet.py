"""Fleets on the generalisation track's mixture (issue 44 item 3): drawn dilemmas, per-dilemma
costs, the compact observation.

* Each run's draws are a function of its seed and its own history: the same whatever other runs
  share its simulator or fleet (bit for bit, for every learner).
* A copy's cost follows the dilemma it is on: each step costs what the chain bound to that env id
  charges (its own normalisation), not the first pool entry's.
* The compact observation tells apart every pair of states the grid tells apart.
* A drawn simulator restored from its state continues as the uninterrupted one.
"""

from __future__ import annotations

import hashlib
import platform

import numpy as np
import pytest
import torch as th

import morality_gym
from morality_gym.baselines.device import Device
from morality_gym.baselines.fleet import FleetRun, build_fleet
from morality_gym.baselines.fleet.drawn_env import DrawnFleetEnv
from morality_gym.baselines.specs import SpecError, learner_spec
from morality_gym.envs.drawn import DrawnBatchedTrolleyEnv
from morality_gym.envs.registry import clear_graph_cache, env_ids, state_graph
from morality_gym.norms.cost import VectorCost
from morality_gym.norms.reward_cost import RewardCostSpec
from morality_gym.world.compact_observe import COMPACT_WIDTH, collisions, compact_from_grid, sign_matrix
from morality_gym.world.grid_observe import grid_table

#: Pools of different scenarios and variants (their cost bounds differ).
POOL_A = ["Switch7-Human-v1", "PushOrSwitch-Animal-v1", "PushStandard-AnimalA-v1", "Push2OrSwitch-Robot-v1",
          "PushOrSwitch-Human-v1"]
POOL_B = ["PushStandard-AnimalA-v1", "Switch7-Robot-v1"]
SMALL = {
    "ppo": {"n_steps": 32, "n_epochs": 2},
    "ppo_shaped": {"n_steps": 32, "n_epochs": 2},
    "ppo_lag": {"n_steps": 32, "n_epochs": 3},
    "cpo": {"n_steps": 32, "n_critic_updates": 2},
}


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tests/conftest.py


@pytest.fixture(autouse=True)
def _own_cache(tmp_path_factory, monkeypatch) -> None:
    """``runners.track`` keeps its pools' tables under ``$MORALITY_GYM_CACHE``: here, not the user's."""
    monkeypatch.setenv("MORALITY_GYM_CACHE", str(tmp_path_factory.mktemp("cache")))


def _stream_entries(env: DrawnBatchedTrolleyEnv, stream: int, steps: int, actions: np.ndarray) -> list[list[str]]:
    """Stream ``stream``'s copies' env ids after each step, its copies driven by ``actions`` [steps, copies]."""
    env.reset()
    cps = env.copies_per_stream
    out = []
    for t in range(steps):
        full = np.zeros(env.num_envs, dtype=np.int64)
        full[stream * cps : (stream + 1) * cps] = actions[t]
        env.step(full)
        out.append(env.current_env_ids()[stream * cps : (stream + 1) * cps])
    return out


def test_a_streams_draws_do_not_depend_on_the_other_streams() -> None:
    actions = np.random.default_rng(3).integers(0, 6, (400, 4))
    alone = _stream_entries(DrawnBatchedTrolleyEnv([POOL_A], 4, [7]), 0, 400, actions)
    shared = _stream_entries(DrawnBatchedTrolleyEnv([POOL_B, POOL_A, POOL_A], 4, [1, 7, 9]), 1, 400, actions)
    assert alone == shared
    assert len({e for step in alone for e in step}) == len(POOL_A)  # it did draw every dilemma of its pool
    other_seed = _stream_entries(DrawnBatchedTrolleyEnv([POOL_A], 4, [8]), 0, 400, actions)
    assert other_seed != alone


def test_a_restored_drawn_simulator_continues_as_the_uninterrupted_one() -> None:
    env = DrawnBatchedTrolleyEnv([POOL_A, POOL_B], 3, [5, 6])
    rng = np.random.default_rng(0)
    env.reset()
    for _ in range(150):
        env.step(rng.integers(0, 6, env.num_envs))
    saved = env.state_dict()
    actions = rng.integers(0, 6, (150, env.num_envs))
    straight = [env.step(a).obs.copy() for a in actions]
    other = DrawnBatchedTrolleyEnv([POOL_A, POOL_B], 3, [5, 6])
    other.reset()
    other.load_state_dict(saved)
    resumed = [other.step(a).obs.copy() for a in actions]
    np.testing.assert_array_equal(np.stack(straight), np.stack(resumed))


@pytest.mark.parametrize("cost_mode", ["minimal", "full"])
def test_each_copys_cost_is_its_current_dilemmas(cost_mode: str) -> None:
    pool = [morality_gym.bind_chain("Utility", e) for e in POOL_A]
    assert len({str(b.global_bounds if cost_mode == "minimal" else b.bounds) for b in pool}) > 1  # normalisers differ
    by_id = {b.env_id: b for b in pool}
    env = DrawnFleetEnv([pool], [11], 6, RewardCostSpec(cost_mode=cost_mode))
    steps = []
    real_step = env.sim.step
    env.sim.step = lambda actions: steps.append(real_step(actions)) or steps[-1]  # type: ignore[method-assign]
    env.reset()

    def fresh(env_id: str) -> VectorCost:  # a new episode: a new dilemma, an empty memory
        return VectorCost(by_id[env_id], 1, mode=cost_mode, reset="per_episode")

    own = [fresh(e) for e in env.sim.current_env_ids()]
    rng = np.random.default_rng(1)
    charged = 0
    for _ in range(600):
        step = env.step(th.from_numpy(rng.integers(0, 6, env.sim.num_envs)))
        res = steps[-1]
        utility = env.sim.utility(res.transition)
        for i, cost in enumerate(own):
            expected = float(cost(res.events[i : i + 1], utility[i : i + 1], np.array([bool(step.dones[i])]))[0])
            assert step.costs[i].item() == expected, (cost.bound.env_id, i)
            charged += expected != 0.0
        for i in np.flatnonzero(step.dones.numpy()):
            own[i] = fresh(env.sim.current_env_ids()[i])
    assert charged > 0  # some steps cost something


def test_mixture_runs_are_the_same_bits_whatever_fleet_they_train_in() -> None:
    for name in ("ppo", "ppo_shaped", "ppo_lag", "cpo"):
        spec = learner_spec(name, {"hparams": SMALL[name]})
        utility = [morality_gym.bind_chain("Utility", e) for e in POOL_A]
        dual = [morality_gym.bind_chain("DualProcess", e) for e in ("PushOrSwitch-Human-v1", "PushStandard-AnimalA-v1")]
        alone = build_fleet(spec, [FleetRun.mixture(utility, 3)], "paper")
        shared = build_fleet(spec, [FleetRun.mixture(dual, 4), FleetRun.mixture(utility, 3)], "paper")
        for fleet in (alone, shared):
            fleet.learn(3 * 32 * 8)
        a, b = alone.learners()[0], shared.learners()[1]
        assert a.model.policy.observation_space.shape == (COMPACT_WIDTH,)
        for (pname, pa), (_, pb) in zip(a.model.policy.named_parameters(), b.model.policy.named_parameters()):
            np.testing.assert_array_equal(pa.detach().numpy(), pb.detach().numpy(), err_msg=f"{name} {pname}")
        assert str(a.update_diagnostics()) == str(b.update_diagnostics())


class _Interrupted(Exception):
    pass


@pytest.mark.parametrize("name", ["ppo_lag", "cpo"])
def test_a_killed_mixture_fleet_resumes_from_its_checkpoint_bit_for_bit(name: str, tmp_path) -> None:
    from morality_gym.baselines.fleet import FleetCheckpoint

    spec = learner_spec(name, {"hparams": SMALL[name]})
    pool = [morality_gym.bind_chain("Utility", e) for e in POOL_A]
    rollout = 32 * 8

    def fleet():
        return build_fleet(spec, [FleetRun.mixture(pool, 3), FleetRun.mixture(pool[1:], 4)], "paper")

    def stop(steps: int, _total: int) -> None:
        if steps >= 2 * rollout:
            raise _Interrupted

    path = tmp_path / "fleet.pt"
    with pytest.raises(_Interrupted):
        fleet().learn(4 * rollout, on_progress=stop, checkpoint=FleetCheckpoint(path, every_s=0.0))
    resumed, whole = fleet(), fleet()
    resumed.learn(4 * rollout, checkpoint=FleetCheckpoint(path, every_s=0.0))
    whole.learn(4 * rollout)
    for a, b in zip(whole.learners(), resumed.learners()):
        for (pname, pa), (_, pb) in zip(a.model.policy.named_parameters(), b.model.policy.named_parameters()):
            np.testing.assert_array_equal(pa.detach().numpy(), pb.detach().numpy(), err_msg=pname)
    np.testing.assert_array_equal(whole.collector.env.sim.draws, resumed.collector.env.sim.draws)


# ---------------------------------------------------------------------- the same bits as the release's runs
#: A mixture run's bits, recorded on main at 212ffd5 (before the table cache and the rollout's speed-ups of
#: issue 44): the release's compute switches to newer code between checkpoints, so every change of the
#: training path must leave every bit of a run as it was. The simulator's figures are numpy integer
#: gathers and float64 costs (any platform); the parameters' are torch's float32 arithmetic on one
#: thread, recorded with torch 2.13.0+cpu on x86-64 (another build may round differently).
GOLDEN_SIM = {"minimal": "e258b508b1153b8c", "full": "a884979aa5a2c37f"}
GOLDEN_PARAMS = {"ppo": ("30aa7ec4e74460b1", "f2bdcd080abe560d"), "ppo_shaped": ("58235f029f6101dc", "0c383f08c42b585a"),
                 "ppo_lag": ("7bc0d7b301c5452e", "54318aaa39eb984f"), "cpo": ("6f0e8cda156e1bb5", "58ab1661aa6f46b1")}
GOLDEN_DIAGNOSTICS = {"ppo": ("4f53cda18c2baa0c",) * 2, "ppo_shaped": ("4f53cda18c2baa0c",) * 2,
                      "ppo_lag": ("2edf31cff26592cd", "5cce204fcd3eed57"), "cpo": ("f45df9897d75c46e", "f3ca5a0784951a62")}
GOLDEN_TORCH = ("2.13.0+cpu", "x86_64")
DUAL = ["PushOrSwitch-Human-v1", "PushStandard-AnimalA-v1", "Switch7-Robot-v1"]


def _golden_pools() -> list[list]:
    return [[morality_gym.bind_chain("DualProcess", e) for e in DUAL], [morality_gym.bind_chain("Utility", e) for e in POOL_A]]


def _digest(*arrays: np.ndarray) -> str:
    digest = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        digest.update(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    return digest.hexdigest()[:16]


@pytest.mark.parametrize("cached", [False, True])
@pytest.mark.parametrize("cost_mode", ["minimal", "full"])
def test_the_mixtures_steps_are_the_recorded_bits(cost_mode: str, cached: bool, tmp_path) -> None:
    cache = tmp_path if cached else None
    if cached:  # the second simulator reads every table from the files
        DrawnFleetEnv(_golden_pools(), [12, 11], 6, RewardCostSpec(cost_mode=cost_mode), table_cache=cache)
        clear_graph_cache()
    env = DrawnFleetEnv(list(reversed(_golden_pools())), [11, 12], 6, RewardCostSpec(cost_mode=cost_mode), table_cache=cache)
    rng = np.random.default_rng(1)
    digest = hashlib.sha256(env.reset().numpy().tobytes())
    for _ in range(600):
        step = env.step(th.from_numpy(rng.integers(0, 6, env.sim.num_envs)))
        for t in (step.obs, step.rewards, step.costs, step.dones, step.truncated):
            digest.update(t.numpy().tobytes())
        if step.final_obs is not None:
            digest.update(step.final_obs.numpy().tobytes())
    assert digest.hexdigest()[:16] == GOLDEN_SIM[cost_mode]


@pytest.mark.skipif((th.__version__, platform.machine()) != GOLDEN_TORCH,
                    reason=f"the parameters' bits were recorded with torch {GOLDEN_TORCH[0]} on {GOLDEN_TORCH[1]}")
def test_mixture_fleets_train_the_recorded_bits_from_built_and_cached_tables(tmp_path) -> None:
    """Every learner, 3 updates of two runs on two chains' pools: the first fleet builds the tables
    and writes them, every later one reads them (and the last again after the graphs are forgotten)."""
    for name in (*GOLDEN_PARAMS, "ppo"):
        if name == "ppo" and any(tmp_path.iterdir()):
            clear_graph_cache()
        spec = learner_spec(name, {"hparams": SMALL[name]})
        fleet = build_fleet(spec, [FleetRun.mixture(p, seed) for p, seed in zip(_golden_pools(), (4, 3))], "paper",
                            table_cache=tmp_path)
        fleet.learn(3 * 32 * 8)
        got = tuple(_digest(*(p.detach().numpy() for p in run.model.policy.parameters())) for run in fleet.learners())
        assert got == GOLDEN_PARAMS[name], name
        assert tuple(hashlib.sha256(str(run.update_diagnostics()).encode()).hexdigest()[:16]
                     for run in fleet.learners()) == GOLDEN_DIAGNOSTICS[name], name
    assert len(list(tmp_path.glob("*.npz"))) == len(set(DUAL) | set(POOL_A))


def test_a_fleet_does_not_mix_mixture_and_single_env_runs() -> None:
    spec = learner_spec("ppo", {"hparams": SMALL["ppo"]})
    bound = morality_gym.bind_chain("Utility", POOL_A[0])
    with pytest.raises(SpecError, match="either mixture runs"):
        build_fleet(spec, [FleetRun.mixture([bound], 1), FleetRun(bound, 2)], "paper")
    with pytest.raises(SpecError, match="simulated on the host"):
        build_fleet(spec, [FleetRun.mixture([bound], 1)], "paper", simulator="device")


# ---------------------------------------------------------------------- the compact observation
def test_the_compact_observation_tells_apart_every_state_the_grid_does_on_the_builtin_envs() -> None:
    """Two variants of every built-in scenario (all 98 and the whole train mixture: the benchmark
    ``benchmarks/bench_track_fleet.py`` checks them, minutes)."""
    by_scenario: dict[str, list[str]] = {}
    for env_id in env_ids():
        by_scenario.setdefault(env_id.split("-")[0], []).append(env_id)
    grids = []
    for env_id in [e for ids in by_scenario.values() for e in (ids[0], ids[-1])]:
        graph = state_graph(env_id)
        n = graph.tables().n_states
        grids.append(grid_table(graph.world, graph.states[:n]).reshape(n, -1))
    table = np.concatenate(grids)
    distinct = np.unique(table, axis=0)
    assert len(distinct) > 5_000
    assert collisions(distinct) == []


def test_collisions_finds_distinct_grids_with_one_compact_observation() -> None:
    grids = np.zeros((3, 20, 16, 16), dtype=np.uint8)
    grids[1, 0, 0, 0] = 1
    compact = compact_from_grid(grids)
    assert collisions(grids, compact) == []
    merged = compact.copy()
    merged[1] = merged[0]  # what a projection that merged two states would give
    assert collisions(grids, merged) == [(0, 1)]
    merged[2] = merged[0]  # grids 0 and 2 are equal: not a collision
    assert collisions(grids, merged) == [(0, 1)]


def test_the_compact_observation_is_exact_and_fixed() -> None:
    signs = sign_matrix()
    assert signs.shape == (20 * 16 * 16, COMPACT_WIDTH) and set(np.unique(signs)) == {-1.0, 1.0}
    assert abs(float(signs.mean())) < 0.01
    # pinned: a change of the matrix changes every trained policy's inputs
    assert signs[:3, :6].tolist() == PINNED_SIGNS
    rng = np.random.default_rng(0)
    grids = rng.integers(0, 256, (4, 20, 16, 16)).astype(np.uint8)
    exact = (grids.reshape(4, -1).astype(np.int64) @ signs.astype(np.int64)) / 16
    np.testing.assert_array_equal(compact_from_grid(grids), exact.astype(np.float32))
    with pytest.raises(ValueError, match="shape"):
        compact_from_grid(np.zeros((2, 7)))
    with pytest.raises(ValueError, match="fractional"):
        compact_from_grid(np.full((1, 5120), 0.5))


PINNED_SIGNS: list[list[float]] = [[-1.0, 1.0, 1.0, -1.0, -1.0, -1.0], [-1.0, -1.0, -1.0, -1.0, -1.0, -1.0],
                                    [1.0, 1.0, 1.0, -1.0, 1.0, -1.0]]



# ---------------------------------------------------------------------- runners.track on fleets
def _chain_sets() -> dict:
    from morality_gym.generalisation.sets import EvalSet, PairValues

    def pv(env_id: str) -> PairValues:
        return PairValues(env_id, "Utility", 1.0, 0.0, 0.5)

    return {"seen": EvalSet("seen", (pv(POOL_A[0]),), {"split": "train", "split_digest": "a", "chain": "Utility"}),
            "test": EvalSet("test", (pv("Switch5-Human-v1"),), {"split": "test", "split_digest": "b", "chain": "Utility"})}


def test_a_chains_track_trains_fleets_and_a_rerun_redoes_only_missing_runs(tmp_path, monkeypatch, capsys) -> None:
    import json

    import pandas as pd

    from runners import track

    monkeypatch.setattr(track, "load_sets", lambda *a, **k: (list(POOL_A), _chain_sets()))
    argv = ["--chain", "Utility", "--learners", "random", "ppo_lag", "--seeds", "1", "2", "--budget", "2048",
            "--out", str(tmp_path)]
    assert track.main(argv) == 0
    runs = tmp_path / "runs"
    for seed in (1, 2):
        record = json.loads((runs / f"Utility-ppo_lag-s{seed}" / track.RESULT).read_text())
        assert record["engine"] == "fleet" and record["chain"] == "Utility" and record["trained_steps"] == 2048
        assert (runs / f"Utility-ppo_lag-s{seed}" / "model.zip").is_file()
    assert "fleet of 2 runs" in capsys.readouterr().out
    from morality_gym.generalisation.sets import table_cache_dir

    assert len(list(table_cache_dir().glob("*.npz"))) == len(POOL_A)  # the next session reads the pool's tables
    first = pd.read_parquet(runs / "Utility-ppo_lag-s2" / track.PAIRS)

    # a crash after seed 1 was written: the rerun trains seed 2 alone, to the same numbers
    (runs / "Utility-ppo_lag-s2" / track.RESULT).unlink()
    assert track.main(argv) == 0
    out = capsys.readouterr().out
    assert "fleet of 1 runs" in out and "Utility-ppo_lag-s1: done, skipped" in out
    pd.testing.assert_frame_equal(pd.read_parquet(runs / "Utility-ppo_lag-s2" / track.PAIRS), first)

    monkeypatch.setattr(track, "train_fleet", lambda *a, **k: pytest.fail("a done fleet was trained again"))
    assert track.main(argv) == 0


def test_the_cost_learners_need_a_chain_before_anything_is_loaded(monkeypatch) -> None:
    from runners import track

    monkeypatch.setattr(track, "load_sets", lambda *a, **k: pytest.fail("loaded the splits first"))
    with pytest.raises(track.TrackError, match="train on a chain's step-wise cost: add --chain"):
        track.main(["--learners", "cpo"])
    with pytest.raises(track.TrackError, match="ppo_lag trains whole rollouts of 2,048 steps"):
        track.main(["--learners", "ppo_lag", "--chain", "Utility", "--budget", "1000"])


def _curve(path) -> list[tuple[str, int, str]]:
    import csv

    return [(r["seed"], int(r["steps"]), r["mean_range_score"]) for r in csv.DictReader(path.open())]


def _train(tmp_path, name: str, curve_every: int | None, budget: int, say=lambda _m: None):
    from runners.execute import track_fleet

    pool = list(POOL_A)
    curve = None
    if curve_every is not None:
        curve = track_fleet.CurveRecorder(tmp_path / "curves" / "c.csv", "ppo_lag", "Utility", [1, 2],
                                          _chain_sets()["seen"], curve_every)
    key = track_fleet.fleet_key("ppo_lag", [1, 2], budget, pool, "Utility", "d")
    return track_fleet.train_fleet("ppo_lag", [1, 2], budget, pool, "Utility", tmp_path / "fleet.pt", key,
                                   say=say, curve=curve)


def test_a_chains_track_records_each_runs_learning_curve_at_every_point(tmp_path, monkeypatch) -> None:
    from runners import track

    monkeypatch.setattr(track, "load_sets", lambda *a, **k: (list(POOL_A), _chain_sets()))
    assert track.main(["--chain", "Utility", "--learners", "ppo_lag", "--seeds", "1", "2", "--budget", str(3 * 2048),
                       "--curve-every", "4096", "--out", str(tmp_path)]) == 0
    rows = _curve(tmp_path / "curves" / "Utility-ppo_lag.csv")
    assert [(seed, steps) for seed, steps, _ in rows] == [(s, n) for s in ("1", "2") for n in (0, 4096, 6144)]
    assert all(0.0 <= float(score) <= 1.0 for *_, score in rows)
    assert rows[0][2] != rows[2][2]  # the policy scored is the current one, not the untrained one
    with pytest.raises(track.TrackError, match="--curve-every must be positive"):
        track.main(["--chain", "Utility", "--curve-every", "0"])


def test_recording_a_curve_does_not_change_a_runs_bits(tmp_path) -> None:
    budget = 2 * 2048
    with_curve = _train(tmp_path / "a", "ppo_lag", 2048, budget)
    without = _train(tmp_path / "b", "ppo_lag", None, budget)
    for seed in (1, 2):
        for (pname, pa), (_, pb) in zip(with_curve[seed][0].model.policy.named_parameters(),
                                        without[seed][0].model.policy.named_parameters()):
            np.testing.assert_array_equal(pa.detach().numpy(), pb.detach().numpy(), err_msg=pname)


def test_a_resumed_fleet_continues_its_curve_without_losing_or_repeating_points(tmp_path, monkeypatch) -> None:
    from runners.execute import track_fleet

    monkeypatch.setattr(track_fleet, "CHECKPOINT_EVERY_S", 0.0)
    monkeypatch.setattr(track_fleet, "PROGRESS_EVERY_S", 0.0)
    budget, every = 5 * 2048, 2048

    def kill(message: str) -> None:  # after the curve's point at 3 rollouts, before that update's checkpoint
        if message.startswith("Utility ppo_lag: 6,144 of"):
            raise _Interrupted

    with pytest.raises(_Interrupted):
        _train(tmp_path / "r", "ppo_lag", every, budget, say=kill)
    assert [steps for seed, steps, _ in _curve(tmp_path / "r" / "curves" / "c.csv") if seed == "1"] == [0, 2048, 4096, 6144]
    def stop_on_resume(message: str) -> None:  # the progress line the restored step count gives
        if message.startswith("Utility ppo_lag: 4,096 of"):
            raise _Interrupted

    with pytest.raises(_Interrupted):  # right after the restore the file holds the restored curve
        _train(tmp_path / "r", "ppo_lag", every, budget, say=stop_on_resume)
    assert [steps for seed, steps, _ in _curve(tmp_path / "r" / "curves" / "c.csv") if seed == "1"] == [0, 2048, 4096]
    _train(tmp_path / "r", "ppo_lag", every, budget)  # resumes from the checkpoint at 4,096 steps
    _train(tmp_path / "w", "ppo_lag", every, budget)  # uninterrupted
    assert _curve(tmp_path / "r" / "curves" / "c.csv") == _curve(tmp_path / "w" / "curves" / "c.csv")
    assert [steps for seed, steps, _ in _curve(tmp_path / "w" / "curves" / "c.csv") if seed == "2"] == [
        0, 2048, 4096, 6144, 8192, 10240]


def test_a_failed_mixture_run_names_its_mixture_not_the_pools_first_dilemma() -> None:
    spec = learner_spec("ppo_lag", {"hparams": SMALL["ppo_lag"]})
    pool = [morality_gym.bind_chain("Utility", e) for e in POOL_A]
    fleet = build_fleet(spec, [FleetRun.mixture(pool, 3), FleetRun.mixture(pool, 4)], "paper")
    fleet.learn(32 * 8)
    with th.no_grad():
        fleet.nets.params("pi")[0][1, 0, 0] = float("nan")
    fleet._fail_non_finite_runs()
    assert list(fleet.failed) == [1]
    assert "(the mixture of 5 dilemmas, Utility, seed 4)" in fleet.failed[1]
    assert POOL_A[0] not in fleet.failed[1]


def test_a_device_is_checked_before_anything_is_loaded_and_keeps_the_cpus_checkpoints(monkeypatch) -> None:
    """``--device`` is refused in one line before the splits load (minutes) where torch sees no such
    device or no chain's fleet would use it; a CPU fleet's checkpoint key is the one it had before
    devices were asked for (the release compute resumes its checkpoints), a GPU's names its device."""
    from runners import track
    from runners.execute import track_fleet

    monkeypatch.setattr(track, "load_sets", lambda *a, **k: pytest.fail("loaded the splits first"))
    with pytest.raises(track.TrackError, match="--device: device='tpu'"):
        track.main(["--chain", "Utility", "--device", "tpu"])
    with pytest.raises(track.TrackError, match="only a chain's track trains fleets on a device; add --chain"):
        track.main(["--device", "cuda"])
    if not th.cuda.is_available():
        with pytest.raises(track.TrackError, match="torch sees no GPU here"):
            track.main(["--chain", "Utility", "--device", "cuda"])
    key = track_fleet.fleet_key("ppo", [1], 10, POOL_A, "Utility", "d")
    assert key == {"track": "generalisation", "learner": "ppo", "seeds": [1], "budget": 10, "chain": "Utility",
                   "train_digest": "d", "pool": len(POOL_A)}
    assert track_fleet.fleet_key("ppo", [1], 10, POOL_A, "Utility", "d", Device("cuda"))["device"] == "cuda"


@pytest.mark.skipif(not th.cuda.is_available(), reason="needs a GPU (device=cuda); this machine has none")
def test_a_chains_track_trains_its_fleets_on_the_gpu(tmp_path, monkeypatch) -> None:
    import json

    from runners import track

    monkeypatch.setattr(track, "load_sets", lambda *a, **k: (list(POOL_A), _chain_sets()))
    assert track.main(["--chain", "Utility", "--learners", "ppo", "cpo", "--seeds", "1", "2", "--budget", "2048",
                       "--device", "cuda", "--out", str(tmp_path)]) == 0
    for name in ("ppo", "cpo"):
        record = json.loads((tmp_path / "runs" / f"Utility-{name}-s1" / track.RESULT).read_text())
        # whole rollouts: PPO's is 8 copies x 2,048 steps, CPO's one copy's
        assert record["device"] == "cuda" and record["trained_steps"] == {"ppo": 16_384, "cpo": 2048}[name]


#: A driver for the SIGTERM test: the chain's track on POOL_A, a SIGTERM sent to itself right after
#: the fleet's second update (where the checkpoint asks whether it is due), as a stopping machine does.
_SIGTERM_DRIVER = """
import os, signal, sys
sys.path.insert(0, {tests!r})
from test_track_fleet import POOL_A, _chain_sets
from morality_gym.baselines.fleet import checkpoint
from runners import track
track.load_sets = lambda *a, **k: (list(POOL_A), _chain_sets())
due, calls = checkpoint.FleetCheckpoint.due, []
def due_then_kill(self):
    calls.append(1)
    if len(calls) == 2 and {kill}:
        os.kill(os.getpid(), signal.SIGTERM)
    return due(self)
checkpoint.FleetCheckpoint.due = due_then_kill
sys.exit(track.cli({argv!r}))
"""


def test_a_sigterm_stops_a_chains_track_at_an_update_with_the_fleets_state_written(tmp_path) -> None:
    """A SIGTERM while a chain's fleet trains (a session or machine that stops) writes the fleet's
    state at the next update and exits 143 with one line; the rerun resumes there and ends with the
    numbers of a run never stopped (without the handler, Python's default ended the process at once
    and the rerun went back to the last periodic checkpoint: up to 5 minutes of every run)."""
    import subprocess
    import sys
    from pathlib import Path

    import pandas as pd

    def run(out: Path, kill: bool) -> subprocess.CompletedProcess:
        argv = ["--chain", "Utility", "--learners", "ppo_lag", "--seeds", "1", "2", "--budget", str(3 * 2048),
                "--curve-every", "100000", "--out", str(out)]
        code = _SIGTERM_DRIVER.format(tests=str(Path(__file__).parent), kill=kill, argv=argv)
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=False)

    stopped = run(tmp_path / "a", kill=True)
    assert stopped.returncode == 143, stopped.stderr[-2000:]
    assert "stopped by SIGTERM: fleet of 2 runs stopped at 4,096 of 6,144 steps" in stopped.stderr
    assert "run the same command again to resume" in stopped.stderr and "Traceback" not in stopped.stderr
    assert len(list((tmp_path / "a" / "fleets").glob("*.pt"))) == 1
    assert not (tmp_path / "a" / "runs" / "Utility-ppo_lag-s1").exists()
    resumed = run(tmp_path / "a", kill=False)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert "resumed at 4,096 of 6,144 steps" in resumed.stderr
    straight = run(tmp_path / "b", kill=False)
    assert straight.returncode == 0, straight.stderr[-2000:]
    for seed in (1, 2):
        name = f"Utility-ppo_lag-s{seed}"
        pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "a" / "runs" / name / "pairs.parquet"),
                                      pd.read_parquet(tmp_path / "b" / "runs" / name / "pairs.parquet"))
