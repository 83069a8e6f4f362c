"""The choices of one seed: a stream of numbers that is the same on every machine and version.

"Same seed, same bytes" is a promise about files that splits publish digests of, so the numbers
cannot come from :mod:`random` or numpy, whose non-basic methods may change their streams between
versions. Draw ``i`` of seed ``s`` is read from SHA-256 of ``"morality-gym-generator:{s}:{i}"``:
portable, documented, and as uniform as a generator of small dilemmas needs.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from typing import TypeVar

T = TypeVar("T")

_SALT = "morality-gym-generator"


class Draws:
    """The numbered draws of one seed (see the module docstring)."""

    def __init__(self, seed: int) -> None:
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ValueError(f"a generator seed is a non-negative integer, got {seed!r}")
        self.seed = seed
        self.count = 0

    def below(self, n: int) -> int:
        """A whole number in ``[0, n)``."""
        if n < 1:
            raise ValueError(f"cannot draw below {n}")
        digest = hashlib.sha256(f"{_SALT}:{self.seed}:{self.count}".encode()).digest()
        self.count += 1
        return int.from_bytes(digest[:8], "big") % n

    def between(self, low: int, high: int) -> int:
        """A whole number in ``[low, high]`` (both included)."""
        return low + self.below(high - low + 1)

    def chance(self, p: float) -> bool:
        """True with probability ``p`` (to 1 part in 10,000)."""
        return self.below(10_000) < round(p * 10_000)

    def pick(self, options: Sequence[T]) -> T:
        """One of ``options``, uniformly."""
        return options[self.below(len(options))]

    def weighted(self, options: Sequence[tuple[T, int]]) -> T:
        """One of ``options`` (``(value, weight)`` pairs, whole-number weights)."""
        roll = self.below(sum(weight for _, weight in options))
        for value, weight in options:
            if roll < weight:
                return value
            roll -= weight
        raise AssertionError("unreachable")

    def shuffled(self, items: Sequence[T]) -> list[T]:
        """``items`` in an order drawn uniformly (Fisher-Yates)."""
        out = list(items)
        for i in range(len(out) - 1, 0, -1):
            j = self.below(i + 1)
            out[i], out[j] = out[j], out[i]
        return out

    def sample(self, items: Sequence[T], k: int) -> list[T]:
        """``k`` distinct items of ``items``, in the order drawn."""
        return self.shuffled(items)[:k]
