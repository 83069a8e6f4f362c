"""Prompts a small model can afford (issue 49): the compact prompt, the answer formats, the prompt's
size on the leaderboard. No model runs here: a scripted chat function plays (tests/test_llm_local.py
runs the real one)."""

from __future__ import annotations

import asyncio
import json

import pandas as pd
import pytest

from morality_gym import ACTION_NAMES
from morality_gym.envs.trolley import TrolleyEnv
from morality_gym.evaluation.oracle import oracle
from morality_gym.llm.agent import EARLIER_HEADING, Message, Reply, compact_message, parse_answer, play_episode
from morality_gym.llm.episode import score_episode
from morality_gym.llm.settings import AgentSettings, SettingsError
from morality_gym.llm.text import ANSWER_INSTRUCTIONS, system_prompt
from morality_gym.norms.metric import bind_chain

ENV = "SwitchStandard-HumanA-v1"


def _script(answers: list[str]):  # type: ignore[no-untyped-def]
    """A chat function answering ``answers[k]`` at call ``k`` (the last repeats), keeping what it was sent."""
    seen: list[list[Message]] = []

    async def chat(messages: list[Message]) -> Reply:
        seen.append(messages)
        return Reply(answers[min(len(seen) - 1, len(answers) - 1)], input_tokens=10 * len(seen), output_tokens=1)

    return chat, seen


@pytest.mark.parametrize(("mode", "text", "expected"), [
    ("number", "6", "INTERACT"),
    ("number", " 3.", "LEFT"),
    ("number", "I choose 1", "UP"),
    ("number", "1 or 2", None),  # two different numbers: unreadable
    ("number", "7", None),
    ("number", "12", None),  # not a digit on its own
    ("number", "RIGHT", "RIGHT"),  # the word instead of its number is still read
    ("bare", "LEFT", "LEFT"),
    ("bare", "left.", "LEFT"),
    ("bare", "The lever is down.", None),  # a sentence, not the word alone (parse_action would read DOWN)
    ("bare", '"Up"', "UP"),
    ("bare", "ACTION: stay", "STAY"),
    ("word", "The lever is down.", "DOWN"),  # word mode keeps parse_action's one-word rule
    ("bare", "The episode ends when you have reached the", None),
    ("word", "ACTION: STAY", "STAY"),
    ("json", '{"action": "INTERACT"}', "INTERACT"),
    ("json", '{"action":"left"}', "LEFT"),
    ("json", '{"action": "JUMP"}', None),
    ("json", "RIGHT", "RIGHT"),
])
def test_parse_answer_reads_each_format(mode: str, text: str, expected: str | None) -> None:
    assert parse_answer(text, mode) == expected


def test_each_answer_mode_asks_in_its_own_words() -> None:
    world = TrolleyEnv(ENV).world
    prompts = {mode: system_prompt(world, "named", None, mode) for mode in ANSWER_INSTRUCTIONS}
    assert prompts["number"].endswith("1 UP, 2 DOWN, 3 LEFT, 4 RIGHT, 5 STAY, 6 INTERACT.")
    assert prompts["bare"].endswith("answer with one word only, the action you choose: UP, DOWN, LEFT, RIGHT, STAY or INTERACT.")
    assert "ACTION: <one of" in prompts["word"] and "act tool" in prompts["tool"]
    assert prompts["json"].endswith('{"action": "<one of UP, DOWN, LEFT, RIGHT, STAY, INTERACT>"}.')
    with pytest.raises(SettingsError, match="answer modes: word, tool, bare, number, json"):
        AgentSettings(answer="letter")
    with pytest.raises(SettingsError, match="prompt modes: transcript, compact"):
        AgentSettings(prompt="short")
    with pytest.raises(SettingsError, match="recent must be >= 0"):
        AgentSettings(prompt="compact", recent=-1)


def test_a_number_playing_agent_scores_the_oracles_best() -> None:
    best = oracle(ENV, "Utility").best
    chat, _ = _script([str(a + 1) for a in best.actions])
    log = asyncio.run(play_episode(ENV, chat, AgentSettings(answer="number", prompt="compact")))
    metric, _ = score_episode(bind_chain("Utility", ENV), log.outcome)
    assert metric == pytest.approx(best.metric) == 1.0
    assert log.actions == [ACTION_NAMES[a] for a in best.actions] and log.unreadable == 0


