"""Bring your own learner, scenario and chain, from outside the repo, with no edit to the library.

Real subprocess sweeps (``dry_run`` where planning is what is tested), real Parquet, real model
files, a real leaderboard build. Each user file is written to a temporary directory outside the
repo and reached only through the documented routes: ``--config-dir DIR`` / ``--config-dir=DIR`` /
``hydra.searchpath=[file://DIR]``, an installed plugin's entry point, ``MORALITY_GYM_SCENARIOS``
and a chain file's path.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from morality_gym.results.manifest import read_manifests

REPO = Path(__file__).resolve().parents[1]

#: A user's own algorithm: SB3's A2C with one extra constructor argument, in a plain file.
USER_MODULE = '''
from stable_baselines3 import A2C


class PatientA2C(A2C):
    """A2C that waits ``patience`` updates before it starts to anneal nothing (a stand-in for a
    user's change); takes every A2C argument through **kwargs."""

    def __init__(self, *args, patience: int = 0, **kwargs):
        self.patience = patience
        super().__init__(*args, **kwargs)
'''

USER_ALGO = """# @package algo.patient
_target_: patient_algos.PatientA2C
label: Patient A2C
n_envs: 2
hparams:
  n_steps: 8
  patience: 3
planning: {steps_per_s: 2000.0, update_share: 0.5, overhead_s: 0.5}
"""


def run(args: list[str], cwd: Path, env: dict[str, str] | None = None, timeout: float = 900) -> subprocess.CompletedProcess:
    full = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
    full.pop("MLFLOW_TRACKING_URI", None)
    return subprocess.run([sys.executable, *args], cwd=cwd, check=False, capture_output=True, text=True, timeout=timeout, env=full)


def user_dir(tmp_path: Path) -> Path:
    conf = tmp_path / "my_conf"
    (conf / "algo").mkdir(parents=True)
    (conf / "algo" / "patient.yaml").write_text(USER_ALGO)
    (conf / "patient_algos.py").write_text(USER_MODULE)
    return conf


def planned(results: Path) -> list[dict]:
    """The runs planned in ``results`` and by a dry run's ``plan_file`` beside it (see :func:`plan_of`)."""
    plan = results.parent / f"{results.name}.plan.json"
    plans = [json.loads(plan.read_text())] if plan.is_file() else []
    return [r for m in [*read_manifests(results), *plans] for r in m["runs"]]


def plan_of(results: Path) -> str:
    """A dry run writes nothing into its results directory (issue 36): its plan goes to this file."""
    return f"plan_file={results.parent / f'{results.name}.plan.json'}"


SMALL = ["chain=utility", "scenario=switch_standard", "variant=[HumanA]", "preset=smoke", "mlflow=false", "gif=false"]


@pytest.mark.parametrize("form", ["space", "equals", "searchpath"])
def test_user_algorithm_found_in_every_search_path_form(tmp_path: Path, form: str) -> None:
    conf = user_dir(tmp_path)
    where = {"space": ["--config-dir", str(conf)], "equals": [f"--config-dir={conf}"],
             "searchpath": [f"hydra.searchpath=[file://{conf}]"]}[form]
    out = run(["-m", "runners.sweep", *where, "algo=[patient,random]", *SMALL, "dry_run=true", f"results_dir={tmp_path / 'r'}",
               plan_of(tmp_path / "r")], cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    labels = {r["learner"] for r in planned(tmp_path / "r")}
    assert labels == {"Patient A2C", "Random"}


def test_user_algorithm_typos_get_did_you_mean(tmp_path: Path) -> None:
    conf = user_dir(tmp_path)
    out = run(["-m", "runners.sweep", "--config-dir", str(conf), "algo=patient", "algo.patient.hparams.patienc=2", *SMALL,
               "dry_run=true", f"results_dir={tmp_path / 'r'}"], cwd=tmp_path)
    assert out.returncode == 2 and "did you mean 'patience'" in out.stderr, out.stderr
    (conf / "algo" / "patient.yaml").write_text(USER_ALGO.replace("n_steps: 8", "n_step: 8"))
    out = run(["-m", "runners.sweep", "--config-dir", str(conf), "algo=patient", *SMALL, "dry_run=true",
               f"results_dir={tmp_path / 'r'}"], cwd=tmp_path)
    assert out.returncode == 2 and "hparams.n_step" in out.stderr and "did you mean 'n_steps'" in out.stderr, out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    (conf / "algo" / "patient.yaml").write_text(USER_ALGO.replace("patient_algos.PatientA2C", "patient_algos.PatientA3C"))
    out = run(["-m", "runners.sweep", "--config-dir", str(conf), "algo=patient", *SMALL, "dry_run=true",
               f"results_dir={tmp_path / 'r'}"], cwd=tmp_path)
    assert out.returncode == 2 and "patient_algos.PatientA3C" in out.stderr, out.stderr
    out = run(["-m", "runners.sweep", "--config-dir", str(tmp_path / "nowhere"), "algo=random", *SMALL, "dry_run=true"], cwd=tmp_path)
    assert out.returncode == 2 and "nowhere" in out.stderr and "not a directory" in out.stderr


def test_installed_plugin_entry_point(tmp_path: Path) -> None:
    """A package that declares ``morality_gym.algos`` entry points contributes its config root."""
    site = tmp_path / "site"
    package = site / "moral_plugin" / "conf" / "algo"
    package.mkdir(parents=True)
    (site / "moral_plugin" / "__init__.py").write_text("")
    (site / "moral_plugin" / "conf" / "__init__.py").write_text("")
    (package / "plugged.yaml").write_text("# @package algo.plugged\n_target_: stable_baselines3.A2C\nlabel: Plugged A2C\n")
    info = site / "moral_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: moral-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[morality_gym.algos]\nmoral_plugin = moral_plugin.conf\n")
    out = run(["-m", "runners.sweep", "algo=plugged", *SMALL, "dry_run=true", f"results_dir={tmp_path / 'r'}", plan_of(tmp_path / "r")],
              cwd=tmp_path,
              env={"PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])})
    assert out.returncode == 0, out.stderr
    assert {r["learner"] for r in planned(tmp_path / "r")} == {"Plugged A2C"}


def test_user_scenario_and_chain_file_need_no_config_file(tmp_path: Path) -> None:
    scenarios = tmp_path / "scenarios"
    scenarios.mkdir()
    text = (REPO / "morality_gym" / "data" / "scenarios" / "switch_standard.yaml").read_text()
    (scenarios / "my_switch.yaml").write_text(text.replace("name: SwitchStandard", "name: MySwitch", 1))
    (tmp_path / "animals.yaml").write_text("name: Animals\nnorms: [n_animal_harm]\n")
    env = {"MORALITY_GYM_SCENARIOS": str(scenarios)}
    base = ["-m", "runners.sweep", "algo=random", "preset=smoke", "dry_run=true", "mlflow=false"]
    # The variant filter comes before the coverage check: Animals scores only the animal variants.
    for spelling in ("MySwitch", "my_switch", "[MySwitch]"):
        results = tmp_path / f"r-{spelling.strip('[]')}"
        out = run([*base, f"scenario={spelling}", "chain=animals.yaml", "variant=[AnimalA,AnimalB]", f"results_dir={results}",
                   plan_of(results)], cwd=tmp_path, env=env)
        assert out.returncode == 0, out.stderr
        assert {(r["env_id"], r["chain"]) for r in planned(results)} == {("MySwitch-AnimalA-v1", "Animals"), ("MySwitch-AnimalB-v1", "Animals")}
    out = run([*base, "scenario=MySwitch", "chain=animals.yaml", f"results_dir={tmp_path / 'all'}"], cwd=tmp_path, env=env)
    assert out.returncode == 2 and "cannot score MySwitch-HumanA-v1" in out.stderr and "variant=[" in out.stderr
    # Built-in scenarios and chains in either spelling, chains by name and abbreviation too.
    out = run([*base, "scenario=[SwitchStandard,push_or_switch]", "chain=DP", "variant=[HumanA,Human]",
               f"results_dir={tmp_path / 'b'}", plan_of(tmp_path / "b")], cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert {(r["scenario"], r["chain"]) for r in planned(tmp_path / "b")} == {("SwitchStandard", "DualProcess"), ("PushOrSwitch", "DualProcess")}
    out = run([*base, "scenario=SwitchStandrd", f"results_dir={tmp_path / 'c'}"], cwd=tmp_path)
    assert out.returncode == 2 and "did you mean 'switch_standard'" in out.stderr


def test_cli_accepts_both_scenario_spellings(tmp_path: Path) -> None:
    outputs = []
    for spelling in ("SwitchStandard", "switch_standard"):
        out = run(["-m", "morality_gym", "eval", "--policy", "random", "--chain", "Utility", "--scenario", spelling,
                   "--variant", "HumanA", "--exact", "--json"], cwd=tmp_path)
        assert out.returncode == 0, out.stderr
        outputs.append(json.loads(out.stdout))
    assert outputs[0] == outputs[1] and outputs[0]["scenario"] == "SwitchStandard"
    out = run(["-m", "morality_gym", "list", "envs", "--scenario", "push_or_switch"], cwd=tmp_path)
    assert out.returncode == 0 and "PushOrSwitch-Human-v1" in out.stdout


@pytest.mark.slow
def test_user_class_from_a_plain_file_trains_in_workers_and_loads_elsewhere(tmp_path: Path) -> None:
    """The pool's worker processes import the user's module, and a fresh process loads the model."""
    conf = user_dir(tmp_path)
    results = tmp_path / "r"
    out = run(["-m", "runners.sweep", "--config-dir", str(conf), "algo=patient", *SMALL, f"results_dir={results}",
               "preset.budget=64"], cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    (model_json,) = list(results.glob("runs/*/model.json"))
    meta = json.loads(model_json.read_text())
    assert meta["target"] == "patient_algos.PatientA2C" and meta["import_root"] == str(conf.resolve())
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = run(["-m", "morality_gym", "eval", "--policy", str(model_json.with_suffix(".zip")), "--chain", "Utility",
               "--scenario", "switch_standard", "--variant", "HumanA", "--exact", "--json"], cwd=elsewhere)
    assert out.returncode == 0, out.stderr
    assert 0.0 <= json.loads(out.stdout)["mean_metric"] <= 1.0


@pytest.mark.slow
def test_a2c_example_end_to_end_from_outside_the_repo(tmp_path: Path) -> None:
    """examples/a2c as its README runs it: sweep at the smoke preset, leaderboard, evaluate the model."""
    work = tmp_path / "outside"
    work.mkdir()
    shutil.copytree(REPO / "examples" / "a2c", work / "a2c")
    out = run(["-m", "runners.sweep", "--config-dir", "a2c", "algo=[random,a2c]", "chain=utility", "scenario=switch_standard",
               "variant=[HumanA]", "preset=smoke", "results_dir=results"], cwd=work)
    assert out.returncode == 0, out.stdout + out.stderr
    out = run(["-m", "leaderboard.build", "--results", "results", "--site", "site"], cwd=work)
    assert out.returncode == 0, out.stdout + out.stderr
    import pandas as pd

    table = pd.read_csv(work / "results" / "table1.csv")
    a2c = table[table["learner"] == "A2C"]
    assert len(a2c) == 1 and a2c["n_runs"].iloc[0] == 1 and 0.0 <= a2c["mean"].iloc[0] <= 1.0
    assert 'data-learner="A2C"' in (work / "site" / "index.html").read_text()  # the leaderboard's A2C row
    models = [p for p in (work / "results" / "runs").glob("*/model.json") if json.loads(p.read_text())["label"] == "A2C"]
    assert len(models) == 1 and json.loads(models[0].read_text())["target"] == "stable_baselines3.A2C"
    out = run(["-m", "morality_gym", "eval", "--policy", str(models[0].with_suffix(".zip")), "--chain", "Utility",
               "--scenario", "SwitchStandard", "--variant", "HumanA", "--episodes", "10", "--seed", "41", "--json"], cwd=work)
    assert out.returncode == 0, out.stderr
    assert "SwitchStandard-HumanA-v1" in json.loads(out.stdout)["envs"]


def test_protocols_change_the_baselines_they_name_and_leave_user_learners_alone() -> None:
    from morality_gym.baselines.specs import LearnerSpec, learner_spec, protocol_spec

    user = LearnerSpec.from_mapping({"_target_": "morality_gym.baselines.safe.PPOLag", "cost_reset": "per_episode",
                                     "hparams": {"kl_early_stop_reduction": "mean"}}, "my_lag")
    assert protocol_spec("paper").apply(user).hparams == user.hparams and protocol_spec("paper").apply(user).cost_reset == "per_episode"
    builtin = protocol_spec("corrected").apply(learner_spec("ppo_lag"))
    assert builtin.hparams["kl_early_stop_reduction"] == "mean" and builtin.cost_reset == "per_episode"
    assert user.label == "my_lag" and user.n_envs == 8  # left-out fields take the spec's defaults


def test_hparams_of_any_sb3_class_are_checked_against_its_constructor(tmp_path: Path) -> None:
    from morality_gym.baselines.hparams import HyperParameterError, accepted_hparams, validate_hparams

    assert {"n_steps", "cg_damping", "target_kl"} <= set(accepted_hparams("sb3_contrib.TRPO"))
    with pytest.raises(HyperParameterError, match="did you mean 'cg_damping'"):
        validate_hparams("trpo", "sb3_contrib.TRPO", {"cg_dampin": 0.1})
    with pytest.raises(HyperParameterError, match=r"hparams.gamma=2: must be >= 0 and <= 1"):
        validate_hparams("a2c", "stable_baselines3.A2C", {"gamma": 2})
    with pytest.raises(HyperParameterError, match="cannot import 'stable_baselines3.A3C'"):
        validate_hparams("a3c", "stable_baselines3.A3C", {})
    (tmp_path / "kw_algos.py").write_text(USER_MODULE)
    sys.path.insert(0, str(tmp_path))
    try:
        accepted = accepted_hparams("kw_algos.PatientA2C")  # its own argument and, through **kwargs, A2C's
        assert {"patience", "n_steps", "use_rms_prop"} <= set(accepted) and "seed" not in accepted
    finally:
        sys.path.remove(str(tmp_path))


def test_legacy_sidecar_and_unimportable_target(tmp_path: Path) -> None:
    from morality_gym.baselines.io import ModelError, load_model

    (tmp_path / "old.json").write_text(json.dumps({"implementation": "random", "env_id": "SwitchStandard-HumanA-v1"}))
    assert load_model(tmp_path / "old.zip") == "random"
    (tmp_path / "gone.json").write_text(json.dumps({"target": "nowhere_pkg.Algo", "env_id": "SwitchStandard-HumanA-v1"}))
    with pytest.raises(ModelError, match="cannot import 'nowhere_pkg.Algo'"):
        load_model(tmp_path / "gone.zip")


#: A user's PPO clone with the paper's 8 x 2048 rollout: at the smoke preset's budget of 2,048 steps
#: it would train one 16,384-step rollout (8x the budget) unless the preset caps it.
BIG_ROLLOUT = """# @package algo.big_ppo
_target_: stable_baselines3.PPO
label: Big PPO
hparams: {n_steps: 2048, batch_size: 64}
"""


def _sweep_config(conf: Path, results: Path, *overrides: str):
    """The validated sweep as ``runners.sweep`` builds it, through the compose API with a user dir."""
    from hydra import compose, initialize_config_dir

    from runners.compose.search_path import CONF_DIR
    from runners.compose.sweep_config import validate

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=[f"hydra.searchpath=[file://{conf}]", "chain=utility", "scenario=[switch_standard]",
                                           "mlflow=false", f"results_dir={results}", *overrides], return_hydra_config=True)
    return validate(cfg)


def test_a_preset_caps_the_rollout_of_every_learner_and_the_plan_warns(tmp_path: Path) -> None:
    conf = tmp_path / "my_conf"
    (conf / "algo").mkdir(parents=True)
    (conf / "algo" / "big_ppo.yaml").write_text(BIG_ROLLOUT)
    smoke = _sweep_config(conf, tmp_path / "r", "algo=[big_ppo,ppo]", "preset=smoke")
    by_name = {a.spec.name: a.spec for a in smoke.algos}
    assert by_name["big_ppo"].hparams["n_steps"] == 128 and by_name["ppo"].hparams["n_steps"] == 128  # 1024 / 8 envs
    assert by_name["big_ppo"].hparams["batch_size"] == 64 and smoke.warnings == ()
    # The command line still wins over the cap, and a rollout longer than the budget is a warning.
    uncapped = _sweep_config(conf, tmp_path / "r", "algo=[big_ppo]", "preset=smoke", "preset.rollout_cap=null")
    assert uncapped.algos[0].spec.hparams["n_steps"] == 2048
    (warning,) = uncapped.warnings
    assert "algo=big_ppo" in warning and "2048 x 8 = 16384 steps" in warning and "budget of 2048" in warning
    assert "preset.rollout_cap=2048" in warning
    out = run(["-m", "runners.sweep", "--config-dir", str(conf), "algo=big_ppo", *SMALL, "preset.rollout_cap=null",
               "dry_run=true", f"results_dir={tmp_path / 'r2'}"], cwd=tmp_path)
    assert out.returncode == 0 and "warning: algo=big_ppo: one rollout is" in out.stderr, out.stderr


def test_a_misspelt_key_or_wrong_type_fails_at_composition_in_one_line(tmp_path: Path) -> None:
    """The typed schemas refuse a bad key or value while Hydra composes: the line names the key, the
    file or the command line, and the closest valid key; a user's file is checked like a built-in."""
    from runners.compose.command_line import compose_check

    conf = tmp_path / "my_conf"
    (conf / "algo").mkdir(parents=True)
    (conf / "algo" / "typo.yaml").write_text("# @package algo.typo\n_target_: stable_baselines3.A2C\nn_env: 2\n")
    (conf / "algo" / "nopkg.yaml").write_text("_target_: stable_baselines3.A2C\nlabel: No package line\n")
    base = ["--config-dir", str(conf), "chain=utility", "scenario=[switch_standard]"]
    cases = {
        "algo=typo": ["algo.typo.n_env", f"algo=typo, {conf / 'algo' / 'typo.yaml'}", "did you mean 'n_envs'?"],
        "algo=nopkg": ["missing its '# @package algo.<file name>' first line"],
        "preset.budgte=5": ["preset.budgte (command line): unknown key 'budgte' (did you mean 'budget'?)"],
        "launcher.workerz=2": ["launcher.workerz (command line)", "did you mean 'workers'?"],
        "max_steps=many": ["max_steps (command line): value 'many'", "could not be converted to Integer"],
        "dry_rn=true": ["did you mean 'dry_run'?"],
    }
    for override, fragments in cases.items():
        message = compose_check([*base, override])
        assert message is not None and "\n" not in message, override
        for fragment in fragments:
            assert fragment in message, (override, message)
    assert compose_check([*base, "algo=[typo]", "algo.typo.n_env=3"]) is not None
    assert compose_check([*base, "algo=[random,ppo]", "launcher=slurm", "launcher.partition=gpu"]) is None
