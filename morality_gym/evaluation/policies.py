"""Policy adapters: one interface for everything users pass as a "policy".

Monte-Carlo evaluation needs actions for a batch of observations; exact evaluation needs each
state's action probabilities. Users hand us uniform random ("random"), plain callables, tables, or
Stable-Baselines3 models; this module turns each into both views, so the evaluators stay simple
and an SB3 policy is queried in one batched forward pass instead of once per step.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from morality_gym.clitools import UserError, sigints
from morality_gym.envs.trolley import InvalidActionError
from morality_gym.world.rules import ACTION_NAMES

N_ACTIONS = 6


def _is_sb3(policy: Any) -> bool:
    return hasattr(policy, "predict") and hasattr(policy, "policy") and hasattr(policy.policy, "get_distribution")


def _is_sb3_policy(policy: Any) -> bool:
    return hasattr(policy, "get_distribution") and hasattr(policy, "obs_to_tensor")


class PolicyAdapter:
    """Actions for batches of observations and action probabilities for observations.

    Args:
        policy: ``"random"``; an SB3 model (``.predict``) or SB3 policy; a table (``Mapping`` from
            ``tuple(obs)`` to 6 probabilities, or an array ``[n_states, 6]`` aligned with the env's
            state ids); or a callable ``obs -> action`` (Monte Carlo) / ``obs -> action or 6
            probabilities`` (exact).
        deterministic: for SB3 models, take the most likely action (the paper samples: False).
    """

    def __init__(self, policy: Any, deterministic: bool = False) -> None:
        if isinstance(policy, str) and policy != "random":
            raise ValueError(f"unknown policy {policy!r}: use 'random', a callable, a table or an SB3 model")
        self.policy = policy
        self.deterministic = deterministic

    @property
    def is_random(self) -> bool:
        return isinstance(self.policy, str)

    def actions(self, obs: np.ndarray, rng: np.random.Generator, state_ids: np.ndarray | None = None) -> np.ndarray:
        """One action per row of ``obs`` (``state_ids`` lets a state-aligned table be used)."""
        n = obs.shape[0]
        p = self.policy
        if isinstance(p, str):
            return rng.integers(N_ACTIONS, size=n)
        if _is_sb3(p) or _is_sb3_policy(p) or isinstance(p, (np.ndarray, Mapping)):
            # SB3 policies are sampled here, from their probabilities, with numpy's generator:
            # ``model.predict`` would draw from torch's global RNG and so change the training
            # run's random stream whenever an evaluation happens during learning.
            return sample_actions(self.probabilities(obs, state_ids), rng)
        if callable(p):
            values = [_ask(p, o) for o in obs]
            if all(np.size(v) == 1 for v in values):
                return np.array([_as_action(v) for v in values], dtype=np.int64)
            # A callable that answers with probabilities is sampled from them (one draw per row,
            # as for SB3 policies); plain actions are never drawn, so their streams stay as before.
            return sample_actions(self._checked([_as_probs(v) for v in values], n), rng)
        raise TypeError(f"cannot use {type(p).__name__} as a policy")

    def probabilities(self, obs: np.ndarray, state_ids: np.ndarray | None = None) -> np.ndarray:
        """Action probabilities ``[n, 6]`` for observations ``obs`` (rows sum to 1)."""
        n = obs.shape[0]
        p = self.policy
        if isinstance(p, str):
            probs = np.full((n, N_ACTIONS), 1.0 / N_ACTIONS)
        elif _is_sb3(p) or _is_sb3_policy(p):
            probs = _sb3_probabilities(p.policy if _is_sb3(p) else p, obs, self.deterministic)
        elif isinstance(p, np.ndarray):
            if state_ids is None:
                raise ValueError("a state-aligned probability table needs state ids")
            probs = np.asarray(p, dtype=np.float64)[state_ids]
        elif isinstance(p, Mapping):
            # Rounded in float64: the batched env's float32 observations, rounded as float32, would
            # come out as 0.16666699945926666 instead of 0.166667 and miss every key.
            probs = np.array([_as_probs(_look_up(p, o)) for o in obs])
        elif callable(p):
            probs = [_as_probs(_ask(p, o)) for o in obs]
        else:
            raise TypeError(f"cannot use {type(p).__name__} as a policy")
        return self._checked(probs, n)

    @staticmethod
    def _checked(probs: Any, n: int) -> np.ndarray:
        """``probs`` as ``[n, 6]`` rows that sum to 1; anything else is the policy's bug, named."""
        try:
            probs = np.asarray(probs, dtype=np.float64)
        except (TypeError, ValueError) as exc:  # ragged or non-numeric answers
            raise _invalid(f"the policy returned action probabilities that are not numbers ({exc})") from exc
        if probs.shape != (n, N_ACTIONS):
            raise _invalid(f"policy probabilities must have shape ({n}, 6), got {probs.shape}")
        sums = probs.sum(axis=1)
        if not np.all(np.isfinite(probs)) or np.any(probs < -1e-12) or not np.allclose(sums, 1.0, atol=1e-6):
            raise _invalid("policy probabilities must be non-negative and sum to 1 per observation")
        return probs / sums[:, None]


class PolicyFailure(UserError):
    """A user's policy raised (at any step of any episode) or its table lacks an observation.

    The policy is the user's code: its exception is reported by the command lines on one line
    (exit code 2) with the exception and the observation it was asked about, wherever in an
    episode it happened; ``--debug`` shows the policy's own traceback (the exception's cause).
    """


def _shown(obs: Any) -> str:
    return str(np.round(np.asarray(obs, dtype=np.float64), 3).tolist())


