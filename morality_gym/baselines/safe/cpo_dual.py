r"""The CPO step direction: which case applies, and the step each dual solution takes.

CPO (Achiam et al., 2017) approximates, around the current policy ``theta_k``, with ``x = theta - theta_k``::

    max_x  g^T x                      (g: gradient of the reward surrogate, the objective)
    s.t.   c + b^T x <= 0             (b: gradient of the cost surrogate, c = J_c(pi_k) - d)
           1/2 x^T H x <= delta       (H: Fisher matrix of the mean KL, delta: target KL)

With ``v = H^-1 g`` and ``w = H^-1 b`` (conjugate gradients) the scalars are::

    q = v^T H v  (= g^T H^-1 g),   r = g^T w,   s = b^T w,
    A = q - r^2 / (s + 1e-8),      B = 2 delta - c^2 / (s + 1e-8).

``q`` is computed as ``v^T H v`` (one more Fisher-vector product) rather than ``g^T v``, as OmniSafe
does; the two agree when conjugate gradients converge, and differ a little when it stops early.

Cases, in OmniSafe's numbering (logged as ``cpo_case``), decided by :func:`determine_case`:

* 4: ``b^T b <= 1e-6`` and ``c < 0``: no usable cost gradient and the constraint is satisfied:
  TRPO step ``alpha v`` with ``alpha = sqrt(2 delta / (v^T H v))``.
* 3: ``c < 0`` and ``B < 0``: every point of the trust region satisfies the constraint: TRPO step.
* 2: ``c < 0 <= B``: the constraint may bind: dual step.
* 1: ``c >= 0`` and ``B >= 0``: violated (or at its limit) but reachable: dual step ("feasible
  recovery").
* 0: ``c >= 0`` and ``B < 0``: no point of the trust region satisfies the linearised constraint:
  recovery step ``-sqrt(2 delta / s) w``, the largest pure decrease of the cost.

With ``cost_limit = 0`` (the paper's runs) ``c`` is a mean episode cost, never negative, so only
cases 0 and 1 occur.

Two solutions of the dual step (cases 1 and 2), chosen by the learner setting ``dual_solution``:

* :func:`exact_direction` (``exact``, the corrected protocol) solves the linearised problem. The
  Lagrangian ``g^T x - nu (c + b^T x) - lambda (x^T H x / 2 - delta)`` is maximised by
  ``x = (v - nu w) / lambda``; the dual ``D(lambda, nu) = (q - 2 nu r + nu^2 s) / (2 lambda) - nu c
  + lambda delta`` is minimised over ``lambda, nu >= 0``. For fixed ``lambda`` the best ``nu`` is
  ``max(0, (lambda c + r) / s)``, which splits the ``lambda`` axis at ``-r / c`` into a piece with
  ``nu > 0`` (``D_a = A / (2 lambda) + B lambda / 2 - r c / s``, minimised by ``sqrt(A / B)``) and
  one with ``nu = 0`` (``D_b = q / (2 lambda) + delta lambda``, minimised by ``sqrt(q / (2 delta))``).
  Each piece is convex, so its best point is its minimiser clipped to its interval; ``lambda*`` is
  the better of the two. A test checks the KKT conditions on random instances.
* :func:`omnisafe_direction` (``omnisafe``, the paper protocol) is what OmniSafe computed, bugs
  included (docs/protocols.md#cpo-uses-omnisafes-dual-solution). It follows the CPO paper's
  formulas written for the gradient of a *loss*, but is given the gradient of the objective: the
  split point is ``r / c`` instead of ``-r / c`` and ``nu* = max(lambda* c - r, 0) / s`` instead of
  ``max(lambda* c + r, 0) / s``. Its projections use torch's clamp, which returns the upper bound
  when the bounds are crossed, so ``lambda_b*`` is the (negative) ``r / c`` whenever ``r / c < 0``.
  Every division carries a ``1e-8`` guard, and a NaN (``sqrt`` of a negative ``A / B``) loses the
  comparison of the two pieces, exactly as in torch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Literal

import numpy as np
import torch as th

#: OmniSafe's guard on divisions by ``s``, ``lambda``, ``c`` and ``v^T H v``.
GUARD = 1e-8
#: OmniSafe's threshold on ``b^T b`` below which the cost gradient counts as absent (case 4).
NO_COST_GRADIENT_BB = 1e-6
#: Below this, q or s count as zero in the exact solution (they are quadratic forms of gradients).
EPS = 1e-8

DualSolution = Literal["omnisafe", "exact"]
DUAL_SOLUTIONS: tuple[str, ...] = ("omnisafe", "exact")


class CPOCase(IntEnum):
    """Which branch produced the step, in OmniSafe's numbering (logged as ``cpo_case``)."""

    INFEASIBLE = 0  # c >= 0, B < 0: recovery step, purely decrease the cost
    FEASIBLE_RECOVERY = 1  # c >= 0, B >= 0: dual step that must cut the cost by c
    FEASIBLE = 2  # c < 0 <= B: dual step, constraint possibly active
    INACTIVE = 3  # c < 0, B < 0: constraint cannot bind inside the trust region: TRPO step
    NO_COST_GRADIENT = 4  # c < 0 and b^T b <= 1e-6: TRPO step


