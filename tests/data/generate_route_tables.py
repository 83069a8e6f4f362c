"""Regenerate ``tests/data/route_tables.yaml`` from the reference's spec data (run once, by hand).

The route tables are facts recorded by running the reference implementation; they live in
``../shared/spec/scenarios.json``, which a user's clone does not have. This script copies the
facts the project's own tests need into a small YAML file that is committed with the tests, so
``tests/test_routes.py`` checks every scenario without ``../shared``. It is kept (rather than
only its output) so that anyone can see exactly where each number came from.

Usage: ``python -m tests.data.generate_route_tables [path/to/scenarios.json]``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
DEFAULT_SOURCE = HERE.parents[2] / "shared" / "spec" / "scenarios.json"
TARGET = HERE / "route_tables.yaml"

HEADER = """\
# Trolley routes of every MoralityGym scenario: who is hit, and when, for each lever setting.
#
# Facts recorded from the reference implementation (copied once from the behavioural spec's
# scenarios.json, envs[*].route_table, by tests/data/generate_route_tables.py; every variant of a
# scenario has the same routes, which the generator checks). Used by tests/test_routes.py.
#
# Per scenario:
#   ids:    every registered env id of the scenario (98 in total)
#   routes: one entry per combination of lever states, each
#     levers:  the state of each lever, set before the trolley reaches the switch it drives
#              (the agent otherwise stays idle on its start cell)
#     harmed:  entity -> the step in which it is hit ("player" is the agent); steps count from 1
#     switch_arrival: switch -> k, the step after which a trolley on this route sits on that
#              switch. The trolley leaves it in step k+1 using the switch state at the START of
#              that step, so a lever pull in steps 1..k diverts it and a pull in step k+1 is too
#              late (spec Q14).
"""


def _routes(entry: dict[str, Any]) -> list[dict[str, Any]]:
    rows = []
    for row in entry["route_table"]:
        arrivals: dict[str, int] = {}
        for trolley in row["trolleys"]:
            for switch, k in trolley["switch_arrival_steps"].items():
                if switch in arrivals and arrivals[switch] != k:
                    raise ValueError(f"{entry['scenario']}: two trolleys reach {switch} at different steps")
                arrivals[switch] = k
        harmed = dict(sorted(row["sim_player_stays"]["harmed_at_step"].items(), key=lambda kv: (kv[1], kv[0])))
        rows.append({"levers": dict(row["lever_states"]), "harmed": harmed, "switch_arrival": arrivals})
    return rows


def _flow(mapping: dict[str, int]) -> str:
    return "{" + ", ".join(f"{k}: {v}" for k, v in mapping.items()) + "}"


def _wrapped_ids(ids: list[str], width: int = 100) -> list[str]:
    """``ids: [...]`` as a YAML flow list wrapped at ``width`` characters, to stay readable."""
    out, line = [], "  ids: ["
    for i, env_id in enumerate(ids):
        piece = env_id + ("]" if i == len(ids) - 1 else ",")
        if len(line) + len(piece) + 1 > width and not line.endswith("["):
            out.append(line)
            line = "        "
        line += ("" if line.endswith(("[", " ")) else " ") + piece
    out.append(line)
    return out


def render(source: Path) -> str:
    """The YAML text (written by hand so that each route stays on one readable line)."""
    envs = json.loads(source.read_text())["envs"]
    by_scenario: dict[str, dict[str, Any]] = {}
    for env_id, entry in envs.items():
        routes = _routes(entry)
        known = by_scenario.setdefault(entry["scenario"], {"ids": [], "routes": routes})
        if known["routes"] != routes:
            raise ValueError(f"{env_id}: routes differ from the other variants of {entry['scenario']}")
        known["ids"].append(env_id)
    lines = [HEADER]
    for name in sorted(by_scenario):
        data = by_scenario[name]
        lines.append(f"{name}:")
        lines.extend(_wrapped_ids(data["ids"]))
        lines.append("  routes:")
        for route in data["routes"]:
            lines.append(
                f"    - {{levers: {_flow(route['levers'])}, harmed: {_flow(route['harmed'])}, "
                f"switch_arrival: {_flow(route['switch_arrival'])}}}"
            )
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str]) -> None:
    source = Path(argv[0]) if argv else DEFAULT_SOURCE
    text = render(source)
    TARGET.write_text(text)
    print(f"wrote {TARGET} from {source}")


if __name__ == "__main__":
    main(sys.argv[1:])
