"""The rule kernel's state encoding: typed flags per entity, plain ints in the state.

Each entity kind has its own ``IntFlag`` (:mod:`morality_gym.world.rules`), but the state keeps
every flag word a plain ``int``: the memoised state graph hashes states, observations read them,
and IntFlag arithmetic is far slower. These tests pin both halves of that bargain, and the shared
bit positions that the renderers and the text view rely on when they test any entity's word.
"""

from __future__ import annotations

from morality_gym.envs.registry import parse_env_id
from morality_gym.world.graph import StateGraph
from morality_gym.world.observe import ObservationCodec
from morality_gym.world.rules import (
    AGENT_FOUND,
    AGENT_HARMED,
    AGENT_TERMINATED,
    CHARACTER_HARMED,
    CHARACTER_PUSHED,
    FOUND,
    HARMED,
    TERMINATED,
    TROLLEY_HARMED,
    TROLLEY_TERMINATED,
    AgentFlag,
    CharacterFlag,
    TrolleyFlag,
    World,
)


def test_shared_bits_agree_with_every_entity_that_has_them() -> None:
    assert HARMED == AgentFlag.HARMED == TrolleyFlag.HARMED == CharacterFlag.HARMED
    assert TERMINATED == AgentFlag.TERMINATED == TrolleyFlag.TERMINATED
    assert FOUND == AgentFlag.FOUND
    plain = {
        AGENT_HARMED: AgentFlag.HARMED,
        AGENT_TERMINATED: AgentFlag.TERMINATED,
        AGENT_FOUND: AgentFlag.FOUND,
        TROLLEY_HARMED: TrolleyFlag.HARMED,
        TROLLEY_TERMINATED: TrolleyFlag.TERMINATED,
        CHARACTER_HARMED: CharacterFlag.HARMED,
        CHARACTER_PUSHED: CharacterFlag.PUSHED,
    }
    for value, member in plain.items():
        assert type(value) is int and value == member, member


def _graph_states(env_id: str) -> list[tuple]:
    scenario, variant = parse_env_id(env_id)
    world = World(scenario, variant)
    graph = StateGraph(world, ObservationCodec(world))
    graph.expand()
    return graph.states


def test_every_flag_word_of_a_whole_state_graph_is_a_plain_int_with_known_bits() -> None:
    """PushOrSwitchSelfSacrifice reaches pushes, harm to every kind and the landmark (before and after harm)."""
    agent_bits, trolley_bits, char_bits = set(), set(), set()
    for _, agent_flags, _, chars, trolleys in _graph_states("PushOrSwitchSelfSacrifice-Human-v1"):
        words = [agent_flags, *(f for _, f, _ in chars), *(f for _, f in trolleys)]
        assert all(type(w) is int for w in words), words
        agent_bits.add(AgentFlag(agent_flags))
        trolley_bits.update(TrolleyFlag(f) for _, f in trolleys)
        char_bits.update(CharacterFlag(f) for _, f, _ in chars)
    # Harmed or at the landmark, the agent is terminated; it can be harmed after reaching the landmark.
    assert agent_bits == {
        AgentFlag(0),
        AgentFlag.HARMED | AgentFlag.TERMINATED,
        AgentFlag.FOUND | AgentFlag.TERMINATED,
        AgentFlag.HARMED | AgentFlag.TERMINATED | AgentFlag.FOUND,
    }
    # A collision harms and stops a trolley (the end of a line, TERMINATED alone, is not on this map).
    assert trolley_bits == {TrolleyFlag(0), TrolleyFlag.HARMED | TrolleyFlag.TERMINATED}
    # A harmed character was either pushed onto the rails or stood there; a pushed one may be unharmed.
    assert char_bits == {
        CharacterFlag(0),
        CharacterFlag.HARMED,
        CharacterFlag.PUSHED,
        CharacterFlag.HARMED | CharacterFlag.PUSHED,
    }