@dataclass(frozen=True)
class CPOScalars:
    """The scalars of one CPO update (all logged)."""

    q: float
    r: float
    s: float
    c: float
    delta: float
    bb: float  # b^T b

    @property
    def A(self) -> float:  # the paper's name
        return self.q - self.r**2 / (self.s + GUARD)

    @property
    def B(self) -> float:  # the paper's name
        return 2 * self.delta - self.c**2 / (self.s + GUARD)


@dataclass(frozen=True)
class CPOStep:
    """A full step before the line search, with the case and dual variables that produced it."""

    direction: th.Tensor
    case: CPOCase
    lam: float  # lambda*: trust-region multiplier as reported (OmniSafe's convention per case)
    nu: float  # nu*: cost-constraint multiplier as reported
    A: float = 0.0  # the paper's names
    B: float = 0.0


def determine_case(sc: CPOScalars) -> tuple[CPOCase, float, float]:
    """``(case, A, B)`` as OmniSafe decides them (``A = B = 0`` in case 4, as it logs them)."""
    if sc.bb <= NO_COST_GRADIENT_BB and sc.c < 0:
        return CPOCase.NO_COST_GRADIENT, 0.0, 0.0
    a, b = sc.A, sc.B
    if sc.c < 0 and b < 0:
        return CPOCase.INACTIVE, a, b
    if sc.c < 0 <= b:
        return CPOCase.FEASIBLE, a, b
    if sc.c >= 0 and b >= 0:
        return CPOCase.FEASIBLE_RECOVERY, a, b
    return CPOCase.INFEASIBLE, a, b


def _trpo_step(v: th.Tensor, vhv: float, delta: float) -> tuple[th.Tensor, float, float]:
    """Cases 3 and 4: ``alpha v`` with ``alpha = sqrt(2 delta / (v^T H v))``; reports lambda = 1/alpha."""
    alpha = math.sqrt(2 * delta / (vhv + GUARD))
    return alpha * v, 1.0 / (alpha + GUARD), 0.0


def _recovery_step(w: th.Tensor, s: float, delta: float) -> tuple[th.Tensor, float, float]:
    """Case 0: ``-sqrt(2 delta / s) w``; reports lambda = 0 and nu = sqrt(2 delta / s)."""
    nu = math.sqrt(2 * delta / (s + GUARD))
    return -nu * w, 0.0, nu


def _f64(value: float) -> np.float64:
    return np.float64(value)


def omnisafe_dual(sc: CPOScalars) -> tuple[float, float]:
    """``(lambda*, nu*)`` of OmniSafe's cases 1 and 2 (see the module docstring), in float64 with
    IEEE semantics (``sqrt`` of a negative is NaN, ``x / 0`` is inf), like torch."""
    with np.errstate(all="ignore"):
        q, r, s, c, delta = map(_f64, (sc.q, sc.r, sc.s, sc.c, sc.delta))
        a, b = _f64(sc.A), _f64(sc.B)
        lam_a = np.sqrt(a / b)
        lam_b = np.sqrt(q / (2 * delta))
        split = r / (c + GUARD)
        inf = np.float64(np.inf)

        def clamp(value: np.float64, lo: np.float64, hi: np.float64) -> np.float64:
            # torch.clamp(x, lo, hi) = min(max(x, lo), hi): NaN stays NaN, crossed bounds give hi.
            return np.minimum(np.maximum(value, lo), hi)

        if c < 0:
            lam_a_star, lam_b_star = clamp(lam_a, _f64(0.0), split), clamp(lam_b, split, inf)
        else:
            lam_a_star, lam_b_star = clamp(lam_a, split, inf), clamp(lam_b, _f64(0.0), split)
        f_a = -0.5 * (a / (lam_a_star + GUARD) + b * lam_a_star) - r * c / (s + GUARD)
        f_b = -0.5 * (q / (lam_b_star + GUARD) + 2 * delta * lam_b_star)
        lam = lam_a_star if f_a >= f_b else lam_b_star  # a NaN comparison is False: piece b wins
        nu = np.maximum(lam * c - r, 0.0) / (s + GUARD)
    return float(lam), float(nu)


def omnisafe_direction(v: th.Tensor, w: th.Tensor, sc: CPOScalars, vhv: float) -> CPOStep:
    """OmniSafe's step for every case (the paper protocol)."""
    case, a, b = determine_case(sc)
    if case in (CPOCase.INACTIVE, CPOCase.NO_COST_GRADIENT):
        direction, lam, nu = _trpo_step(v, vhv, sc.delta)
    elif case == CPOCase.INFEASIBLE:
        direction, lam, nu = _recovery_step(w, sc.s, sc.delta)
    else:
        lam, nu = omnisafe_dual(sc)
        direction = (v - nu * w) / (lam + GUARD)
    return CPOStep(direction, case, lam, nu, a, b)


