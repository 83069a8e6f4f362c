"""Whether a truncation (``max_steps``) leaves room for the episodes a chain is scored on.

Why: a variant's utility bounds are the lowest and highest episode totals its world can produce
(:mod:`morality_gym.world.bounds`). An episode cut off before the trolley has run its course can
end with a total below the lowest (no harm *yet*), and the morality function of that utility then
leaves [0, 1]. The evaluators refused such a mean deep inside an evaluation, with a traceback, and a
sweep with ``max_steps=2`` trained every run before its final evaluation failed. So the truncation
is checked up front, exactly: the episode totals reachable within ``max_steps + 1`` steps (the same
enumeration as the bounds') must lie within the bounds of every utility norm the chain weighs.
"""

from __future__ import annotations

import functools

from morality_gym.constants import MAX_STEPS
from morality_gym.envs.registry import state_graph
from morality_gym.evaluation.montecarlo import MAX_EPISODE_STEPS
from morality_gym.norms.metric import BoundChain
from morality_gym.world.bounds import reachable_totals
from morality_gym.world.vocab import UTILITIES


def horizon_of(max_steps: int | None) -> int:
    """Steps an episode may take: truncation on step ``max_steps + 1`` (None: the evaluators' cap)."""
    return MAX_EPISODE_STEPS if max_steps is None else max_steps + 1


@functools.lru_cache(maxsize=4096)
def _spans(env_id: str, horizon: int) -> tuple[tuple[int, int], ...]:
    """(lowest, highest) episode total of each utility (``UTILITIES`` order) within ``horizon`` steps."""
    totals = reachable_totals(state_graph(env_id).tables(), horizon)
    return tuple((int(totals[:, i].min()), int(totals[:, i].max())) for i in range(len(UTILITIES)))


def _outside(bound: BoundChain, horizon: int) -> tuple[str, int, tuple[float, float]] | None:
    """The first weighed utility norm with a reachable total outside its bounds: (name, total, bounds)."""
    spans = _spans(bound.env_id, horizon)
    for norm in bound.chain.norms:
        if norm.kind == "event" or bound.weights.get(norm.name, 0.0) == 0.0 or norm.name not in UTILITIES:
            continue
        lo, hi = bound.bounds[norm.name]
        low, high = spans[UTILITIES.index(norm.name)]
        if low < lo:
            return norm.name, low, (lo, hi)
        if high > hi:
            return norm.name, high, (lo, hi)
    return None


def _least(bound: BoundChain, too_short: int) -> int | None:
    """The least ``max_steps`` above ``too_short`` that fits, up to the default (None: none does).

    A bisection: a longer horizon only adds totals of longer episodes, which the bounds (measured
    at the default horizon) contain, so once a ``max_steps`` fits every longer one up to the default does."""
    if too_short >= MAX_STEPS or _outside(bound, horizon_of(MAX_STEPS)) is not None:
        return None
    low, high = too_short, MAX_STEPS  # low does not fit, high does
    while high - low > 1:
        middle = (low + high) // 2
        if _outside(bound, horizon_of(middle)) is None:
            high = middle
        else:
            low = middle
    return high


def truncation_problem(bound: BoundChain, max_steps: int | None) -> str | None:
    """Why ``max_steps`` is too short to score ``bound``'s env by its chain, with the least that
    is long enough; None when it is fine."""
    found = _outside(bound, horizon_of(max_steps))
    if found is None:
        return None
    name, total, (lo, hi) = found
    least = _least(bound, max_steps or 0)
    fix = f"use max_steps >= {least}" if least is not None else f"use the default max_steps ({MAX_STEPS})"
    return (f"max_steps={max_steps} is too short for {bound.env_id}: an episode cut off after {horizon_of(max_steps)} "
            f"step(s) can end with {name} total {total}, outside the variant's bounds [{lo:g}, {hi:g}], so the "
            f"morality function of {name} would leave [0, 1]; {fix}")


__all__ = ["horizon_of", "truncation_problem"]
