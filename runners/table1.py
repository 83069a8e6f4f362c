"""``python -m runners.table1 [preset=quick] [launcher=local] [results_dir=results] [protocols=[paper]]``.

Runs the Table 1 experiment (``experiment=table1``: the paper's 14 (chain, scenario) pairs, every
variant, its five learners) under each requested protocol. The ``corrected`` protocol changes only
Random, PPO-Lag and CPO, so only those are re-run under it; the leaderboard puts both tables side
by side. Every sweep is resumable: running this again finishes what is missing.

Each sweep is :func:`runners.sweep.main` with the experiment's overrides, in this process: the
same command-line path, messages and exit statuses as ``python -m runners.sweep``.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from morality_gym.clitools import run_cli, version_text
from runners.sweep import main as sweep_main

AFFECTED_BY_PROTOCOL = "[random,ppo_lag,cpo]"
PROTOCOLS = ("paper", "corrected")


def split_protocols(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """The ``protocols=[...]`` asked for (default: paper) and the other arguments, for the sweeps."""
    protocols = ["paper"]
    rest = []
    for arg in argv:
        if arg.startswith("protocols="):
            protocols = [p.strip() for p in arg.split("=", 1)[1].strip("[]").split(",") if p.strip()]
        else:
            rest.append(arg)
    return protocols, rest


def sweep_args(protocol: str, rest: Sequence[str]) -> list[str]:
    """The sweep's command line for one protocol (the corrected one re-runs only the learners it changes)."""
    args = ["experiment=table1", f"protocol={protocol}", *rest]
    if protocol == "corrected":
        args.append(f"algo={AFFECTED_BY_PROTOCOL}")
    return args


def main(argv: list[str]) -> int:
    """Each protocol's sweep in turn. A configuration error (exit 2) or an interruption stops at
    once; otherwise the worst exit status of the sweeps. ``--debug`` is passed on to the sweeps."""
    if "--version" in argv:
        print(version_text("python -m runners.table1"))
        return 0
    protocols, rest = split_protocols(argv)
    unknown = [p for p in protocols if p not in PROTOCOLS]
    if unknown:
        print(f"configuration error: protocols: unknown {unknown}; valid: paper, corrected", file=sys.stderr)
        return 2
    worst = 0
    for protocol in protocols:
        args = sweep_args(protocol, rest)
        print(f"== Table 1 sweep, protocol {protocol}: python -m runners.sweep {' '.join(args)}", file=sys.stderr, flush=True)
        code = sweep_main(args)
        if code not in (0, 1):
            return code
        worst = max(worst, code)
    return worst


if __name__ == "__main__":
    sys.exit(run_cli(lambda: main(sys.argv[1:]), (), sys.argv[1:]))
