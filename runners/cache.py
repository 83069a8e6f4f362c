"""``python -m runners.cache [--dir DIR] [--prune-unused-days N]``: what the simulator-table cache holds, and pruning it.

The generalisation track's fleets keep their pools' simulator tables under
``$MORALITY_GYM_CACHE/tables`` (:mod:`morality_gym.envs.table_cache`): about 400 MB for a chain's
train pool, written again whenever the world code changes (every entry is keyed by it), and never
deleted on their own, since a long run pinned to an older commit may share the folder. This command
says what is there (how much belongs to this checkout's world code, how much to other versions,
when each was last used) and, with ``--prune-unused-days N``, removes the entries no process has
read for more than ``N`` days. Deleting the folder is always safe too: it only makes the next fleet
start slower.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from morality_gym.clitools import OneLineParser, UserError, add_debug_flag, run_cli
from morality_gym.envs.table_cache import CacheEntry, list_entries, prune
from morality_gym.generalisation.sets import table_cache_dir


def build_parser() -> argparse.ArgumentParser:
    """The command's parser (the docs' command-line reference is generated from it)."""
    parser = OneLineParser(prog="python -m runners.cache", description=__doc__.splitlines()[0].split(": ", 1)[1])
    parser.add_argument("--dir", type=Path, default=None,
                        help="the table cache folder (default: $MORALITY_GYM_CACHE/tables, the track's)")
    parser.add_argument("--prune-unused-days", type=float, default=None, metavar="N",
                        help="remove the entries not read for more than N days (0: every entry)")
    add_debug_flag(parser)
    return parser


def summary(entries: Sequence[CacheEntry], now: float) -> list[str]:
    """What a folder holds, in a few lines: sizes by world code and the range of last uses."""
    if not entries:
        return ["no entries"]
    mine = [e for e in entries if e.this_code]
    other = [e for e in entries if e.this_code is False]
    unknown = [e for e in entries if e.this_code is None]
    lines = [f"{len(entries)} entries, {_mb(entries)}",
             f"  this checkout's world code: {len(mine)} ({_mb(mine)})",
             f"  other world code: {len(other)} ({_mb(other)})"]
    if unknown:
        lines.append(f"  not recorded (written before entries named their code, or unreadable): "
                     f"{len(unknown)} ({_mb(unknown)})")
    lines.append(f"last used: {_age(now - entries[-1].last_used)} ago (newest) to "
                 f"{_age(now - entries[0].last_used)} ago (oldest)")
    return lines


def _mb(entries: Sequence[CacheEntry]) -> str:
    return f"{sum(e.size for e in entries) / 1e6:,.1f} MB"


def _age(seconds: float) -> str:
    days = max(seconds, 0.0) / 86400
    return f"{days:.1f} days" if days >= 1 else f"{max(seconds, 0.0) / 3600:.1f} hours"


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    folder = args.dir if args.dir is not None else table_cache_dir()
    if not folder.is_dir():
        raise UserError(f"{folder}: no such folder (a table cache is made by the track's fleets; pass --dir DIR)")
    if args.prune_unused_days is not None and args.prune_unused_days < 0:
        raise UserError(f"--prune-unused-days must be 0 or more, got {args.prune_unused_days:g}")
    now = time.time()
    print(f"{folder}:")
    print("\n".join(summary(list_entries(folder), now)))
    if args.prune_unused_days is not None:
        removed = prune(folder, args.prune_unused_days, now)
        print(f"removed {len(removed)} entries ({_mb(removed)}) not used for more than {args.prune_unused_days:g} days; "
              f"{len(list_entries(folder))} left")
    return 0


def cli(argv: Sequence[str]) -> int:
    return run_cli(lambda: main(argv), (), argv)


if __name__ == "__main__":
    sys.exit(cli(sys.argv[1:]))
