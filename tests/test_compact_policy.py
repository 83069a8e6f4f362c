"""A model saved by a track fleet (``obs_type: compact``) acts in a built-in env through ``load_policy``
as the fleet's own policy does (issue 44, small leftover (a)): before, ``eval`` fed it the env's flat
observation and refused it for its width."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from morality_gym.baselines.learners import make_learner
from morality_gym.baselines.policy_ref import load_policy
from morality_gym.baselines.specs import learner_spec
from morality_gym.evaluation.exact import exact_evaluate, state_policy
from morality_gym.evaluation.montecarlo import evaluate
from morality_gym.evaluation.policies import PolicyAdapter
from morality_gym.generalisation.scoring import policy_table
from morality_gym.norms.metric import bind_chain

ENV, OTHER = "SwitchStandard-HumanA-v1", "PushStandard-HumanA-v1"


@pytest.fixture(scope="module")
def saved(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    """An (untrained) PPO model on the compact observation, saved as a fleet saves its runs' models."""
    import torch

    torch.manual_seed(0)
    learner = make_learner(learner_spec("ppo"), bind_chain("Utility", OTHER), seed=3, obs_type="compact")
    path = learner.save(tmp_path_factory.mktemp("fleet") / "model.zip")
    return path, learner.model


def test_a_compact_model_acts_in_a_builtin_env_as_the_fleets_own_policy(saved: tuple[Path, object]) -> None:
    path, model = saved
    loaded = load_policy(str(path), [ENV], allow_other_env=True)
    assert loaded.kind == "model"
    # the track's scoring asks the fleet's model on every state's compact observation: the same table
    np.testing.assert_allclose(state_policy(loaded.policy, ENV), policy_table(model, ENV), rtol=0, atol=1e-6)
    exact = exact_evaluate(loaded.policy, ENV, "Utility")
    assert exact.exact and 0.0 <= exact.metric <= 1.0
    mc = evaluate(loaded.policy, ENV, "Utility", n_episodes=4, seed=0)
    assert mc.n_episodes == 4


def test_the_model_alone_cannot_read_the_flat_observation(saved: tuple[Path, object]) -> None:
    """What the wrapper is for: the flat observation is not the model's input."""
    _, model = saved
    from morality_gym.envs.registry import state_graph

    flat = state_graph(ENV).tables().obs
    assert flat.shape[1] != model.observation_space.shape[0]
    with pytest.raises(ValueError):
        PolicyAdapter(model).probabilities(np.asarray(flat[:2], dtype=np.float32))


def test_an_observation_of_another_env_is_refused_by_name(saved: tuple[Path, object]) -> None:
    path, _ = saved
    loaded = load_policy(str(path), [ENV], allow_other_env=True)
    from morality_gym.envs.registry import state_graph

    other = np.asarray(state_graph("Switch5-Human-v1").tables().obs[0])
    with pytest.raises(ValueError, match=f"none of the envs this model was loaded for \\({ENV}\\)"):
        loaded.policy(other)