def test_the_compact_prompt_is_one_bounded_message_with_the_recent_events() -> None:
    """A 201-step episode's every prompt is the system message and one user message no longer than
    the view plus ``recent`` event lines; the transcript prompt grows with the window instead."""
    chat, seen = _script(["UP"])  # up into the wall, the whole episode: it never ends early
    log = asyncio.run(play_episode(ENV, chat, AgentSettings(prompt="compact", recent=2, answer="bare")))
    assert len(log.actions) == 201 and log.outcome.truncated
    assert all([m.role for m in msgs] == ["system", "user"] for msgs in seen)
    texts = [msgs[1].content for msgs in seen]
    assert not any(t.startswith("Step ") for t in texts)  # no step counter: a repeated state reads the same
    assert EARLIER_HEADING not in texts[0]
    def happened(text: str) -> str:
        return next(line for line in text.splitlines() if line.startswith("What happened: ")).removeprefix("What happened: ")

    assert texts[3].splitlines()[:3] == [EARLIER_HEADING, f"- {happened(texts[1])}", f"- {happened(texts[2])}"]
    earlier = [t.split("\n\n")[0] for t in texts[3:] if t.startswith(EARLIER_HEADING)]
    assert all(e.count("\n- ") == 2 for e in earlier)  # never more than ``recent`` event lines
    assert texts[-1] == texts[-2]  # the trolley has stopped and the agent is stuck: the prompt repeats
    longest = max(len(msgs[0].content) + len(msgs[1].content) for msgs in seen)
    assert log.max_prompt_chars == longest and log.max_input_tokens == 10 * len(seen)
    chat, _ = _script(["ACTION: UP"])
    transcript = asyncio.run(play_episode(ENV, chat, AgentSettings(window=8, max_steps=20)))
    assert transcript.max_prompt_chars > 3 * log.max_prompt_chars


def test_compact_message_lists_the_earlier_events_above_the_view() -> None:
    view = "Step 4 (the episode stops after step 201).\nWhat happened: You moved up.\nMap:\n..."
    assert compact_message(view, []) == "What happened: You moved up.\nMap:\n..."
    assert compact_message(view, ["You moved left.", "You stayed where you were."]) == (
        f"{EARLIER_HEADING}\n- You moved left.\n- You stayed where you were.\n\nWhat happened: You moved up.\nMap:\n...")


def test_the_leaderboard_entry_shows_parse_and_fallback_rates_tokens_and_seconds() -> None:
    from leaderboard.web.llm_entries import llm_entries

    def row(calls: int, unreadable: int, fallbacks: int, length: int, seconds: float, max_in: int | None) -> dict:
        config = {"policy": {"kind": "llm", "model": "local/smollm2-135m", "framing": "named", "answer": "bare",
                             "prompt": "compact", "recent": 3, "temperature": "provider default",
                             "llm_preset": "paid", "episodes_per_variant": 3},
                  "provenance": {"calls": calls, "unreadable": unreadable, "fallbacks": fallbacks,
                                 "input_tokens": 100 * calls, "output_tokens": 2 * calls, "max_input_tokens": max_in}}
        return {"algo": "submitted", "learner": "SmolLM2", "protocol": "paper", "preset": "quick", "chain": "Utility",
                "mean_length": length, "wall_time_s": seconds, "config": json.dumps(config)}

    [entry] = llm_entries(pd.DataFrame([row(10, 4, 2, 8, 4.0, 700), row(30, 0, 0, 12, 6.0, 650)]))
    assert entry["parse_rate"] == pytest.approx(1 - 4 / 40, abs=1e-3)
    assert entry["fallback_rate"] == pytest.approx(2 / 20, abs=1e-3)
    assert entry["tokens_per_step"] == round(102 * 40 / 20) and entry["seconds_per_step"] == 0.5
    assert entry["max_input_tokens"] == 700 and entry["prompt"] == "compact"
    assert entry["episodes_source"] == "set by --episodes"  # 3 per variant is not the paid preset's 5
