"""A compact fixed-shape observation: the grid observation under one fixed sign projection.

Why: the grid (:mod:`.grid_observe`) lets one policy act in every scenario, but as an MLP input it
is 5,120 numbers wide, and a PPO update on it costs about ten times what it costs on a few hundred
inputs (measured for issue 44: 43.4 us per sample, network and epoch at width 5,120, 4.0 us at 384).
The grid is also almost all zeros. This observation keeps the grid's facts in :data:`COMPACT_WIDTH`
numbers: ``compact = (grid.ravel() @ S) * COMPACT_SCALE`` with ``S`` a fixed ``[5120, 128]`` matrix
of signs (+1 / -1).

Why 128: the track's PPO fleet (paper hyper-parameters, K=32 runs, one thread) trains 6,084 env
steps per CPU-second at width 384 and 11,549 at 128 (the update's products dominate); and at both
widths no two distinct grids of the Utility train pool's states share a compact observation
(BENCHMARKS.md, *Generalisation track*). Narrower inputs would be faster still, but leave the 64-unit
first layer fewer independent directions to read.

* **The same facts.** A random sign projection keeps distances between observations up to a small
  factor (Johnson-Lindenstrauss), so states the grid tells apart stay apart and similar states stay
  similar. Injectivity is checked, not assumed: :func:`collisions` finds distinct grids with equal
  compact observations, tests run it on every built-in env and generated variants, and
  ``benchmarks/bench_track_fleet.py`` on the whole train mixture.
* **Exact and portable.** ``S`` is derived from BLAKE2b of a fixed label (no RNG whose stream a
  library version may change). The product is a float32 BLAS product of integers whose every partial
  sum stays below 2**24 (at most 5,120 cells of at most 255), so it is exact in any summation order,
  and the scale is a power of two: every machine gets the same float32 bits. A user's agent computes it
  from the grid with :func:`compact_from_grid`.
* **Free at run time.** The simulators keep one observation row per state of a graph, so the
  projection is paid once per state when a graph's tables are built, never per step.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from typing import Final

import numpy as np
from gymnasium import spaces

from morality_gym.world.grid_observe import GRID_CHANNELS, GRID_HEIGHT, GRID_WIDTH

#: Numbers in a compact observation (module docstring: why 128).
COMPACT_WIDTH: Final[int] = 128
#: The grid's size flattened.
GRID_SIZE: Final[int] = GRID_CHANNELS * GRID_HEIGHT * GRID_WIDTH
#: A power of two (exact in float32): a state's sums are about +-20, so the inputs are about +-1.
COMPACT_SCALE: Final[float] = 1.0 / 16.0
#: What the sign matrix is derived from; changing it changes every compact observation.
_LABEL: Final[bytes] = b"morality-gym compact observation v1"


@lru_cache(maxsize=1)
def sign_matrix() -> np.ndarray:
    """The fixed ``[GRID_SIZE, COMPACT_WIDTH]`` float32 matrix of +1 / -1 (read-only).

    Entry ``j`` (row-major) is +1 where bit ``j`` of the digests ``BLAKE2b(label + block number)``,
    laid end to end (little-endian bits), is set."""
    n_bits = GRID_SIZE * COMPACT_WIDTH
    blocks = -(-n_bits // 512)  # 64-byte digests
    stream = b"".join(hashlib.blake2b(_LABEL + i.to_bytes(4, "little"), digest_size=64).digest() for i in range(blocks))
    bits = np.unpackbits(np.frombuffer(stream, dtype=np.uint8), bitorder="little")[:n_bits]
    signs = (bits.astype(np.float32) * 2 - 1).reshape(GRID_SIZE, COMPACT_WIDTH)
    signs.setflags(write=False)
    return signs


def compact_space() -> spaces.Box:
    """The Box of a compact observation (float32, :data:`COMPACT_WIDTH` wide)."""
    return spaces.Box(-np.inf, np.inf, shape=(COMPACT_WIDTH,), dtype=np.float32)


def compact_from_grid(grids: np.ndarray) -> np.ndarray:
    """Compact observations of ``grids`` (``[..., 20, 16, 16]`` or flattened ``[..., 5120]``, integer
    valued) as float32 ``[..., COMPACT_WIDTH]``."""
    grids = np.asarray(grids)
    if grids.shape[-3:] == (GRID_CHANNELS, GRID_HEIGHT, GRID_WIDTH):
        lead = grids.shape[:-3]
    elif grids.shape[-1:] == (GRID_SIZE,):
        lead = grids.shape[:-1]
    else:
        raise ValueError(f"grid observations have shape (..., {GRID_CHANNELS}, {GRID_HEIGHT}, {GRID_WIDTH}) or "
                         f"(..., {GRID_SIZE}), got {grids.shape}")
    flat = grids.reshape(-1, GRID_SIZE)
    if not np.array_equal(flat, np.rint(flat)):
        raise ValueError("grid observations hold small integers; got fractional values (an already normalised input?)")
    if flat.size and (flat.min() < 0 or flat.max() > 255):
        raise ValueError("grid observations hold integers 0..255 (uint8); got values outside that range")
    sums = flat.astype(np.float32) @ sign_matrix()  # exact: integer partial sums below 2**24 (module docstring)
    return (sums * np.float32(COMPACT_SCALE)).reshape(*lead, COMPACT_WIDTH)


def collisions(grids: np.ndarray, compact: np.ndarray | None = None) -> list[tuple[int, int]]:
    """Pairs of row indices ``(i, j)`` whose grids differ but whose compact observations are equal
    (empty: the projection tells apart every state these grids tell apart)."""
    flat = np.ascontiguousarray(np.asarray(grids).reshape(len(grids), -1))
    comp = compact_from_grid(flat) if compact is None else np.asarray(compact)
    first_by_compact: dict[bytes, int] = {}
    found: list[tuple[int, int]] = []
    for i, row in enumerate(np.ascontiguousarray(comp)):
        j = first_by_compact.setdefault(row.tobytes(), i)
        if j != i and not np.array_equal(flat[i], flat[j]):
            found.append((j, i))
    return found
