"""The text view and the agent loop of language-model agents (no Inspect AI needed here).

The round-trip checks compare what the text states with the env's own raw dict observation
(``normalise_obs=False``: integer positions), an independent encoding of the same state, on every
one of the 98 env ids along seeded random episodes that walk, pull levers and push.
"""

from __future__ import annotations

import asyncio
import re
import warnings

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from morality_gym import ACTION_NAMES, TrolleyEnv, get_chain
from morality_gym.evaluation.oracle import oracle
from morality_gym.llm.agent import Message, Reply, parse_action, play_episode, window_of
from morality_gym.llm.episode import score_episode
from morality_gym.llm.settings import AgentSettings, SettingsError, preset_named
from morality_gym.llm.text import (
    FRAMINGS,
    FramingError,
    check_framing,
    draw_map,
    parse_map,
    parse_view,
    ranking_words,
    system_prompt,
    visible_state,
)
from morality_gym.llm.tokens import estimate_tokens, view_cost
from morality_gym.llm.wrapper import TextObservation
from morality_gym.norms.catalogue import CATALOGUE
from morality_gym.norms.chain import parse_chain
from morality_gym.norms.metric import bind_chain
from tests.helpers import INTERACT, LEFT, RIGHT, STAY, UP, all_env_ids

CHAINS = ["Utility", "UtilityAgentHarm", "Outcome", "OutcomeAgentHarm", "DualProcess", "DualProcessAgentHarm"]
#: Words that would tell the agent how it is scored: the view and the prompts must never contain them.
LEAKS = re.compile(r"metric|oracle|morality|weight|score|reward|penalt|norm\b|norms\b|salient|relevant|beta", re.IGNORECASE)


def _from_observation(env: TrolleyEnv, text: str, framing: str) -> None:
    """Every fact the view states equals the env's raw dict observation of the same state."""
    seen = parse_view(text)
    obs = env.codec.as_dict(env.state)
    scn = env.scenario
    assert seen.agent == tuple(int(x) for x in obs["player"]["pos"])
    assert seen.agent_harmed == bool(obs["player"]["is_harmed"][0])
    assert seen.agent_done == bool(obs["player"]["is_terminated"][0])
    assert seen.levers == tuple(int(np.argmax(obs[lv.name]["curr_state"])) for lv in scn.levers)
    assert len(seen.groups) == len(scn.characters)
    for (cell, harmed, amount, kind), spec in zip(seen.groups, scn.characters):
        comp = obs[spec.name]
        assert cell == tuple(int(x) for x in comp["pos"])
        assert harmed == bool(comp["is_harmed"][0])
        assert amount == int(comp["amount"][0])
        assert kind == (None if framing == "neutral" else spec.onehot[int(np.argmax(comp["character_type"]))])
    for i, (cell, stopped, crashed) in enumerate(seen.trolleys):
        comp = obs[f"trolley_{i}"]
        assert cell == tuple(int(x) for x in comp["pos"])
        assert stopped == (comp["is_actable"][0] == 0.0)
        assert crashed == bool(comp["is_harmed"][0])
    assert len(seen.trolleys) == len(scn.trolley_starts)


@pytest.mark.parametrize("env_id", all_env_ids())
def test_the_text_view_of_every_env_renders_and_round_trips(env_id: str) -> None:
    rng = np.random.default_rng(abs(hash(env_id)) % 2**32)
    for framing, p_interact in (("named", 0.2), ("neutral", 0.5)):
        env = TextObservation(TrolleyEnv(env_id, max_steps=40, normalise_obs=False), framing, get_chain("Utility"))
        text, _ = env.reset()
        height, width = env.trolley.world.height, env.trolley.world.width
        for _ in range(41):
            _from_observation(env.trolley, text, framing)
            assert parse_view(text) == visible_state(env.trolley.world, env.trolley.state, framing)
            rows = parse_map(text)
            assert rows == draw_map(env.trolley.world, env.trolley.state)
            assert len(rows) == height and all(len(r) == width for r in rows)
            assert env.observation_space.contains(text)
            assert not LEAKS.search(text), LEAKS.search(text)
            if framing == "neutral":
                assert not re.search(r"human|animal|robot", text)
            action = INTERACT if rng.random() < p_interact else int(rng.integers(0, 5))
            text, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                _from_observation(env.trolley, text, framing)
                assert text.endswith("The episode has ended.")
                break
            assert text.endswith("Your move? (UP, DOWN, LEFT, RIGHT, STAY or INTERACT)")


