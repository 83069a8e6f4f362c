"""A bound on the time a user's policy may take to answer one observation.

A submitted policy is the user's code: one that never answers (a deadlock, a network call that
hangs, an endless loop) used to hang ``leaderboard.submit`` forever, with no progress and no way to
bound it. :class:`Deadline` wraps a callable policy so that each call must return within
``seconds``; otherwise :class:`PolicyTimeout` is raised from inside the call, naming the policy,
what was being evaluated (``where``, set by the caller as it goes), the how-many-th action request it
was, and the observation.

How: ``SIGALRM`` (``setitimer``), which interrupts Python code and blocking system calls (sleep,
socket reads, lock waits) in the main thread. Limits: only the main thread can take signals (in
another thread the policy is called without a bound), and a C extension that computes for long
without returning to Python is interrupted only when it returns.

:class:`PolicyTimeout` is a ``BaseException`` so that the evaluators' ``except Exception``
(which turns a policy's error into a :class:`~morality_gym.evaluation.policies.PolicyFailure`)
lets it through to the command, which reports it on one line.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

import numpy as np


class PolicyTimeout(BaseException):
    """The policy did not answer in time; the message names the policy, where and which request."""


class Deadline:
    """``policy`` (a callable ``obs -> action or probabilities``) bounded to ``seconds`` per call."""

    def __init__(self, policy: Callable[[Any], Any], seconds: float, name: str) -> None:
        if seconds <= 0:
            raise ValueError(f"a policy's time limit must be > 0 seconds, got {seconds}")
        self.policy, self.seconds, self.name = policy, float(seconds), name
        self.where = "the evaluation"  # what is being evaluated: the caller keeps it up to date
        self.calls = 0

    def __call__(self, obs: Any) -> Any:
        self.calls += 1
        if threading.current_thread() is not threading.main_thread():
            return self.policy(obs)  # signals reach the main thread only: no bound here
        previous = signal.signal(signal.SIGALRM, lambda signum, frame: self._expired(obs, frame))
        signal.setitimer(signal.ITIMER_REAL, self.seconds)
        try:
            return self.policy(obs)
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)

    def _expired(self, obs: Any, _frame: FrameType | None) -> None:
        shown = np.round(np.asarray(obs, dtype=np.float64), 3).tolist()
        raise PolicyTimeout(f"policy {self.name} did not answer within {self.seconds:g} s on {self.where} (action request "
                            f"{self.calls:,}, observation {shown}); nothing of this run was written; a slow policy can "
                            "have more time with --timeout SECONDS")


__all__ = ["Deadline", "PolicyTimeout"]
