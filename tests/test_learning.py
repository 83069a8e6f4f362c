"""Learners on MoralityGym itself (fixed seeds, well under a minute each)."""

from __future__ import annotations

import pytest

import morality_gym
from morality_gym.baselines.learners import build_learner
from morality_gym.baselines.specs import learner_spec
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.oracle import oracle


@pytest.mark.slow
def test_ppo_shaped_beats_random_on_switch_standard(capsys: pytest.CaptureFixture[str]) -> None:
    env_id = "SwitchStandard-HumanA-v1"
    bound = morality_gym.bind_chain("Utility", env_id)
    random_metric = exact_evaluate("random", env_id, bound).metric
    best = oracle(env_id, bound).best.metric
    learner = build_learner(learner_spec("ppo_shaped", {"hparams": {"n_steps": 256}}), bound, "paper", seed=41)
    learner.learn(30_000, eval_every=0)
    learned = learner.exact_evaluation().metric
    final = learner.final_evaluation(100)
    with capsys.disabled():
        print(f"\nPPO-Shaped on {env_id} (Utility, 30k steps): exact metric {learned:.3f}, Monte Carlo {final.metric:.3f}; "
              f"Random (exact) {random_metric:.3f}; oracle best {best:.3f} (gap {best - learned:.3f})")
    assert random_metric == pytest.approx(0.2685, abs=1e-3)  # exact, computed independently of sampling
    assert learned > random_metric + 0.4
    assert learned <= best + 1e-9


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ppo", "ppo_lag", "cpo"])
def test_every_learner_trains_evaluates_saves_and_loads(name: str, tmp_path) -> None:
    from morality_gym.baselines.io import load_model
    from morality_gym.evaluation.policies import PolicyAdapter

    bound = morality_gym.bind_chain("DualProcess", "PushOrSwitch-Human-v1")
    spec = learner_spec(name, {"hparams": {"n_steps": 64}})
    learner = build_learner(spec, bound, "corrected", seed=3)
    rows = []
    learner.learn(1024, eval_every=512, eval_episodes=4, on_eval=rows.append)
    assert [r["step"] for r in rows] == [0, 512, 1024] and 0 <= rows[-1]["exact_metric"] <= 1
    path = learner.save(tmp_path / "model")
    loaded = load_model(path)
    assert type(loaded) is type(learner.model)
    # The constrained learners restart their envs every epoch as OmniSafe did (spec Q20); it survives save/load.
    assert getattr(loaded, "reset_envs_each_rollout", False) is (name != "ppo")
    obs = learner.model.observation_space.sample()[None]
    assert PolicyAdapter(loaded).probabilities(obs) == pytest.approx(PolicyAdapter(learner.model).probabilities(obs))
    assert exact_evaluate(loaded, bound.env_id, bound).metric == pytest.approx(learner.exact_evaluation().metric)


@pytest.mark.slow
def test_cli_evaluates_a_saved_model(tmp_path) -> None:
    import json
    import subprocess
    import sys

    bound = morality_gym.bind_chain("Utility", "SwitchStandard-HumanA-v1")
    learner = build_learner(learner_spec("cpo", {"hparams": {"n_steps": 64}}), bound, "paper", seed=5)
    learner.learn(512, eval_every=0)
    path = learner.save(tmp_path / "model")
    out = subprocess.run(
        [sys.executable, "-m", "morality_gym", "eval", "--policy", str(path), "--chain", "Utility",
         "--scenario", "SwitchStandard", "--variant", "HumanA", "--exact", "--json"],
        check=False, capture_output=True, text=True, timeout=300,
    )
    assert out.returncode == 0, out.stderr
    metric = json.loads(out.stdout)["envs"]["SwitchStandard-HumanA-v1"]["metric"]
    assert metric == pytest.approx(learner.exact_evaluation().metric)
    missing = subprocess.run([sys.executable, "-m", "morality_gym", "eval", "--policy", str(tmp_path / "nope.zip"),
                              "--chain", "Utility", "--scenario", "SwitchStandard"], check=False, capture_output=True, text=True, timeout=300)
    assert missing.returncode == 2 and "does not exist" in missing.stderr


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ppo", "cpo"])
def test_learn_time_evaluations_do_not_change_training(name: str) -> None:
    """Evaluating during training draws only from its own generator: the trained weights are identical."""
    import torch

    bound = morality_gym.bind_chain("DualProcess", "PushOrSwitch-Human-v1")
    spec = learner_spec(name, {"hparams": {"n_steps": 64}})
    weights = []
    for eval_every in (0, 256):
        learner = build_learner(spec, bound, "paper", seed=11)
        learner.learn(1536, eval_every=eval_every, eval_episodes=5)
        weights.append([p.detach().clone() for p in learner.model.policy.parameters()])
    assert all(torch.equal(a, b) for a, b in zip(*weights))


def test_a_budget_of_zero_evaluates_the_untrained_policy_once() -> None:
    """No training, one learn-time evaluation at step 0, handed to learn_evals and on_eval alike
    (the callback used to reach for an SB3 model that is only attached by model.learn)."""
    bound = morality_gym.bind_chain("Utility", "SwitchStandard-HumanA-v1")
    learner = build_learner(learner_spec("ppo", {"hparams": {"n_steps": 64}}), bound, "paper", seed=3)
    rows: list[dict] = []
    assert learner.learn(0, eval_episodes=2, on_eval=rows.append) == 0
    assert rows == learner.learn_evals and [r["step"] for r in rows] == [0]
    assert 0.0 <= rows[0]["exact_metric"] <= 1.0


@pytest.mark.parametrize("algo", ["ppo", "ppo_lag", "cpo"])
def test_training_leaves_no_sb3_folder_in_the_temp_dir(algo: str, tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    # SB3 configures a logger that creates $TMPDIR/SB3-<date> on every learn() unless one is set
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    bound = morality_gym.bind_chain("Utility", "SwitchStandard-HumanA-v1")
    learner = build_learner(learner_spec(algo, {"hparams": {"n_steps": 64, "batch_size": 64}}), bound, "paper", seed=1)
    assert learner.learn(budget=512, eval_every=10**9) > 0
    assert not list(tmp_path.glob("SB3-*"))
    assert learner.model.logger.name_to_value is not None  # records still work, they are written nowhere