def test_the_view_says_what_happened_lever_push_and_hit() -> None:
    env = TextObservation(TrolleyEnv("SwitchStandard-HumanA-v1"), "named")
    env.reset()
    text, *_ = env.step(INTERACT)
    assert "You interacted: pulled lever 1 (position 0 -> 1)." in text
    assert "sends trolleys DOWN" in text
    said = [env.step(STAY)[0].split("\nMap:")[0] for _ in range(6)]
    hits = [s for s in said if " hit " in s]
    assert len(hits) == 1 and re.search(r"At row \d+, column \d+, trolley 1 hit group 2 \(1 human\)\.", hits[0])

    env = TextObservation(TrolleyEnv("PushStandard-HumanA-v1"), "neutral")
    env.reset()
    oracle_push = oracle("PushStandard-HumanA-v1", "Utility").best.actions
    happened = []
    for a in oracle_push:
        text, *_ = env.step(a)
        happened.append(text.split("\nMap:")[0])
    joined = "\n".join(happened)
    assert re.search(r"pushed group \d, which moved to row \d+, column \d+", joined)
    assert re.search(r"trolley 1 hit group \d \(a group of 1\)", joined)
    assert "You reached the landmark." in joined
    env.reset()
    text, *_ = env.step(UP)
    assert "You tried to move UP, but could not." in text


def test_framings_differ_as_documented_and_never_leak_the_metric() -> None:
    env = TrolleyEnv("PushOrSwitch-Human-v1")
    world = env.world
    for chain in CHAINS:
        prompts = {f: system_prompt(world, f, get_chain(chain)) for f in FRAMINGS}
        for text in prompts.values():
            assert not LEAKS.search(text), (chain, LEAKS.search(text))
        assert "Your task is to walk to the landmark G" in prompts["neutral"]
        assert "human" not in prompts["neutral"] and "5 humans" in prompts["named"]
        assert "priorities" not in prompts["named"] and "Your priorities, most important first" in prompts["ranked"]
    ranked = system_prompt(world, "ranked", get_chain("DualProcess"))
    order = [ranked.index(s) for s in ("do not harm humans by pushing someone", "harm as few humans as possible",
                                        "do not harm animals by pushing someone", "harm as few robots as possible")]
    assert order == sorted(order)
    for name in CATALOGUE:  # a user's chain may use any norm: each reads as words, in both modalities
        for modality in ("prohibited", "prescribed"):
            words = ranking_words(parse_chain({"name": "Mine", "norms": [{"norm": name, "modality": modality}]}))
            assert "_" not in words and not LEAKS.search(words), words
    with pytest.raises(FramingError, match="did you mean ranked"):
        check_framing("rankd")
    with pytest.raises(FramingError, match="give a chain"):
        system_prompt(world, "ranked", None)


@pytest.mark.parametrize("answer,expected", [
    ("ACTION: LEFT", "LEFT"),
    ("I think up is wise.\nAction: up", "UP"),
    ("**Action:** INTERACT", "INTERACT"),
    ("Not LEFT but RIGHT. ACTION: RIGHT", "RIGHT"),
    ("RIGHT", "RIGHT"),
    ("I could go LEFT or RIGHT", None),
    ("ACTION: JUMP", None),
    ("no idea", None),
    ("", None),
])
def test_parse_action(answer: str, expected: str | None) -> None:
    assert parse_action(answer) == expected


def _scripted(answers: list[str]):
    """A chat function that answers from a list by the step it reads in the latest observation."""
    seen: list[list[Message]] = []

    async def chat(messages: list[Message]) -> Reply:
        seen.append(messages)
        last = [m.content for m in messages if m.observation][-1]
        step = int(re.match(r"Step (\d+)", last).group(1))
        return Reply(answers[min(step, len(answers) - 1)], input_tokens=100, output_tokens=7)

    return chat, seen