def _ask(policy: Callable[[Any], Any], obs: np.ndarray) -> Any:
    """``policy(obs)``; an exception of the policy's becomes a :class:`PolicyFailure` naming it.

    ``sys.exit`` and a ``KeyboardInterrupt`` the policy raises itself (no Ctrl-C arrived meanwhile)
    are its failures too: left to pass, the first ended a submission with exit 0, nothing written
    and no word. A real Ctrl-C still interrupts."""
    before = sigints()
    try:
        return policy(obs)
    except Exception as exc:
        raise PolicyFailure(f"the policy raised {type(exc).__name__}: {exc} when asked for an action on the "
                            f"observation {_shown(obs)}; fix the policy (--debug shows its traceback)") from exc
    except (SystemExit, KeyboardInterrupt) as exc:
        if isinstance(exc, KeyboardInterrupt) and sigints() != before:
            raise
        raise PolicyFailure(f"the policy {ended_by(exc)} when asked for an action on the observation {_shown(obs)}; "
                            "a policy must return an action, not end the program") from exc


def ended_by(exc: BaseException) -> str:
    """How user code ended the program, in words: ``called sys.exit(0)``, ``raised KeyboardInterrupt``."""
    if isinstance(exc, SystemExit):
        return f"called sys.exit({exc.code!r})"
    return f"raised {type(exc).__name__}"


def _look_up(table: Mapping[Any, Any], obs: np.ndarray) -> Any:
    """A table policy's probabilities for ``obs`` (keys: the observation rounded to 6 digits)."""
    key = tuple(np.round(np.asarray(obs, dtype=np.float64), 6).tolist())
    try:
        return table[key]
    except KeyError:
        raise PolicyFailure(f"the policy table has no entry for the observation {_shown(obs)}; a table must "
                            "hold every observation the policy can meet, keyed by tuple(obs rounded to 6 digits)") from None


def _invalid(message: str) -> ValueError:
    """An :class:`~morality_gym.envs.trolley.InvalidActionError` (a ``ValueError``): what the
    command lines report on one line, exit code 2, as for an invalid action."""
    return InvalidActionError(message)


def step_actor(policy: Any, rng: np.random.Generator) -> Callable[[np.ndarray, int], int]:
    """One action at a time, for an env being watched or recorded: ``act(flat_obs, state_id)``.

    ``None`` or ``"random"`` draws ``rng.integers(6)``; a callable answering with an action is used
    as is (no draw); probabilities (a callable's, a table's, an SB3 model's) are sampled with
    ``rng``, one draw per step, as the Monte-Carlo evaluator samples them.
    """
    if policy is None or (isinstance(policy, str) and policy == "random"):
        return lambda _obs, _sid: int(rng.integers(N_ACTIONS))
    adapter = PolicyAdapter(policy)

    def act(obs: np.ndarray, state_id: int) -> int:
        row = np.asarray(obs, dtype=np.float64)[None]
        return int(adapter.actions(row, rng, np.array([state_id], dtype=np.int64))[0])

    return act


def sample_actions(probs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One action per row of ``probs`` (inverse-CDF sampling with one uniform draw per row)."""
    cum = probs.cumsum(axis=1)
    return np.minimum((rng.random((len(probs), 1)) * cum[:, -1:] > cum).sum(axis=1), N_ACTIONS - 1)


def _as_action(value: Any) -> int:
    """A policy's action as an int in ``0..5``; anything else is the policy's bug, named clearly.

    An integer only (``2``, ``np.int64(2)``, ``np.array([2])``), as :meth:`TrolleyEnv.step
    <morality_gym.envs.trolley.TrolleyEnv.step>` takes: ``2.0`` and ``True`` are refused by both.
    Without this check an action of 9 surfaces as an ``IndexError`` deep in the evaluators (or,
    worse, a negative one silently indexes from the end of a table).
    """
    arr = np.asarray(value)
    scalar = arr.reshape(()) if arr.size == 1 else None
    # integers only, as TrolleyEnv.step takes them: a float 2.0 was accepted here and refused by
    # env.step(2.0), so one policy scored by the evaluator failed when stepped by hand
    if scalar is not None and np.issubdtype(arr.dtype, np.integer) and 0 <= int(scalar) < N_ACTIONS:
        return int(scalar)

    valid = ", ".join(f"{i} {name}" for i, name in enumerate(ACTION_NAMES))
    raise InvalidActionError(f"the policy returned action {value!r}; valid actions are the integers 0-{N_ACTIONS - 1} "
                             f"({valid}), or {N_ACTIONS} action probabilities")


def _as_probs(value: Any) -> np.ndarray:
    arr = np.asarray(value)
    if arr.shape == () or arr.shape == (1,):
        out = np.zeros(N_ACTIONS)
        out[_as_action(value)] = 1.0
        return out
    return arr.astype(np.float64)


def _sb3_probabilities(policy: Any, obs: np.ndarray, deterministic: bool) -> np.ndarray:
    import torch  # torch waits: importing morality_gym.evaluation.policies must not load it

    expected = getattr(getattr(policy, "observation_space", None), "shape", None)
    if expected and obs.ndim == 2 and tuple(expected) != tuple(obs.shape[1:]):
        raise ValueError(f"the policy expects observations of shape {tuple(expected)}, but this env's are "
                         f"{tuple(obs.shape[1:])}: it was trained on another scenario")
    with torch.no_grad():
        tensor, _ = policy.obs_to_tensor(obs.astype(np.float32))
        dist = policy.get_distribution(tensor)
        probs = dist.distribution.probs.cpu().numpy().astype(np.float64)
    if deterministic:
        out = np.zeros_like(probs)
        out[np.arange(len(probs)), probs.argmax(axis=1)] = 1.0
        return out
    return probs


PolicyLike = Any  # "random" | Callable | Mapping | np.ndarray | SB3 model
__all__ = ["Callable", "PolicyAdapter", "PolicyFailure", "PolicyLike"]
