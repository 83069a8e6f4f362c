"""A plan as a scenario file: the ordinary YAML format, laid out like the built-in files.

The format of ``docs/scenario-format.md`` stays the one source of truth: a generated dilemma is a
file a user could have written, loaded and checked by the same code. The text is written by hand,
not by a YAML library, so that its bytes depend on the plan alone (a split's digest is a digest of
these bytes) and so that it reads like the built-in files: pictures side by side, one variant a line.
"""

from __future__ import annotations

from collections.abc import Mapping

from morality_gym.generator.grammar import GRAMMAR_VERSION, Plan
from morality_gym.world.layout import UTILITY_TYPES

Bounds = Mapping[str, tuple[int, int]]
#: The scenario-wide utilities, in the order the built-in files list them.
SCENARIO_UTILITIES = ("n_harm", "n_human_harm", "n_robot_harm", "n_animal_harm", "n_weighted_harm")


def _span(bounds: tuple[int, int]) -> str:
    return f"[{bounds[0]}, {bounds[1]}]"


def _layout(plan: Plan) -> list[str]:
    width = len(plan.floor[0])
    pad = max(width, len("things")) + 2
    lines = ["layout: |", "  " + "".join(label.ljust(pad) for label in ("floor", "rails")) + "things"]
    for floor, rails, things in zip(plan.floor, plan.rails, plan.things):
        lines.append("  " + floor.ljust(pad) + rails.ljust(pad) + things)
    return lines


def _switches(plan: Plan) -> list[str]:
    if not plan.switches:
        return []
    lines = ["", "switches:"]
    for (r, c), exits, lever in plan.switches:
        lines.append(f"  - {{at: [{r}, {c}], exits: [{', '.join(exits)}], lever: {lever}}}")
    lines.append(f"levers_loop: {'true' if plan.levers_loop else 'false'}")
    return lines


def _variant_line(plan: Plan, index: int, bounds: Bounds) -> str:
    variant = plan.variants[index]
    groups = ", ".join(f"{kind} {amount}" for kind, amount in variant.groups)
    spans = ", ".join(f"{key}: {_span(bounds[key])}" for key in UTILITY_TYPES if tuple(bounds[key]) != (0, 0))
    return (f"  {variant.name}: {{characters: [{groups}], bounds: {{{spans}}}, "
            f"relevant: [{', '.join(variant.relevant)}]}}")


def scenario_text(plan: Plan, variant_bounds: Mapping[str, Bounds], scenario_bounds: Bounds) -> str:
    """The scenario file of ``plan``, with each variant's exact bounds of the three type utilities
    (``variant_bounds[name]``) and the scenario-wide ``utility_bounds``."""
    lines = [
        f"# {plan.name}: a generated MoralityGym trolley dilemma (data, not code): seed {plan.seed} of the",
        f"# generator's grammar version {GRAMMAR_VERSION}, written by `python -m morality_gym generate`.",
        "# The format is docs/scenario-format.md; docs/how-to/generate-dilemmas.md explains the generator.",
        f"name: {plan.name}",
        "summary: >-",
        f"  {plan.summary}",
        f"rewards: {{step: -1, landmark: 100, agent_harmed: {plan.agent_harmed_reward}}}",
        "landmark_mode: enter",
        "trolley_start: episode_start",
        "",
        *_layout(plan),
        *_switches(plan),
        "",
        "characters:" if plan.pushable else "characters: {}",
        *(f"  {i}: {{pushable: {'true' if can else 'false'}}}" for i, can in enumerate(plan.pushable, start=1)),
        "",
        "utility_bounds: {" + ", ".join(f"{k}: {_span(scenario_bounds[k])}" for k in SCENARIO_UTILITIES) + "}",
        "",
        "variants:",
        *(_variant_line(plan, i, variant_bounds[v.name]) for i, v in enumerate(plan.variants)),
    ]
    return "\n".join(lines) + "\n"
