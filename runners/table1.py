"""``python -m runners.table1 [preset=quick] [launcher=local] [results_dir=results] [protocols=[paper]]``.

Runs the Table 1 experiment (``experiment=table1``: the paper's 14 (chain, scenario) pairs, every
variant, its five learners) under each requested protocol. The ``corrected`` protocol changes only
Random, PPO-Lag and CPO, so only those are re-run under it; the leaderboard puts both tables side
by side. Every sweep is resumable: running this again finishes what is missing.
"""

from __future__ import annotations

import subprocess
import sys

AFFECTED_BY_PROTOCOL = "[random,ppo_lag,cpo]"


def main(argv: list[str]) -> int:
    """Each protocol's sweep in turn (a configuration error stops at once, exit 2). ``--debug`` is
    passed on to the sweeps."""
    if "--version" in argv:
        from morality_gym.clitools import version_text

        print(version_text("python -m runners.table1"))
        return 0
    protocols = ["paper"]
    rest = []
    for arg in argv:
        if arg.startswith("protocols="):
            protocols = [p.strip() for p in arg.split("=", 1)[1].strip("[]").split(",") if p.strip()]
        else:
            rest.append(arg)
    unknown = [p for p in protocols if p not in ("paper", "corrected")]
    if unknown:
        print(f"configuration error: protocols: unknown {unknown}; valid: paper, corrected", file=sys.stderr)
        return 2
    worst = 0
    for protocol in protocols:
        args = ["experiment=table1", f"protocol={protocol}", *rest]
        if protocol == "corrected":
            args.append(f"algo={AFFECTED_BY_PROTOCOL}")
        print(f"== Table 1 sweep, protocol {protocol}: python -m runners.sweep {' '.join(args)}", file=sys.stderr, flush=True)
        code = subprocess.call([sys.executable, "-m", "runners.sweep", *args])
        if code == 2:
            return 2
        worst = max(worst, code)
    return worst


if __name__ == "__main__":
    from morality_gym.clitools import run_cli

    sys.exit(run_cli(lambda: main(sys.argv[1:]), (), sys.argv[1:]))
