"""The distinct observations of a run's rollout, for the learners' whole-rollout computations.

A trolley world has a few dozen to a few hundred states, so a rollout of 2,048 transitions visits
far fewer distinct observations (measured over CPO training on PushOrSwitch, Push2OrSwitch and
Switch7: 13 to 240 per rollout, typically 50-150). Whatever depends on a state only through its
observation (logits, the Fisher matrix's per-state term ``J^T M J``, the per-state KL) is the same
for every copy of it, so a sum over the rollout is a count-weighted sum over its distinct
observations: the same number (up to the order of float additions), computed on a tenth to a
hundredth of the rows. CPO's conjugate gradients, gradients and line search, and PPO-Lag's
per-pass KL test, use this.

Observations are compared as raw float32 bytes, exactly: equal observations are the same state as
far as the networks can tell.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch as th


@dataclass(frozen=True)
class DistinctStates:
    """One run's rollout as distinct observations: ``obs[index]`` are the distinct rows (``[U, d]``),
    ``inverse`` maps each transition to its row (``[M]``) and ``weights`` are the rows' counts
    divided by ``M`` (``[U]`` float32: the weights of a mean over the rollout)."""

    obs: th.Tensor
    inverse: th.Tensor
    counts: th.Tensor
    weights: th.Tensor

    @classmethod
    def of(cls, obs: th.Tensor, device: th.device | str | None = None) -> DistinctStates:
        """The distinct rows of ``obs`` (``[M, d]`` float32), in the byte order of the rows (so the
        result depends on this run's observations only), on ``device`` (default: ``obs``'s)."""
        device = obs.device if device is None else device
        arr = np.ascontiguousarray(obs.cpu().numpy())
        rows = arr.view(np.dtype((np.void, arr.dtype.itemsize * arr.shape[1])))[:, 0]
        _, index, inverse, counts = np.unique(rows, return_index=True, return_inverse=True, return_counts=True)
        counts_t = th.from_numpy(counts.astype(np.float32)).to(device)
        return cls(
            obs=th.from_numpy(arr[index]).to(device),
            inverse=th.from_numpy(inverse.reshape(-1).astype(np.int64)).to(device),
            counts=counts_t,
            weights=counts_t / float(len(arr)),
        )

    @property
    def n(self) -> int:
        return int(self.obs.shape[0])
