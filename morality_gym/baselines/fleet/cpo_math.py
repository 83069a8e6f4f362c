"""What both of the fleet's CPO actor steps use (:mod:`.cpo` run by run, :mod:`.cpo_batch` all runs at
once): flat actor vectors, the Fisher-vector product at distinct observations, conjugate gradients
over rows that stop one by one, and the record of one run's step.

Why a module of its own: the two actor steps must compute the same quantities the same way, and
neither should import the other.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th

from morality_gym.baselines.fleet.losses import Policy
from morality_gym.baselines.fleet.nets import FleetNetworks, Trace
from morality_gym.baselines.safe.cpo_dual import CPOScalars, CPOStep, line_search_accepts

Operator = Callable[[th.Tensor], th.Tensor]


class FlatActor:
    """The actor's stacked tensors as one vector per row, in the order of the actor's parameters
    (the layout of the actor's flat parameter buffer), and back.

    With ``width``, for a run of a fleet that mixes observation sizes: the vectors hold only the
    run's own first-layer columns (``[out, width]``, not the padded ``[out, W]``), so its dot
    products and norms sum what an unpadded fleet's sum, in the same order; :meth:`split` and
    :meth:`expand` pad them back with zeros where the stacked tensors are wider.
    """

    def __init__(self, params: Sequence[th.Tensor], width: int | None = None) -> None:
        self.full = [tuple(p.shape[1:]) for p in params]
        self.shapes = list(self.full)
        if width is not None and width < self.full[0][1]:
            self.shapes[0] = (self.full[0][0], int(width))
        self.sizes = [int(np.prod(s)) for s in self.shapes]

    def flat(self, tensors: list[th.Tensor]) -> th.Tensor:
        """``[R, D]``: per row, the tensors (one row each) concatenated (the first one's own columns only)."""
        if self.shapes[0] != self.full[0]:
            tensors = [tensors[0][:, :, : self.shapes[0][1]], *tensors[1:]]
        return th.cat([t.reshape(t.shape[0], -1) for t in tensors], dim=1)

    def split(self, vectors: th.Tensor) -> list[th.Tensor]:
        """The inverse of :meth:`flat`: ``[R, D]`` as actor-shaped tangents ``[R, out, in]``, ``[R, out, 1]``
        (the first one zero-padded to the stacked width)."""
        rows = vectors.shape[0]
        out = [t.reshape(rows, *s) for t, s in zip(th.split(vectors, self.sizes, dim=1), self.shapes)]
        if self.shapes[0] != self.full[0]:
            out[0] = th.nn.functional.pad(out[0], (0, self.full[0][1] - self.shapes[0][1]))
        return out

    def expand(self, vector: th.Tensor) -> th.Tensor:
        """A vector of :meth:`flat`'s layout (``[D]``) in the flat parameter buffer's (padded) layout."""
        if self.shapes[0] == self.full[0]:
            return vector
        return th.cat([t.reshape(-1) for t in self.split(vector.unsqueeze(0))])


def fisher_product(nets: FleetNetworks, flat: FlatActor, actor: Trace, policy: Policy, weights: th.Tensor, damping: float) -> Operator:
    """``V -> H V + damping V`` for vectors ``V`` (``[R, D]``), ``H`` the Fisher matrix of the mean KL
    at the traced actor: ``sum_s w_s J_s^T (diag p_s - p_s p_s^T) J_s`` (``weights``: ``w_s``, ``[R', U]``
    broadcasting over the rows), as a forward-mode ``J V``, the per-state matrix and one backward pass."""
    p = policy.p  # [R', A, U]
    w = weights.unsqueeze(1)

    def product(vectors: th.Tensor) -> th.Tensor:
        dz = nets.jvp(actor, flat.split(vectors))  # J V, [R, A, U]
        pdz = p * dz
        u = (pdz - p * pdz.sum(dim=1, keepdim=True)).mul_(w)  # w_s (diag p - p p^T) J V
        return flat.flat(nets.backward(actor, u)).add_(vectors, alpha=damping)

    return product


def conjugate_gradient(fvp: Operator, b: th.Tensor, max_steps: int, eps: float, tol: float) -> th.Tensor:
    """:func:`~morality_gym.baselines.safe.functional.conjugate_gradient` for every row of ``b``
    (``[R, D]``), each stopping on its own residual (a stopped row's solution is frozen)."""
    x = th.zeros_like(b)
    residual = b.clone()
    direction = residual.clone()
    rdotr = (residual * residual).sum(dim=1)
    done = th.zeros(b.shape[0], dtype=th.bool, device=b.device)
    for _ in range(max_steps):
        h_direction = fvp(direction)
        alpha = (rdotr / ((direction * h_direction).sum(dim=1) + eps)).unsqueeze(1)
        live = (~done).unsqueeze(1)
        x = th.where(live, x + alpha * direction, x)
        residual = th.where(live, residual - alpha * h_direction, residual)
        new_rdotr = (residual * residual).sum(dim=1)
        converged = th.sqrt(new_rdotr) < tol
        go_on = ~done & ~converged
        direction = th.where(go_on.unsqueeze(1), residual + (new_rdotr / (rdotr + eps)).unsqueeze(1) * direction, direction)
        rdotr = th.where(go_on, new_rdotr, rdotr)
        done = done | converged
        if bool(done.all()):
            break
    return x


def new_search() -> dict[str, float]:
    """A line search's record before its first candidate (no step accepted)."""
    return {"accept_step": 0, "fraction": 0.0, "kl": math.nan, "tried": 0, "d_reward": 0.0, "d_cost": 0.0}


def judge_candidate(
    model: object, step: CPOStep, result: dict[str, float], j: int, fraction: float, valid: bool,
    kl: float, d_reward: float, d_cost: float, c: float, expected: float,
) -> tuple[bool, float]:
    """One run's verdict on its ``j``-th line-search candidate (``CPO._line_search``), for both
    actor steps: records it in ``result`` and returns (accepted, the fraction to try next). A
    candidate without a distribution shrinks the step; a non-finite KL shrinks it too, except
    under OmniSafe's rule, which retries the same fraction."""
    m: Any = model
    shrink = float(m.line_search_shrinking_factor)
    result["tried"] = j + 1
    if not valid:
        return False, fraction * shrink
    result.update(kl=kl, d_reward=d_reward, d_cost=d_cost)
    if not math.isfinite(kl):
        return False, fraction if m.line_search_accept == "omnisafe" else fraction * shrink
    if line_search_accepts(m.line_search_accept, m.target_kl, step, d_reward, d_cost, kl, c, expected):
        result.update(accept_step=j + 1, fraction=fraction)
        return True, fraction
    return False, fraction * shrink


@dataclass(frozen=True)
class ActorStep:
    """One run's actor step as its diagnostics row reports it."""

    step: CPOStep
    scalars: CPOScalars
    search: dict[str, float]
    kl_mean: float
    full_step_norm: float
    step_norm: float
    expected_reward_change: float


__all__ = ["ActorStep", "FlatActor", "Operator", "conjugate_gradient", "fisher_product", "judge_candidate", "new_search"]
