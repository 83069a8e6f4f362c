"""How many decimals a bootstrap bound is printed with: those it is stable to over bootstrap seeds.

A percentile bound is a quantile of a finite number of resamples, so it moves with the bootstrap's
seed; :func:`leaderboard.stats.core.quantile_mcse` estimates by how much (its Monte Carlo standard
error, MCSE). Printing digits beyond that is printing noise: the ranking page once showed a lower
bound of 0.7418 that 60 other seeds put at 0.7367 ± 0.0020. So every page, table and report prints
a bound with at most the decimals it would print anyway, and fewer where its MCSE is more than
:data:`STABLE_SHARE` of a unit of the last one. Kept free of SciPy: the table writers use it.
"""

from __future__ import annotations

import math
from typing import Any

#: A bound is stable to a decimal when its MCSE is at most this share of a unit of that decimal:
#: two standard errors within half a unit, so other seeds print the same digits except where the
#: bound sits near a rounding boundary, and then differ by one unit of the last digit.
STABLE_SHARE = 0.25
#: Most decimals any bound is written with (the precision of the CSV files).
MOST_DECIMALS = 6


def stable_decimals(mcse: Any, most: int = MOST_DECIMALS) -> int:
    """The most decimals (at most ``most``, at least 0) a bound with Monte Carlo standard error ``mcse`` is stable to.

    Unknown (None, NaN, missing: a table built without the error) gives ``most``.
    """
    try:
        error = float(mcse)
    except (TypeError, ValueError):
        return most
    if not math.isfinite(error):
        return most
    decimals = most
    while decimals > 0 and error > STABLE_SHARE * 10.0 ** -decimals:
        decimals -= 1
    return decimals


#: What every page and table says about the digits of a bound (one wording everywhere).
DIGITS_RULE = ("an interval has three decimals, or fewer where the bootstrap's Monte Carlo error would move the last "
               "one: both bounds are printed to the decimals on which their Monte Carlo standard errors are at most a "
               "quarter of a unit, so another bootstrap seed prints the same digits (or, next to a rounding boundary, "
               "one unit off)")
