"""Small, stateless maths shared by the constrained learners.

Kept apart from the algorithms so that each formula lives in exactly one place and can be tested
on its own (the GAE recursion here is the one used for *both* the reward and the cost stream).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import torch as th

AdvantageNormalization = Literal["standardize", "center", "none"]

#: Guards divisions by a standard deviation that can be (close to) zero, e.g. a cost stream
#: that is zero everywhere in a rollout.
STD_EPS = 1e-8


def gae(
    rewards: np.ndarray,
    values: np.ndarray,
    episode_starts: np.ndarray,
    last_values: np.ndarray,
    last_dones: np.ndarray,
    gamma: float,
    gae_lambda: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Generalised advantage estimation over a ``(n_steps, n_envs)`` rollout.

    With ``m_{t+1} = 1 - done_{t}`` (0 when step t ended its episode)::

        delta_t = r_t + gamma * m_{t+1} * V(s_{t+1}) - V(s_t)
        A_t     = delta_t + gamma * lambda * m_{t+1} * A_{t+1}
        R_t     = A_t + V(s_t)                       (the TD(lambda) return, the critic's target)

    ``episode_starts[t]`` is SB3's flag "s_t is the first state of an episode", i.e. the step
    before it was terminal; for the last step the flag comes from ``last_dones``. Truncated
    episodes are handled *before* this function by adding ``gamma * V(terminal_obs)`` to the last
    reward, exactly like SB3 does, so that ``done`` can always cut the bootstrap here.

    :return: ``(advantages, returns)``, both float32 of the rollout's shape.
    """
    n_steps = rewards.shape[0]
    advantages = np.zeros_like(rewards, dtype=np.float32)
    running = np.zeros(rewards.shape[1:], dtype=np.float32)
    for step in reversed(range(n_steps)):
        if step == n_steps - 1:
            not_done = 1.0 - last_dones.astype(np.float32)
            next_values = last_values
        else:
            not_done = 1.0 - episode_starts[step + 1]
            next_values = values[step + 1]
        delta = rewards[step] + gamma * next_values * not_done - values[step]
        running = delta + gamma * gae_lambda * not_done * running
        advantages[step] = running
    return advantages, (advantages + values).astype(np.float32)


def normalize_advantages(advantages: np.ndarray, mode: AdvantageNormalization) -> np.ndarray:
    """Normalise a *whole rollout's* advantages (not per minibatch), so every minibatch and every
    epoch sees the same scaling.

    ``standardize``: ``(A - mean) / (std + eps)``; ``center``: ``A - mean`` (keeps the scale of the
    signal; OmniSafe, which the paper's runs used, does this to cost advantages); ``none``: unchanged.
    """
    if mode == "none":
        return advantages
    centred = advantages - advantages.mean()
    if mode == "center":
        return centred.astype(np.float32)
    if mode == "standardize":
        return (centred / (advantages.std() + STD_EPS)).astype(np.float32)
    raise ValueError(f"unknown advantage normalisation {mode!r}; use 'standardize', 'center' or 'none'")


def categorical_kl(old_logits: th.Tensor, new_logits: th.Tensor) -> th.Tensor:
    """Exact per-state ``KL(pi_old || pi_new) = sum_a pi_old(a) (log pi_old(a) - log pi_new(a))``.

    Exact rather than the sample estimate ``mean(log pi_old(a_t) - log pi_new(a_t))`` because the
    policies are categorical: the exact value costs nothing extra and has no sampling noise, which
    matters for KL early stopping and for the trust-region line search.
    """
    old_log_p = th.log_softmax(old_logits, dim=-1)
    new_log_p = th.log_softmax(new_logits, dim=-1)
    return (old_log_p.exp() * (old_log_p - new_log_p)).sum(dim=-1)
