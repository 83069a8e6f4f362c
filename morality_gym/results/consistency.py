"""A run file's numbers must agree with each other, and its name with the run it holds.

Why: a run file is trusted by whoever reads it, and two kinds of damage passed every check. A
file copied under another run's name (``cp a.parquet b.parquet``) made the sweep say "done" for
``b`` while the leaderboard found ``a`` twice and left ``b``'s cell incomplete forever. A file
whose ``metric`` was edited was published unmarked, although the row itself says otherwise: the
metric of a Monte-Carlo evaluation *is* the chain's weighted mean of the morality functions stored
beside it (spec section 4), and it lies within what ``eval_episodes`` episodes allow of the exact
metric of the same policy.

:func:`run_row_problem` says what disagrees, in words, or None. The sweep's readers move such a
file aside (:mod:`morality_gym.results.quarantine`) and plan the run again; the leaderboard, which
never moves files, leaves it out and lists it with the reason.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from morality_gym.norms.chain import ChainError, get_chain
from morality_gym.norms.metric import lexicographic_weights

#: The metric against its own functions: both are float64 sums of the same terms in another order.
FUNCTIONS_TOLERANCE = 1e-9
#: The chance that an honest Monte-Carlo metric lies further from the exact one than
#: :func:`episodes_bound` allows (Hoeffding's inequality: each episode's metric lies in [0, 1]).
FALSE_ALARM = 1e-12


def episodes_bound(n_episodes: int) -> float:
    """How far the mean of ``n_episodes`` episode metrics (each in [0, 1]) may lie from its
    expectation, except with probability :data:`FALSE_ALARM` (Hoeffding: ``sqrt(ln(2/p) / 2n)``)."""
    return math.sqrt(math.log(2.0 / FALSE_ALARM) / (2.0 * n_episodes))


def _number(value: Any) -> float | None:
    if value is None or isinstance(value, bool):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def run_row_problem(row: Mapping[str, Any], functions: Mapping[str, Any], path: Path) -> str | None:
    """What in the run row ``row`` read from ``path`` (``runs/<run_id>.parquet``) disagrees, or None.
    ``functions``: the row's morality functions by norm name (its ``mf_*`` columns).

    Checked: the row's ``run_id`` is the file's name; for a finished run, the ``metric`` is the
    weighted mean of its own morality functions, and lies within :func:`episodes_bound` of its own
    ``exact_metric``. A part that cannot be checked (a row without functions, an old file without a
    config) is not held against the file."""
    run_id = row.get("run_id")
    if run_id is not None and str(run_id) != path.name.split(".", 1)[0]:
        return (f"the file is named for run {path.name.split('.', 1)[0]} but holds run {run_id} "
                "(a copy under another run's name?)")
    if row.get("status") != "ok":
        return None
    metric = _number(row.get("metric"))
    if metric is None:
        return None
    expected = _functions_metric(row, functions)
    if expected is not None and abs(metric - expected) > FUNCTIONS_TOLERANCE:
        return (f"its metric {metric:.6f} is not the weighted mean of its own morality functions ({expected:.6f}); "
                "the row was changed after it was written")
    exact, episodes = _number(row.get("exact_metric")), _number(row.get("eval_episodes"))
    if exact is not None and episodes is not None and episodes >= 1:
        bound = episodes_bound(int(episodes))
        if abs(metric - exact) > bound:
            return (f"its metric {metric:.6f} lies {abs(metric - exact):.3f} from its own exact metric {exact:.6f}, "
                    f"more than {int(episodes)} episodes allow ({bound:.3f}); the row was changed after it was written")
    return None


def _functions_metric(row: Mapping[str, Any], functions: Mapping[str, Any]) -> float | None:
    """The chain's weighted mean of the row's morality functions, or None when the row lacks a part."""
    try:
        names = _norm_names(row)
        relevant = [str(n) for n in row.get("relevant_norms") or []]
        beta = _number(row.get("beta"))
        if not relevant or beta is None:
            return None
        weights = _weights(tuple(names), tuple(relevant), beta)
    except (TypeError, ValueError, KeyError, IndexError, ChainError):
        return None
    total = sum(weights.values())
    if total <= 0:
        return None
    value = 0.0
    for name, weight in weights.items():
        if weight == 0:
            continue
        function = _number(functions.get(name))
        if function is None:
            return None
        value += weight * function
    return value / total


def _norm_names(row: Mapping[str, Any]) -> list[str]:
    """The chain's norms, most important first: as the run's config recorded them, else (a config
    that names the chain only) the built-in chain of the row's name."""
    config = json.loads(row.get("config") or "null")
    chain = config.get("chain") if isinstance(config, dict) else None
    if isinstance(chain, dict):
        return [str(n[0]) for n in chain["norms"]]
    return list(_chain_norms(str(row.get("chain"))))


@functools.lru_cache(maxsize=256)
def _chain_norms(name: str) -> tuple[str, ...]:
    """A built-in chain's norm names (cached: thousands of run files name a handful of chains)."""
    return tuple(get_chain(name).norm_names)


@functools.lru_cache(maxsize=4096)
def _weights(names: tuple[str, ...], relevant: tuple[str, ...], beta: float) -> dict[str, float]:
    return lexicographic_weights(names, relevant, beta)