def _clip(value: float, lo: float, hi: float) -> float:
    return max(max(lo, EPS), min(value, hi))


def exact_dual(q: float, r: float, s: float, c: float, delta: float) -> tuple[float, float]:
    """``(lambda*, nu*)`` minimising the dual of the linearised problem (module docstring)."""
    a = max(q - r * r / s, EPS)
    b = max(2 * delta - c * c / s, EPS)
    inf = math.inf
    # Intervals of lambda on which nu(lambda) > 0 (piece a) or nu(lambda) = 0 (piece b).
    interval_a: tuple[float, float] | None
    interval_b: tuple[float, float] | None
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
        candidates.append((a / (2 * lam_a) + b * lam_a / 2 - r * c / s, lam_a))
    if interval_b is not None:
        lam_b = _clip(math.sqrt(q / (2 * delta)), *interval_b)
        candidates.append((q / (2 * lam_b) + delta * lam_b, lam_b))
    lam = min(candidates)[1]
    nu = max(0.0, (lam * c + r) / s)
    return lam, nu


def exact_direction(v: th.Tensor, w: th.Tensor, sc: CPOScalars, vhv: float) -> CPOStep:
    """The exact solution of the linearised problem (the corrected protocol).

    Cases 0, 3 and 4 take the same steps as OmniSafe (those are right); cases 1 and 2 solve the
    dual exactly. Degenerate inputs: with ``s ~ 0`` the step cannot change the cost, so the
    constraint is ignored (TRPO step); with ``q ~ 0`` there is no reward direction, so the step is
    the smallest one that satisfies the linearised constraint (``-(c / s) w``), or none.
    """
    case, a, b = determine_case(sc)
    if case in (CPOCase.INACTIVE, CPOCase.NO_COST_GRADIENT):
        direction, lam, nu = _trpo_step(v, vhv, sc.delta)
    elif case == CPOCase.INFEASIBLE:
        direction, lam, nu = _recovery_step(w, sc.s, sc.delta)
    elif sc.s <= EPS:
        direction, lam, nu = _trpo_step(v, vhv, sc.delta) if sc.q > EPS else (th.zeros_like(v), 0.0, 0.0)
    elif sc.q <= EPS:
        direction = -(sc.c / sc.s) * w if sc.c > 0 else th.zeros_like(v)
        lam, nu = 0.0, max(sc.c, 0.0) / sc.s
    else:
        lam, nu = exact_dual(sc.q, sc.r, sc.s, sc.c, sc.delta)
        direction = (v - nu * w) / lam
    return CPOStep(direction, case, lam, nu, a, b)


def cpo_direction(
    v: th.Tensor,
    w: th.Tensor,
    q: float,
    r: float,
    s: float,
    c: float,
    delta: float,
    *,
    bb: float | None = None,
    solution: DualSolution = "exact",
    vhv: float | None = None,
) -> CPOStep:
    """The CPO full step from ``v = H^-1 g``, ``w = H^-1 b`` and the scalars of the module docstring.

    :param bb: ``b^T b`` (case 4's test); ``None`` treats the cost gradient as present.
    :param solution: ``exact`` or ``omnisafe`` (see the module docstring).
    :param vhv: ``v^T H v`` for the TRPO steps; ``None`` uses ``q``.
    """
    sc = CPOScalars(q=q, r=r, s=s, c=c, delta=delta, bb=math.inf if bb is None else bb)
    vhv = q if vhv is None else vhv
    if solution == "omnisafe":
        return omnisafe_direction(v, w, sc, vhv)
    if solution == "exact":
        return exact_direction(v, w, sc, vhv)
    raise ValueError(f"unknown CPO dual solution {solution!r}; use one of {', '.join(DUAL_SOLUTIONS)}")


def line_search_accepts(
    rule: str, target_kl: float, step: CPOStep, d_reward: float, d_cost: float, kl: float, c: float, expected: float
) -> bool:
    """Whether the line search accepts a candidate (``line_search_accept``: ``rule``), for the
    single learner (:class:`~morality_gym.baselines.safe.cpo.CPO`) and the fleet alike.

    ``d_reward`` / ``d_cost``: the candidate's change of the reward / cost surrogate from
    ``theta_old``; ``kl``: its exact mean KL from ``theta_old`` (finite here); ``c``: ``J_c - d``;
    ``expected``: ``g^T x``, the reward change the full step predicts. Both rules refuse a KL above
    ``target_kl`` or a cost change above ``max(-c, 0)``; ``omnisafe`` then refuses a worse reward
    in cases 2-4 only, ``strict`` asks a recovery step to cut the cost and any other step to
    improve the reward when it predicts so (else to cut the cost).
    """
    if kl > target_kl or d_cost > max(-c, 0.0):
        return False
    if rule == "omnisafe":
        return not (step.case > CPOCase.FEASIBLE_RECOVERY and d_reward < 0)
    if step.case == CPOCase.INFEASIBLE:
        return d_cost < 0
    return d_reward > 0 if expected > 0 else d_cost < 0
