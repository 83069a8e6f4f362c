r"""The CPO step direction: the closed-form solution of the linearised trust-region problem.

CPO (Achiam et al., 2017) approximates, around the current policy ``theta_k``, with ``x = theta - theta_k``::

    max_x  g^T x                      (g: gradient of the reward surrogate)
    s.t.   c + b^T x <= 0             (b: gradient of the cost surrogate, c = J_c(pi_k) - d)
           1/2 x^T H x <= delta       (H: Fisher matrix of the mean KL, delta: target KL)

With ``v = H^-1 g`` and ``w = H^-1 b`` (both from conjugate gradients) define the scalars

    q = g^T H^-1 g,   r = g^T H^-1 b,   s = b^T H^-1 b,
    A = q - r^2 / s,  B = 2 delta - c^2 / s.

Cases (how :func:`cpo_direction` chooses):

* ``INFEASIBLE`` (``c > 0`` and ``B < 0``): no point of the trust region satisfies the
  linearised constraint. Recovery step, the largest pure decrease of the cost inside the trust
  region: ``x = -sqrt(2 delta / s) H^-1 b``.
* ``INACTIVE`` (``c <= 0`` and ``B < 0``: every point of the trust region satisfies the
  constraint; or ``s ~ 0``: the step cannot change the cost): the TRPO step
  ``x = sqrt(2 delta / q) H^-1 g``.
* ``FEASIBLE`` (``B >= 0``; the constraint may be active). Lagrangian
  ``g^T x - nu (c + b^T x) - lambda (x^T H x / 2 - delta)`` is maximised by
  ``x = (H^-1 g - nu H^-1 b) / lambda``; substituting gives the dual, minimised over
  ``lambda >= 0, nu >= 0``::

      D(lambda, nu) = (q - 2 nu r + nu^2 s) / (2 lambda) - nu c + lambda delta.

  For fixed ``lambda`` the best ``nu`` is ``nu(lambda) = max(0, (lambda c + r) / s)``, which splits
  the ``lambda`` axis at ``lambda_mid = -r / c`` into two pieces:

  - where ``nu > 0`` (``lambda c + r > 0``): ``D_a(lambda) = A / (2 lambda) + B lambda / 2 - r c / s``,
    minimised by ``lambda_a = sqrt(A / B)``;
  - where ``nu = 0``: ``D_b(lambda) = q / (2 lambda) + delta lambda``, minimised by
    ``lambda_b = sqrt(q / (2 delta))`` (the TRPO step).

  Each piece is convex, so its minimum over its own interval is its unconstrained minimiser
  clipped to the interval; ``lambda*`` is the better of the two, ``nu* = nu(lambda*)`` and
  ``x* = (H^-1 g - nu* H^-1 b) / lambda*``. (``FEASIBLE_VIOLATED`` is the same solution with
  ``c > 0``: the step must *reduce* the cost by at least ``c``, at some loss of reward if needed.)

Sign convention: the paper's appendix writes ``nu* = (lambda* c - r)_+ / s`` with the opposite sign
of ``r``; the formulas above are derived for ``r = g^T H^-1 b`` as defined here and are checked
against a brute-force solution of the primal in ``tests/test_safe_rl.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import torch as th

#: Below this, q, s, A or B count as zero (they are quadratic forms of gradients).
EPS = 1e-8


class CPOCase(IntEnum):
    """Which branch produced the step (logged as ``train/cpo_case``)."""

    INFEASIBLE = 0  # recovery step: purely decrease the cost
    FEASIBLE_VIOLATED = 1  # c > 0 but reachable: dual solution, must cut the cost by c
    FEASIBLE = 2  # c <= 0, constraint possibly active: dual solution
    INACTIVE = 3  # constraint cannot bind inside the trust region (or has no gradient): TRPO step
    NO_STEP = 4  # nothing to improve: zero gradient


@dataclass(frozen=True)
class CPOStep:
    """A full step before the line search, with the dual variables that produced it."""

    direction: th.Tensor
    case: CPOCase
    lam: float  # trust-region multiplier (0 when not applicable)
    nu: float  # cost-constraint multiplier (0 when not applicable)


def _dual_a(lam: float, a: float, b: float, r: float, c: float, s: float) -> float:
    return a / (2 * lam) + b * lam / 2 - r * c / s


def _dual_b(lam: float, q: float, delta: float) -> float:
    return q / (2 * lam) + delta * lam


def _clip(value: float, lo: float, hi: float) -> float:
    return max(max(lo, EPS), min(value, hi))


def _solve_dual(q: float, r: float, s: float, c: float, delta: float) -> tuple[float, float]:
    """``(lambda*, nu*)`` of the feasible case (see the module docstring)."""
    a = max(q - r * r / s, EPS)
    b = max(2 * delta - c * c / s, EPS)
    inf = math.inf
    # Intervals of lambda on which nu(lambda) > 0 (piece a) or nu(lambda) = 0 (piece b).
    if c > 0:
        mid = max(-r / c, 0.0)
        interval_a, interval_b = (mid, inf), (0.0, mid)
    elif c < 0:
        mid = max(-r / c, 0.0)
        interval_a, interval_b = (0.0, mid), (mid, inf)
    elif r > 0:  # c == 0: nu(lambda) = r / s for every lambda
        interval_a, interval_b = (0.0, inf), None
    else:
        interval_a, interval_b = None, (0.0, inf)

    candidates: list[tuple[float, float]] = []  # (dual value, lambda)
    if interval_a is not None:
        lam_a = _clip(math.sqrt(a / b), *interval_a)
        candidates.append((_dual_a(lam_a, a, b, r, c, s), lam_a))
    if interval_b is not None:
        lam_b = _clip(math.sqrt(q / (2 * delta)), *interval_b)
        candidates.append((_dual_b(lam_b, q, delta), lam_b))
    lam = min(candidates)[1]
    nu = max(0.0, (lam * c + r) / s)
    return lam, nu


def cpo_direction(v: th.Tensor, w: th.Tensor, q: float, r: float, s: float, c: float, delta: float) -> CPOStep:
    """The CPO full step ``x`` from ``v = H^-1 g``, ``w = H^-1 b`` and the scalars of the module
    docstring (``delta`` is the target KL)."""
    zero = th.zeros_like(v)
    if s <= EPS:  # the step cannot move the cost (linearly): constraint irrelevant
        if q <= EPS:
            return CPOStep(zero, CPOCase.NO_STEP, 0.0, 0.0)
        lam = math.sqrt(q / (2 * delta))
        return CPOStep(v / lam, CPOCase.INACTIVE, lam, 0.0)

    b = 2 * delta - c * c / s
    if c > 0 and b < 0:
        return CPOStep(-math.sqrt(2 * delta / s) * w, CPOCase.INFEASIBLE, 0.0, 0.0)
    if c <= 0 and b < 0:
        if q <= EPS:
            return CPOStep(zero, CPOCase.NO_STEP, 0.0, 0.0)
        lam = math.sqrt(q / (2 * delta))
        return CPOStep(v / lam, CPOCase.INACTIVE, lam, 0.0)

    case = CPOCase.FEASIBLE_VIOLATED if c > 0 else CPOCase.FEASIBLE
    if q <= EPS:
        # No reward direction: the smallest step that satisfies the linear constraint, if needed.
        if c > 0:
            return CPOStep(-(c / s) * w, case, 0.0, 0.0)
        return CPOStep(zero, CPOCase.NO_STEP, 0.0, 0.0)
    lam, nu = _solve_dual(q, r, s, c, delta)
    return CPOStep((v - nu * w) / lam, case, lam, nu)
