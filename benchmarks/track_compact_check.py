"""Does the compact observation tell apart every state of a chain's train pool that the grid does?

Why: the track's fleets read the compact observation (:mod:`morality_gym.world.compact_observe`),
a fixed sign projection of the grid. A projection can merge two distinct grids, and a policy could
then not act differently in them. It was checked on the Utility v2 train pool (0 collisions,
docs/how-to/generalisation-track.md); this checks any chain's pool, DualProcess's included.

Every reachable state of every env id of the chain's v2 ``train`` pool is encoded as its grid and
compact observation, one env id at a time (the whole pool's grids would be gigabytes): a compact
observation seen before with another grid is a collision. Grids and compact observations are
compared by BLAKE2b-128 digests (a digest collision is ~2**-64 likely over these counts).

    nice -n 19 python -m benchmarks.track_compact_check --chain DualProcess

Prints one line per 100 env ids, then the counts: env ids, states, distinct grids, collisions.
"""

from __future__ import annotations

import argparse
import hashlib
import time

from morality_gym.envs.registry import state_graph
from morality_gym.generalisation.selection import read_manifest
from morality_gym.generator.splits import load_split
from morality_gym.world.compact_observe import compact_from_grid
from morality_gym.world.grid_observe import grid_table


def _digest(data: bytes) -> bytes:
    return hashlib.blake2b(data, digest_size=16).digest()


def check(chain: str, limit: int | None = None) -> dict[str, int]:
    """Counts over the chain's v2 train pool (its first ``limit`` env ids, if given)."""
    load_split("train")  # registers the generated dilemmas
    env_ids = read_manifest("train").env_ids(chain)[:limit]
    grid_of: dict[bytes, bytes] = {}  # compact digest -> the first grid digest seen with it
    grids: set[bytes] = set()
    states = collided = 0
    t0 = time.perf_counter()
    for n, env_id in enumerate(env_ids, start=1):
        graph = state_graph(env_id)
        graph.tables()  # completes the graph: every reachable state gets its id
        table = grid_table(graph.world, list(graph.states))
        compact = compact_from_grid(table)
        for grid, row in zip(table, compact):
            g, c = _digest(grid.tobytes()), _digest(row.tobytes())
            grids.add(g)
            if grid_of.setdefault(c, g) != g:
                collided += 1
        states += len(table)
        if n % 100 == 0:
            print(f"{n} of {len(env_ids)} env ids, {states:,} states, {collided} collisions, "
                  f"{time.perf_counter() - t0:.0f} s", flush=True)
    return {"env_ids": len(env_ids), "states": states, "distinct_grids": len(grids), "collisions": collided}


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.track_compact_check", description=__doc__.splitlines()[0])
    parser.add_argument("--chain", default="DualProcess", choices=("Utility", "DualProcess"))
    parser.add_argument("--limit", type=int, default=None, help="check only the pool's first N env ids")
    args = parser.parse_args()
    counts = check(args.chain, args.limit)
    print(f"{args.chain} v2 train pool: {counts['env_ids']} env ids, {counts['states']:,} states, "
          f"{counts['distinct_grids']:,} distinct grids, {counts['collisions']} collisions")


if __name__ == "__main__":
    main()
