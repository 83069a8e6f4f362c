"""The plan's time estimate counts what a sweep pays besides its runs (issue #22).

A smoke sweep's runs take seconds; its estimate (0m02s) was 2-8x below the wall time (17 s)
because creating the MLflow store of a new results directory and the workers' start were left out (:class:`runners.plan.estimate.SweepOverheads`).
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest

from runners.plan.estimate import SweepOverheads

REPO = Path(__file__).resolve().parents[1]


def test_the_estimate_counts_what_a_sweep_pays_besides_its_runs(tmp_path: Path) -> None:
    overheads = SweepOverheads()
    assert overheads.seconds(0, new_store=True, mlflow=True) == 0.0
    fresh = overheads.seconds(12, new_store=True, mlflow=True)
    assert fresh == pytest.approx(overheads.worker_start_s + overheads.new_store_s)
    assert overheads.seconds(12, new_store=False, mlflow=True) == pytest.approx(fresh - overheads.new_store_s)
    assert overheads.seconds(12, new_store=True, mlflow=False) == pytest.approx(overheads.worker_start_s)
    out = subprocess.run([sys.executable, "-m", "runners.sweep", "algo=random", "chain=utility", "scenario=switch_standard",
                          "variant=[HumanA]", "preset=smoke", "dry_run=true", f"results_dir={tmp_path}"],
                         cwd=REPO, check=False, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    shown = " ".join(out.stderr.split()).split("estimated time for what remains: ")[1].split()[0]  # the plan is on stderr
    minutes, seconds = shown.rstrip("s").split("m")
    assert int(minutes) * 60 + int(seconds) >= round(overheads.worker_start_s + overheads.new_store_s)


def test_the_estimate_says_what_a_busy_machine_costs() -> None:
    """Issue 36: on a shared machine the plan states the idle estimate and the one at the machine's load:
    workers share the cores with the other runnable processes (the kernel's fair share)."""
    from runners.plan.estimate import Estimate, MachineLoad, load_factor

    assert load_factor(2, MachineLoad(cores=2, load=0.0)) == 1.0  # a core each: as fitted
    assert load_factor(2, MachineLoad(cores=2, load=3.0)) == pytest.approx(2.5)  # 5 runnable on 2 cores
    assert load_factor(2, MachineLoad(cores=8, load=3.0)) == 1.0  # room to spare
    busy = Estimate.of(206.0, 2, MachineLoad(cores=2, load=3.0))
    assert busy.loaded_s == pytest.approx(515.0)
    assert busy.text() == "3m26s on an idle machine, 8m35s at this machine's load (load average 3.0 on 2 core(s))"
    assert Estimate.of(206.0, 2, MachineLoad(cores=2, load=0.0)).text() == "3m26s"  # idle: one figure
    assert Estimate.of(206.0, 2, None).text() == "3m26s"  # SLURM: this machine's load does not matter
    assert MachineLoad.now(lambda: (1.0, 2.5, 0.5)).load == 2.5  # a quiet minute of a busy hour counts as busy


def _sweep_config(tmp_path: Path, *overrides: str):
    """A validated dry-run sweep (a GPU plan needs no GPU to be priced)."""
    from tests.test_fleet_sweep import _sweep_config as compose

    return compose(tmp_path, "dry_run=true", *overrides)


def test_a_fleet_rate_on_a_device_follows_its_measured_sizes_and_sharing() -> None:
    """Issue 31 item 5: a GPU sweep is priced from measured fleet rates (planning.devices)."""
    from runners.plan.estimate import DeviceRate, device_fleet_rate, device_share

    rate = DeviceRate("card", {21: 50_000.0, 84: 200_000.0, 336: 400_000.0}, {8: 4.0})
    assert device_fleet_rate(rate, 84) == pytest.approx(200_000.0)  # measured: as measured
    assert device_fleet_rate(rate, 42) == pytest.approx(100_000.0)  # log-log: K x2 between 21 and 84 (rate ~ K)
    assert device_fleet_rate(rate, 168) == pytest.approx(200_000.0 * 2**0.5)  # half-way in log K: the geometric mean
    assert device_fleet_rate(rate, 7) == pytest.approx(50_000.0 / 3)  # below: proportional to the size
    assert device_fleet_rate(rate, 1512) == pytest.approx(400_000.0)  # above: no gain that was not measured
    assert device_share({8: 4.0}, 1) == 1.0 and device_share({8: 4.0}, 8) == pytest.approx(0.5)
    assert device_share({8: 4.0}, 16) == pytest.approx(0.25)  # held beyond 8 processes: the device is full
    assert device_share({}, 4) == pytest.approx(0.25)  # nothing measured: N processes split one's rate


def test_fleets_sharing_a_device_speed_up_as_others_finish() -> None:
    from runners.plan.estimate import makespan, shared_makespan

    # perfect sharing: as if each had its own device
    assert shared_makespan([(10.0, 1.0, {2: 2.0}), (30.0, 1.0, {2: 2.0})], 2) == pytest.approx(31.0)
    # no gain from sharing: the two trainings take turns in effect (20 s each side by side, then 20 s alone)
    assert shared_makespan([(10.0, 0.0, {}), (30.0, 0.0, {})], 2) == pytest.approx(40.0)
    # a CPU-only job never waits for the device; one worker runs jobs in turn
    assert shared_makespan([(0.0, 5.0, {}), (0.0, 7.0, {})], 2) == pytest.approx(makespan([5.0, 7.0], 2))
    assert shared_makespan([(10.0, 1.0, {}), (30.0, 2.0, {})], 1) == pytest.approx(43.0)


def test_a_gpu_sweep_is_priced_at_the_measured_device_rates(tmp_path: Path) -> None:
    """The estimate of a device=cuda plan comes from planning.devices and says on which card those
    were measured; a learner without one is named as priced at its CPU rate."""
    from morality_gym.baselines.specs import fleet_trains
    from morality_gym.baselines.targets import learner_trains
    from runners.plan.estimate import device_estimate_note, device_rates
    from runners.plan.fleets import make_jobs
    from runners.plan.runs import expand_sweep

    def note_of(sweep):  # what the sweep prints: the learners whose runs fleets train
        return device_estimate_note(sweep.device.kind, [a for a in sweep.algos
                                                   if fleet_trains(a.spec.target) and learner_trains(a.spec.target)])

    overrides = ("algo=[random,ppo,cpo]", "chain=utility", "scenario=[switch_standard,switch5]", "preset=paper")
    cpu = _sweep_config(tmp_path, *overrides)
    assert note_of(cpu) is None and device_rates(cpu.device.kind, cpu.algos) == {}
    gpu = _sweep_config(tmp_path, *overrides, "device=cuda", "launcher.workers=4")
    rates = device_rates(gpu.device.kind, gpu.algos)
    assert set(rates) == {"ppo", "cpo"} and rates["ppo"].measured_on.startswith("NVIDIA H200")
    note = note_of(gpu)
    assert note is not None and "PPO, CPO are priced at cuda rates measured on NVIDIA H200" in note and "CPU rates" not in note
    runs = expand_sweep(gpu)
    jobs = make_jobs(runs, "fleet", 336, 4, mix_scenarios=True, device_rates=rates)
    fleets = [j for j in jobs if j.engine == "fleet"]
    assert fleets and all(j.device is not None for j in fleets)
    assert all(j.device is None for j in jobs if j.engine == "single")  # Random: evaluated on the CPU
    for job in fleets:
        steps = sum(r.train_steps for r in job.runs)
        assert steps > 0 and job.est_seconds < sum(r.est_seconds for r in job.runs)  # faster than one by one on the CPU
    # a learner without device rates is priced at its CPU rate, and the note says so
    unpriced = dataclasses.replace(gpu, algos=tuple(dataclasses.replace(a, rates=dataclasses.replace(a.rates, device_rates={}))
                                                    if a.spec.name == "cpo" else a for a in gpu.algos))
    note = note_of(unpriced)
    assert "CPO: no cuda rates are measured" in note and "not a GPU estimate" in note


def test_a_compiled_gpu_sweep_is_priced_at_the_measured_compiled_gain(tmp_path: Path) -> None:
    """fleet_update=compiled on cuda: fleets are priced at the eager rates times the gain measured
    with the compiled update (and its sharing of the card); a learner with no measured gain keeps
    its eager rates, and the note says which is which."""
    from morality_gym.baselines.specs import fleet_trains
    from morality_gym.baselines.targets import learner_trains
    from runners.plan.estimate import device_estimate_note, device_rates
    from runners.plan.fleets import make_jobs
    from runners.plan.runs import expand_sweep

    overrides = ("algo=[ppo,ppo_lag,cpo]", "chain=utility", "scenario=[switch_standard,switch5]", "preset=paper",
                 "device=cuda", "launcher.workers=4")
    eager = _sweep_config(tmp_path, *overrides)
    compiled = _sweep_config(tmp_path, *overrides, "fleet_update=compiled")
    plain, fast = device_rates("cuda", eager.algos), device_rates("cuda", compiled.algos, "compiled")
    for name, gain, shared in (("ppo", 1.297, {8: 4.28}), ("cpo", 1.496, {8: 2.82})):
        assert fast[name].fleet_steps_per_s == pytest.approx({k: v * gain for k, v in plain[name].fleet_steps_per_s.items()})
        assert dict(fast[name].processes) == shared
    assert fast["ppo_lag"] == plain["ppo_lag"]  # nothing measured compiled: eager's rates
    fleet_trained = [a for a in compiled.algos if fleet_trains(a.spec.target) and learner_trains(a.spec.target)]
    note = device_estimate_note("cuda", fleet_trained, "compiled")
    assert "times the gain measured for PPO (1.30x at K=336), CPO (1.50x at K=336)" in note, note
    assert "PPO Lag: no compiled gain is measured" in note, note
    assert "compiled" not in device_estimate_note("cuda", fleet_trained)  # an eager sweep's note says nothing of it

    runs = expand_sweep(compiled)

    def fleet_seconds(rates):
        jobs = make_jobs(runs, "fleet", 336, 4, mix_scenarios=True, device_rates=rates)
        totals: dict[str, float] = {}
        for job in (j for j in jobs if j.engine == "fleet"):
            name = job.runs[0].config.algo.name
            totals[name] = totals.get(name, 0.0) + job.est_seconds
        return totals

    before, after = fleet_seconds(plain), fleet_seconds(fast)
    assert after["ppo"] < before["ppo"] and after["cpo"] < before["cpo"] and after["ppo_lag"] == before["ppo_lag"]


def test_a_bad_compiled_gain_is_refused_naming_its_key(tmp_path: Path) -> None:
    from runners.compose.sweep_config import ConfigError

    with pytest.raises(ConfigError, match=r"planning\.devices\.cuda\.compiled_gain needs fleet sizes >= 1 with a compiled/eager ratio > 0"):
        _sweep_config(tmp_path, "algo=ppo", "chain=utility", "scenario=[switch5]", "algo.ppo.planning.devices.cuda.compiled_gain={336: 0}")


def test_bad_device_rates_are_refused_with_where_they_are(tmp_path: Path) -> None:
    from runners.compose.sweep_config import ConfigError

    with pytest.raises(ConfigError, match=r"algo=ppo .*planning\.devices\.cuda\.fleet_steps_per_s needs at least one fleet size"):
        _sweep_config(tmp_path, "algo=ppo", "chain=utility", "scenario=[switch5]", "algo.ppo.planning.devices.cuda.fleet_steps_per_s={21: 0}")
    # the error names the command-line override, not only the file it was laid over
    with pytest.raises(ConfigError, match=r"ppo\.yaml\) with algo\.ppo\.planning\.devices\.cuda\.fleet_steps_per_s=\{21: 0\}: "):
        _sweep_config(tmp_path, "algo=ppo", "chain=utility", "scenario=[switch5]", "algo.ppo.planning.devices.cuda.fleet_steps_per_s={21: 0}")


def test_a_misspelt_device_rate_key_is_refused_with_the_close_match(tmp_path: Path) -> None:
    """A typo used to be ignored, and the device then priced at rates nobody measured."""
    from runners.compose.sweep_config import ConfigError

    with pytest.raises(ConfigError, match=r"planning\.devices\.cuda: unknown key 'fleet_step_per_s' \(did you mean 'fleet_steps_per_s'\?\)"):
        _sweep_config(tmp_path, "algo=ppo", "chain=utility", "scenario=[switch5]", "device=cuda",
                      "+algo.ppo.planning.devices.cuda.fleet_step_per_s={21: 5.0}")


def test_plan_estimate_scales_only_the_update_share_with_epochs() -> None:
    """The plan's estimate: a preset that trains with fewer epochs saves only the gradient part.

    Fitted to measured runs (conf/algo/*.yaml planning); a whole-rate scaling made the smoke plan
    2.7x too long.
    """
    from morality_gym.baselines.specs import learner_spec
    from runners.plan.estimate import PlanningError, planning_rate

    file_values = {"hparams": {"n_epochs": 10}}
    same = learner_spec("ppo")
    fewer = same.with_overrides({"hparams": {"n_epochs": 2}})
    planning = {"steps_per_s": 3000.0, "update_share": 0.5, "overhead_s": 0.5}
    assert planning_rate("w", planning, file_values, same) == pytest.approx((3000.0, 0.5, 1.0))
    rate, _, _ = planning_rate("w", planning, file_values, fewer)
    assert rate == pytest.approx(3000.0 / (0.5 + 0.5 * 0.2))  # 5000 steps/s, not 15000
    with pytest.raises(PlanningError, match="update_share"):
        planning_rate("w", {**planning, "update_share": 1.5}, file_values, same)


def test_plan_estimate_per_protocol() -> None:
    """A protocol that changes a learner's speed (PPO-Lag: one pass vs up to 40) has its own rate;
    other protocols keep the file's values, and a malformed block names the key."""
    from morality_gym.baselines.specs import learner_spec
    from runners.plan.estimate import PlanningError, planning_rate

    spec = learner_spec("ppo_lag")
    file_values = {"hparams": {"n_epochs": 40}}
    planning = {"steps_per_s": 10000.0, "update_share": 0.25, "overhead_s": 0.5,
                "protocols": {"corrected": {"steps_per_s": 500.0, "overhead_s": 1.0}}}
    assert planning_rate("w", planning, file_values, spec, "paper") == pytest.approx((10000.0, 0.5, 1.0))
    assert planning_rate("w", planning, file_values, spec, "corrected") == pytest.approx((500.0, 1.0, 1.0))
    assert planning_rate("w", planning, file_values, spec) == pytest.approx((10000.0, 0.5, 1.0))
    with pytest.raises(PlanningError, match="planning.protocols.corrected must be a mapping"):
        planning_rate("w", {**planning, "protocols": {"corrected": 5}}, file_values, spec, "corrected")
    with pytest.raises(PlanningError, match="unknown planning key"):
        planning_rate("w", {**planning, "protocols": {"corrected": {"speed": 1}}}, file_values, spec, "corrected")
