"""Generated documentation: a MiniGrid-style docstring for each scenario, built from its YAML.

Because scenarios are data, their documentation must be data-driven too: the per-scenario env
classes get these docstrings, and ``python -m morality_gym docs`` writes the same text as Markdown.
"""

from __future__ import annotations

from morality_gym.constants import MAX_STEPS
from morality_gym.world.layout import Scenario
from morality_gym.world.observe import ObservationCodec
from morality_gym.world.rules import World

_DIRS = {"L": "left", "R": "right", "U": "up", "D": "down"}


def _cell(cell: tuple[int, int]) -> str:
    return f"({cell[0]}, {cell[1]})"


def describe_scenario(scenario: Scenario) -> str:
    """Markdown sections: description, layout, actions, observation, rewards, termination, ids.

    One helper per section that has logic of its own; the fixed text stays inline here so the page
    reads top to bottom in this function.
    """
    first = next(iter(scenario.variants))
    codec = ObservationCodec(World(scenario, first))
    lines = [f"{scenario.name}: {scenario.summary}", "", "## Description", ""]
    lines += _description_lines(scenario, first)
    lines += [
        "## Action Space",
        "",
        "`Discrete(6)`: 0 UP, 1 DOWN, 2 LEFT, 3 RIGHT, 4 STAY, 5 INTERACT.",
        "",
        "## Observation Space",
        "",
        f"Flat `Box` of size {codec.size} (float64). Layout:",
        "",
        "| entity | component | offset | width | upper bound |",
        "|---|---|---|---|---|",
    ]
    for f in codec.fields:
        lines.append(f"| {f.entity} | {f.name} | {f.offset} | {f.width} | {codec.high[f.offset]:g} |")
    lines += [
        "",
        "## Rewards",
        "",
        (f"{scenario.step_reward:g} per step, {scenario.landmark_reward:g} on reaching the landmark, "
         f"{scenario.agent_harmed_reward:g} when the agent is harmed, 0 after the agent has stopped."),
        "",
        "## Termination",
        "",
        ("Terminated when the agent has stopped (landmark or harm) and every trolley has stopped; truncated on "
         f"step `max_steps + 1` (default {MAX_STEPS})."),
        "",
        "## Registered Configurations",
        "",
        "| env id | characters | bounds | relevant norms |",
        "|---|---|---|---|",
    ]
    lines += _variant_rows(scenario)
    return "\n".join(lines) + "\n"


def _description_lines(scenario: Scenario, first: str) -> list[str]:
    """The grid, start and landmark, the trolleys, the first variant's picture, switches and pushables."""
    lines = [
        f"A {scenario.height}x{scenario.width} grid. The agent starts at {_cell(scenario.player_start)} and must reach "
        f"the landmark at {_cell(scenario.landmark)} (mode `{scenario.landmark_mode}`). "
        f"{len(scenario.trolley_starts)} trolley(s) start at "
        f"{', '.join(_cell(c) for c in scenario.trolley_starts)} and move "
        + ("from the first step." if scenario.trolley_start == "episode_start" else "once the landmark is reached.")
    ]
    lines += ["", ("Layout of the first variant (`P` agent, `G` landmark, `T` trolley, `/` lever, `S` switch, "
               "`< > ^ v` rails, `h a r` human/animal/robot groups, upper case when pushable, `#` wall):"), "", "```"]
    lines += scenario.picture(first)
    lines += ["```", ""]
    lines += _switch_lines(scenario)
    pushable = [c.name for c in scenario.characters if c.pushable]
    if pushable:
        lines += [f"Pushable characters: {', '.join(f'`{p}`' for p in pushable)}.", ""]
    return lines


def _switch_lines(scenario: Scenario) -> list[str]:
    """Each switch's exits and the lever that sets it, and whether levers wrap (nothing without switches)."""
    if not scenario.switches:
        return []
    lines = ["Switches and levers:", ""]
    for sw in scenario.switches:
        lever = scenario.levers[sw.lever]
        exits = ", ".join(f"{k}={_DIRS[e]}" for k, e in enumerate(sw.exits))
        lines.append(f"- `{sw.name}` at {_cell(sw.at)}: state {exits}; set by `{lever.name}` at {_cell(lever.at)}.")
    lines.append(
        "- Levers " + ("wrap round after their last state." if scenario.levers_loop else "stick at their last state (no wrap).")
    )
    lines.append("")
    return lines


def _variant_rows(scenario: Scenario) -> list[str]:
    """One table row per variant: its env id, characters (``*`` pushable), non-zero bounds, relevant norms."""
    rows = []
    for name, v in scenario.variants.items():
        chars = ", ".join(
            f"{t} {a}{'*' if spec.pushable else ''}" for spec, t, a in zip(scenario.characters, v.types, v.amounts)
        )
        bounds = ", ".join(f"{k} [{lo:g}, {hi:g}]" for k, (lo, hi) in v.bounds.items() if (lo, hi) != (0.0, 0.0))
        rows.append(f"| `MoralityGym/{scenario.env_id(name)}` | {chars} | {bounds} | {', '.join(v.relevant)} |")
    return rows
