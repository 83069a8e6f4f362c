"""Small, stateless maths shared by the constrained learners.

Kept apart from the algorithms so that each formula lives in exactly one place and can be tested
on its own (the GAE recursion here is the one used for *both* the reward and the cost stream).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np
import torch as th

AdvantageNormalization = Literal["standardize", "center", "none"]
KLReduction = Literal["sum", "mean"]

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

    ``standardize``: ``(A - mean) / (std + eps)`` with the population std; ``center``: ``A - mean``
    (keeps the scale of the signal; OmniSafe, which ran the paper's PPO-Lag and CPO, does this to
    cost advantages, see docs/protocols.md#cost-advantages-are-only-centred); ``none``: unchanged.
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


def reduce_kl(per_state: th.Tensor, reduction: KLReduction) -> th.Tensor:
    """One number from per-state KLs, as a KL early-stop rule compares it with ``target_kl``.

    ``mean``: the mean over states, the quantity a KL target is meant for. ``sum``: the sum over
    states. The second is what OmniSafe's PPO-Lag computed for categorical policies: its
    ``kl.sum(-1).mean()`` was written for Gaussian policies, where the last axis holds action
    dimensions, but a categorical distribution's KL has the batch of states there, so it sums over
    the epoch's 2,048 states and stops once the *mean* KL exceeds target/2,048
    (docs/protocols.md#ppo-lag-kl-early-stop-sums-over-states).
    """
    if reduction == "sum":
        return per_state.sum()
    if reduction == "mean":
        return per_state.mean()
    raise ValueError(f"unknown KL reduction {reduction!r}; use 'sum' or 'mean'")


def conjugate_gradient(
    matrix_vector_product: Callable[[th.Tensor], th.Tensor],
    b: th.Tensor,
    max_iter: int,
    residual_tol: float = 1e-10,
    eps: float = 1e-6,
) -> th.Tensor:
    """Approximately solve ``H x = b`` by conjugate gradients, starting from ``x = 0``.

    The arithmetic is OmniSafe's, which produced the paper's CPO numbers: it stops when the
    residual's *norm* falls below ``residual_tol`` and adds ``eps`` to the denominators of the step
    and direction coefficients. ``eps`` matters here: the cost gradients of these tasks are small
    (cost advantages are only centred), so ``p^T H p`` can be comparable to 1e-6, and the guard then
    shortens the solution. sb3-contrib's solver differs in both respects and, worse, starts from a
    random ``1e-4 * randn`` point (consuming torch's RNG) and returns it as is when ``|b|^2`` is
    below the tolerance, which for a tiny cost gradient is noise rather than ``H^-1 b``.
    """
    x = th.zeros_like(b)
    residual = b.clone()  # b - H @ 0
    direction = residual.clone()
    rdotr = residual @ residual
    for _ in range(max_iter):
        h_direction = matrix_vector_product(direction)
        alpha = rdotr / (direction @ h_direction + eps)
        x = x + alpha * direction
        residual = residual - alpha * h_direction
        new_rdotr = residual @ residual
        if th.sqrt(new_rdotr) < residual_tol:
            break
        direction = residual + (new_rdotr / (rdotr + eps)) * direction
        rdotr = new_rdotr
    return x
