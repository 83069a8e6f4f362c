"""The paper's entry point: ``make(env_id, chain)`` returns the environment and its bound chain."""

from __future__ import annotations

from typing import Any

from morality_gym.constants import BETA
from morality_gym.envs.registration import env_class
from morality_gym.envs.registry import parse_env_id
from morality_gym.envs.trolley import TrolleyEnv
from morality_gym.norms.chain import MoralityChain
from morality_gym.norms.metric import BoundChain, bind_chain


def make(
    env_id: str,
    chain: str | MoralityChain,
    *,
    beta: float | str = BETA,
    **env_kwargs: Any,
) -> tuple[TrolleyEnv, BoundChain]:
    """Create an env and the morality chain bound to it, as the paper's ``make`` does.

    ``beta`` defaults to 0.1 as in every run of the paper (``"derived"`` gives the reference's
    per-variant default). ``env_kwargs`` go to :class:`~morality_gym.envs.trolley.TrolleyEnv`
    (``max_steps``, ``obs_type``, ``render_mode``, ...). Unlike the reference, the env is not
    reset yet: call ``env.reset()`` first, as Gymnasium expects.
    """
    scenario, variant = parse_env_id(env_id)
    env = env_class(scenario.name)(scenario.env_id(variant), **env_kwargs)
    return env, bind_chain(chain, env.env_id, beta)