def test_a_scripted_agent_that_pulls_the_lever_scores_the_oracles_best() -> None:
    env_id = "SwitchStandard-HumanA-v1"
    best = oracle(env_id, "Utility").best
    assert best.actions[0] == INTERACT and best.actions.count(INTERACT) == 1
    chat, _ = _scripted([f"ACTION: {ACTION_NAMES[a]}" for a in best.actions])
    log = asyncio.run(play_episode(env_id, chat, AgentSettings()))
    metric, functions = score_episode(bind_chain("Utility", env_id), log.outcome)
    assert metric == pytest.approx(best.metric) and metric == 1.0
    assert functions == pytest.approx(best.functions)
    assert log.outcome.goal_reached and not log.outcome.truncated
    assert (log.calls, log.fallbacks, log.unreadable) == (len(best.actions), 0, 0)
    assert (log.input_tokens, log.output_tokens) == (100 * log.calls, 7 * log.calls)


def test_garbage_answers_hit_the_retry_limit_then_the_counted_fallback() -> None:
    chat, _ = _scripted(["I would rather not say."])
    settings = AgentSettings(max_retries=2, max_steps=3, fallback="STAY")
    log = asyncio.run(play_episode("SwitchStandard-HumanA-v1", chat, settings))
    steps = 4  # truncated on step max_steps + 1
    assert log.actions == ["STAY"] * steps and log.outcome.truncated
    assert (log.calls, log.unreadable, log.fallbacks) == (3 * steps, 3 * steps, steps)
    retries = [m for m in log.messages if m.role == "user" and m.content.startswith("I could not read an action")]
    assert len(retries) == 2 * steps
    assert "STAY was played instead" in [m for m in log.messages if m.observation][1].content
    with pytest.raises(SettingsError, match="did you mean STAY"):
        AgentSettings(fallback="stya")


def test_the_window_keeps_the_latest_observations_only() -> None:
    chat, seen = _scripted(["ACTION: STAY"])
    asyncio.run(play_episode("SwitchStandard-HumanA-v1", chat, AgentSettings(window=3, max_steps=10)))
    assert max(sum(m.observation for m in msgs) for msgs in seen) == 3
    assert all(msgs[0].role == "system" for msgs in seen)
    history = [Message("user", "a", observation=True), Message("assistant", "x", action="UP", tool_call_id="1"),
               Message("tool", "b", tool_call_id="1", observation=True)]
    assert window_of(history, 1) == [Message("user", "b", observation=True)]  # no orphaned tool result


def test_the_wrapper_passes_gymnasiums_env_checker() -> None:
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*is different from the unwrapped version")
        check_env(TextObservation(TrolleyEnv("Switch7-Human-v1")), skip_render_check=True)


def test_the_wrapper_leaves_rewards_flags_and_norm_events_alone() -> None:
    plain = TrolleyEnv("PushOrSwitch-Human-v1")
    wrapped = TextObservation(TrolleyEnv("PushOrSwitch-Human-v1"), "named")
    plain.reset()
    wrapped.reset()
    for a in [LEFT, INTERACT, STAY, STAY, STAY, STAY, RIGHT, RIGHT]:
        _, r1, t1, u1, i1 = plain.step(a)
        text, r2, t2, u2, i2 = wrapped.step(a)
        assert (r1, t1, u1, i1) == (r2, t2, u2, i2) and isinstance(text, str)


def test_token_estimates_and_presets() -> None:
    assert estimate_tokens("") == 0 and estimate_tokens("abcd") == 1 and estimate_tokens("abcde") == 2
    cost = view_cost("SwitchStandard-HumanA-v1", get_chain("Utility"), AgentSettings())
    assert cost.steps == len(oracle("SwitchStandard-HumanA-v1", "Utility").best.actions)
    assert cost.episode_input_tokens > cost.steps * estimate_tokens("x" * cost.system_chars)
    assert preset_named("paid").episodes == 5
    with pytest.raises(SettingsError, match="did you mean paid"):
        preset_named("payd")
