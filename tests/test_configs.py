"""The config files hold the paper's values, each default once, and the schemas type them."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from morality_gym.baselines.specs import LearnerSpec, ProtocolSpec, learner_spec, protocol_spec
from morality_gym.envs.registry import scenarios
from morality_gym.norms.chain import chain_file_stem, get_chain
from morality_gym.paper import table1

CONF = Path(__file__).resolve().parents[1] / "conf"


def _body(path: Path) -> dict:
    return yaml.safe_load(path.read_text())


LEARNERS = ("random", "ppo", "ppo_shaped", "ppo_lag", "cpo")
PROTOCOL_NAMES = ("paper", "corrected")


@pytest.mark.parametrize("name", LEARNERS)
def test_algo_files_state_only_what_differs_from_the_schema(name: str) -> None:
    """Each default is defined once: a value equal to a LearnerSpec field default is not repeated
    in an algo file (and the file's name is the learner's name)."""
    path = CONF / "algo" / f"{name}.yaml"
    assert path.read_text().startswith(f"# @package algo.{name}\n")
    body = _body(path)
    assert "name" not in body and "protocol" not in body
    for f in dataclasses.fields(LearnerSpec):
        if f.name in body and f.default is not dataclasses.MISSING:
            value = tuple(body[f.name]) if isinstance(f.default, tuple) else body[f.name]
            assert value != f.default, f"{path}: {f.name}: {body[f.name]!r} is the schema's default; leave it out"
    assert body.get("hparams", None) != {}
    spec = learner_spec(name)
    assert spec.name == name and spec.protocol is None


@pytest.mark.parametrize("name", PROTOCOL_NAMES)
def test_protocol_files_state_only_what_differs_from_the_schema(name: str) -> None:
    body = _body(CONF / "protocol" / f"{name}.yaml")
    for f in dataclasses.fields(ProtocolSpec):
        if f.name in body and f.default is not dataclasses.MISSING:
            value = tuple(body[f.name]) if isinstance(f.default, tuple) else body[f.name]
            assert value != f.default, f"{name}: {f.name} repeats the schema's default"
    assert protocol_spec(name).name == name


def test_paper_hyper_parameters() -> None:
    """evaluation.md 6.3: what actually ran (not the paper's appendix tables)."""
    ppo = learner_spec("ppo")
    assert (ppo.n_envs, ppo.hparams["n_steps"], ppo.hparams["batch_size"], ppo.hparams["n_epochs"]) == (8, 2048, 64, 10)
    assert ppo.reward_cost().reward_factor == 300
    shaped = learner_spec("ppo_shaped")
    assert (shaped.cost_mode, shaped.cost_scale, shaped.shape_reward, shaped.cost_reset) == ("full", 50.0, True, "per_episode")
    lag, cpo = learner_spec("ppo_lag"), learner_spec("cpo")
    assert (lag.hparams["lagrange_init"], lag.hparams["lagrange_lr"], lag.hparams["n_epochs"], lag.hparams["target_kl"]) == (0.001, 0.035, 40, 0.02)
    assert (cpo.hparams["cg_damping"], cpo.hparams["cg_max_steps"], cpo.hparams["target_kl"]) == (0.1, 15, 0.01)
    for spec in (lag, cpo):
        assert spec.hparams["n_steps"] * spec.n_envs == 2048 and spec.cost_mode == "minimal" and spec.cost_scale == 1.0
        assert spec.reward_cost().cost_reset == "never"
        assert protocol_spec("paper").apply(spec).reward_cost().cost_reset == "never"
        assert protocol_spec("corrected").apply(spec).reward_cost().cost_reset == "per_episode"
    # OmniSafe's settings (docs/protocols.md), the defaults; the corrected protocol fixes the bugs only.
    for spec in (lag, cpo):
        h = spec.hparams
        assert (h["cost_advantage_normalization"], h["anneal_lr_timing"], h["anneal_critic_lr"]) == ("center", "epoch", False)
        assert (h["weight_init"], h["adam_eps"], h["critic_grad_clip"]) == ("kaiming_uniform", 1e-8, "per_critic")
        fixed = protocol_spec("corrected").apply(spec).hparams
        assert {k: v for k, v in fixed.items() if h[k] != v} == (
            {"kl_early_stop_reduction": "mean"} if spec is lag else {"dual_solution": "exact"}
        )
    assert lag.hparams["kl_early_stop_reduction"] == "sum"
    assert (cpo.hparams["dual_solution"], cpo.hparams["line_search_max_iter"], cpo.hparams["line_search_accept"]) == ("omnisafe", 20, "omnisafe")
    assert cpo.hparams["trust_region_rescale"] is False


def test_step_budgets_as_the_reference_ran_them() -> None:
    import math

    from morality_gym.baselines.specs import training_steps

    for name, budget, expected in (("ppo", 1_000_000, 1_015_808), ("ppo", 500_000, 507_904),
                                   ("ppo_lag", 1_000_000, 999_424), ("cpo", 500_000, 499_712)):
        spec = learner_spec(name)
        steps = training_steps(spec, budget)
        rollout = spec.hparams["n_steps"] * spec.n_envs
        # SB3 keeps collecting whole rollouts while num_timesteps < total_timesteps
        assert math.ceil(steps / rollout) * rollout == expected


def test_experiment_table1_is_the_papers_table() -> None:
    body = _body(CONF / "experiment" / "table1.yaml")
    pairs = [(get_chain(c).name, s) for c, s in body["experiment"]["pairs"]]
    assert pairs == [(row.chain, row.scenario) for row in table1()]
    assert "override /algo: [random, ppo, ppo_shaped, ppo_lag, cpo]" in (CONF / "experiment" / "table1.yaml").read_text()


def test_scenario_and_chain_groups_cover_the_data() -> None:
    files = {p.read_text().splitlines()[0].split("scenario.")[1] for p in (CONF / "scenario").glob("*.yaml")}
    assert files == set(scenarios())
    paper = {}
    for row in table1():
        paper.setdefault(row.scenario, set()).add(chain_file_stem(get_chain(row.chain)))
    for path in (CONF / "scenario").glob("*.yaml"):
        name = path.read_text().splitlines()[0].split("scenario.")[1]
        assert set(_body(path)["chains"]) == paper[name], name
    for path in (CONF / "chain").glob("*.yaml"):
        assert path.read_text().startswith(f"# @package chain.{path.stem}\n")
        assert chain_file_stem(get_chain(_body(path)["ref"])) == path.stem


def test_docs_command_writes_the_env_class_docs(tmp_path: Path) -> None:
    """``python -m morality_gym docs`` writes each scenario's env class docstring (the site's
    catalogue pages are generated from the same docstrings while it builds: docs/_hooks/generate.py)."""
    from morality_gym.__main__ import main
    from morality_gym.envs.registration import env_class
    from morality_gym.envs.registry import scenarios

    assert main(["docs", "--output", str(tmp_path)]) == 0
    for name in scenarios():
        assert (tmp_path / f"{name}.md").read_text() == f"# {name}\n\n{env_class(name).__doc__}"
    assert (tmp_path / "README.md").is_file()


def test_sweep_plan_uses_the_protocol_rate() -> None:
    """The shipped ppo_lag file: the corrected protocol plans ~20x the paper protocol's time per step."""
    from hydra import compose, initialize_config_dir

    from runners.compose.search_path import CONF_DIR
    from runners.compose.sweep_config import validate

    rates = {}
    for protocol in ("paper", "corrected"):
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            cfg = compose("config", overrides=[f"protocol={protocol}", "algo=[ppo_lag]", "chain=utility",
                                               "preset=quick", "mlflow=false"])
        sweep = validate(cfg)
        rates[protocol] = sweep.algos[0].rates.steps_per_s
    assert rates["paper"] > 10 * rates["corrected"]
