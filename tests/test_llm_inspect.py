"""Language-model agents through Inspect AI, end to end and offline: Inspect's mock model provider
(``mockllm``) answers from a script, Inspect runs the task, scores every episode with the morality
metric and writes its log; ``python -m leaderboard.llm`` turns the log into a leaderboard entry."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest

pytest.importorskip("inspect_ai", reason="the llm extra (make test installs it: pip install -e '.[dev,llm]')")

from inspect_ai import eval as inspect_eval
from inspect_ai.log import EvalLog
from inspect_ai.model import ModelOutput, ModelUsage, get_model

from morality_gym import ACTION_NAMES, TrolleyEnv, env_ids, get_chain
from morality_gym.envs.registry import UnknownEnvError
from morality_gym.evaluation.montecarlo import evaluate_sequential
from morality_gym.evaluation.oracle import oracle
from morality_gym.llm.inspect_tasks import EPISODE_KEY, morality_gym_task, select_env_ids
from morality_gym.llm.settings import SettingsError
from morality_gym.norms.metric import bind_chain
from morality_gym.paper import table1
from morality_gym.results.schema import run_files

REPO = Path(__file__).resolve().parent.parent
ENV = "SwitchStandard-HumanA-v1"


def scripted(answers: list[str], tool: bool = False):  # type: ignore[no-untyped-def]
    """Inspect's mock model answering ``answers[k]`` at step ``k`` (read from the latest observation)."""

    def answer(messages, tools, tool_choice, config):  # type: ignore[no-untyped-def]
        seen = [m.text for m in messages if m.role in ("user", "tool") and m.text.startswith("Step ")]
        step = int(re.match(r"Step (\d+)", seen[-1]).group(1))
        text = answers[min(step, len(answers) - 1)]
        if tool:
            out = ModelOutput.for_tool_call(model="mockllm/model", tool_name="act", tool_arguments={"action": text})
        else:
            out = ModelOutput.from_content(model="mockllm/model", content=text)
        out.usage = ModelUsage(input_tokens=50, output_tokens=5, total_tokens=55)
        return out

    return get_model("mockllm/model", custom_outputs=answer, memoize=False)


def run(task, model, tmp_path: Path) -> EvalLog:  # type: ignore[no-untyped-def]
    [log] = inspect_eval(task, model=model, log_dir=str(tmp_path / "logs"), display="none")
    assert log.status == "success", log.error
    return log


def means(log: EvalLog) -> dict[str, float]:
    return {s.name: s.metrics["mean"].value for s in log.results.scores if "mean" in s.metrics}


@pytest.mark.parametrize("tool", [False, True], ids=["word", "tool-call"])
def test_a_scripted_model_that_pulls_the_lever_once_scores_the_oracles_best(tmp_path: Path, tool: bool) -> None:
    best = oracle(ENV, "Utility").best
    assert [ACTION_NAMES[a] for a in best.actions].count("INTERACT") == 1
    words = [ACTION_NAMES[a] for a in best.actions]
    answers = words if tool else [f"The lever is next to me.\nACTION: {w}" for w in words]
    task = morality_gym_task("Utility", env=ENV, episodes=3, answer="tool" if tool else "word")
    log = run(task, scripted(answers, tool), tmp_path)
    assert means(log)["metric"] == pytest.approx(best.metric) == 1.0
    for name, value in best.functions.items():
        assert means(log)[f"mf_{name}"] == pytest.approx(value)
    assert len(log.samples) == 3 and [s.metadata["seed"] for s in log.samples] == [41, 42, 43]
    for sample in log.samples:
        record = sample.store[EPISODE_KEY]
        assert record["actions"] == words and record["fallbacks"] == 0
        assert record["calls"] == len(words) and record["input_tokens"] == 50 * len(words)
        roles = [m.role for m in sample.messages]
        assert roles[0] == "system" and roles.count("assistant") == len(words)
        if tool:
            assert roles.count("tool") == len(words) and sample.messages[2].tool_calls[0].arguments == {"action": "INTERACT"}


def test_garbage_answers_hit_the_retry_limit_and_the_counted_fallback(tmp_path: Path) -> None:
    # A short horizon (8): the trolley still hits the group (step 6), the agent never reaches the landmark.
    task = morality_gym_task("Utility", env=ENV, episodes=2, max_steps=8, max_retries=2)
    log = run(task, scripted(["I would rather not say."]), tmp_path)
    # 9 steps (truncated on step max_steps + 1), each 1 + 2 retries, then STAY.
    stay = evaluate_sequential(lambda obs: 4, TrolleyEnv(ENV, max_steps=8), bind_chain("Utility", ENV), 1)
    assert means(log)["metric"] == pytest.approx(stay.metric)
    for sample in log.samples:
        score = sample.scores["morality_score"]
        assert (score.metadata["calls"], score.metadata["unreadable"], score.metadata["fallbacks"]) == (27, 27, 9)
        assert sample.store[EPISODE_KEY]["actions"] == ["STAY"] * 9 and sample.store[EPISODE_KEY]["truncated"]
        assert sum("STAY was played instead" in m.text for m in sample.messages if m.role == "user") == 9


def test_inspects_mean_is_the_monte_carlo_estimate_over_the_variants(tmp_path: Path) -> None:
    """One episode per variant of SwitchStandard: Inspect's mean of ``metric`` (and of each ``mf_``)
    equals the mean over variants of the Monte-Carlo evaluation of the same behaviour."""
    words = ["ACTION: INTERACT", "ACTION: LEFT", "ACTION: LEFT", "ACTION: UP"]
    log = run(morality_gym_task("Utility", scenario="SwitchStandard", episodes=1), scripted(words), tmp_path)
    ids = env_ids("SwitchStandard")
    assert sorted(s.metadata["env_id"] for s in log.samples) == sorted(ids)
    results = []
    for env_id in ids:
        step = iter(range(10_000))
        results.append(evaluate_sequential(lambda obs, step=step: [5, 2, 2, 0][min(next(step), 3)], TrolleyEnv(env_id),
                                           bind_chain("Utility", env_id), 1))
    assert means(log)["metric"] == pytest.approx(sum(r.metric for r in results) / len(results))
    for norm in get_chain("Utility").norm_names:
        assert means(log)[f"mf_{norm}"] == pytest.approx(sum(r.functions[norm] for r in results) / len(results))


def test_task_arguments_select_and_check(tmp_path: Path) -> None:
    chain = get_chain("DualProcess")
    dp_scenarios = [row.scenario for row in table1() if row.chain == "DualProcess"]
    assert dp_scenarios and select_env_ids(chain) == [e for s in dp_scenarios for e in env_ids(s)]
    assert select_env_ids(get_chain("Utility"), scenario="SwitchStandard", variant="HumanA,HumanB") == [
        "SwitchStandard-HumanA-v1", "SwitchStandard-HumanB-v1"]
    with pytest.raises(UnknownEnvError, match="SwitchStandard"):
        select_env_ids(chain, scenario="SwitchStandrd")
    with pytest.raises(UnknownEnvError, match="HumanZ"):
        select_env_ids(chain, scenario="SwitchStandard", variant="HumanZ")
    with pytest.raises(SettingsError, match="did you mean ranked"):
        morality_gym_task("Utility", env=ENV, framing="rankd")
    task = morality_gym_task("Utility", env=ENV, preset="paid")
    assert len(task.dataset) == 5 and task.metadata["morality_gym"]["episodes"] == 5


def _cli(*args: str, cwd: Path = REPO) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "leaderboard.llm", *args], cwd=cwd, check=False,
                          capture_output=True, text=True, timeout=600)


def test_the_mock_run_lands_on_the_leaderboard_beside_the_baselines(tmp_path: Path) -> None:
    from tests.leaderboard_data import make_results

    results, site = tmp_path / "results", tmp_path / "site"
    make_results(results)
    script = tmp_path / "levers.txt"
    script.write_text("ACTION: RIGHT\nACTION: RIGHT\nACTION: RIGHT\nACTION: INTERACT\nACTION: LEFT\nACTION: LEFT\n"
                      "ACTION: INTERACT\nACTION: INTERACT\nACTION: LEFT\nACTION: LEFT\nACTION: LEFT\nACTION: UP\n")
    args = ["--model", "mockllm/model", "--script", str(script), "--name", "Mock LLM", "--chain", "Utility",
            "--scenario", "Switch5", "--results", str(results), "--preset", "quick", "--log-dir", str(tmp_path / "logs"),
            "--display", "none"]
    out = _cli("run", *args)
    assert out.returncode == 0, out.stderr
    assert "Utility: 35 episode(s)" in out.stdout and "wrote 35 run(s)" in out.stdout
    [log] = sorted((tmp_path / "logs").glob("*.eval"))
    again = _cli("import", str(log), "--name", "Mock LLM", "--results", str(results), "--preset", "quick")
    assert again.returncode == 0 and "wrote 0 run(s), 35 already present" in again.stdout
    rows = [pq.read_table(p).to_pandas() for p in run_files(results)]
    mine = [r for r in rows if r["learner"].iloc[0] == "Mock LLM"]
    assert len(mine) == 35 and all(r["eval_episodes"].iloc[0] == 1 for r in mine)
    assert sorted({int(r["seed"].iloc[0]) for r in mine}) == [41, 42, 43, 44, 45]
    built = subprocess.run([sys.executable, "-m", "leaderboard.build", "--results", str(results), "--site", str(site),
                            "--no-reference"], cwd=REPO, check=False, capture_output=True, text=True, timeout=600)
    assert built.returncode == 0, built.stderr
    html = (site / "index.html").read_text()
    row = re.search(r'<tr data-sweep="paper-quick" data-chain="Utility" data-scenario="Switch5" data-learner="Mock LLM".*?</tr>',
                    html, re.DOTALL)
    assert row and "badge submitted" in row.group(0) and "35/35" in row.group(0)
    assert re.search(r"\[0\.9\d\d, 0\.9\d\d\]", row.group(0))  # an interval over the episodes
    assert 'data-learner="PPO Shaped"' in html and 'data-scenario="Switch5"' in html
    entry = re.search(r'<tr data-llm-entry="Mock LLM">.*?</tr>', html, re.DOTALL).group(0)
    assert "mockllm/model" in entry and "framing named" in entry and "5 (paid)" in entry and str(log) in entry
    assert "temperature provider default" in entry
    assert '<td class="num">12.0</td>' in entry  # calls per episode: the 12 steps of the script, no retries


def test_the_temperature_is_the_tasks_else_inspects_and_is_recorded(tmp_path: Path) -> None:
    from leaderboard.llm import read_episodes

    calls: list[tuple[float | None, int | None]] = []

    def answer(messages, tools, tool_choice, config):  # type: ignore[no-untyped-def]
        calls.append((config.temperature, config.seed))
        out = ModelOutput.from_content(model="mockllm/model", content="ACTION: STAY")
        out.usage = ModelUsage(input_tokens=1, output_tokens=1, total_tokens=2)
        return out

    model = get_model("mockllm/model", custom_outputs=answer, memoize=False)
    task = morality_gym_task("Utility", env=ENV, episodes=2, max_steps=6, seed=7)
    [log] = inspect_eval(task, model=model, log_dir=str(tmp_path / "a"), display="none", temperature=0.3)
    assert set(calls) == {(0.3, 7), (0.3, 8)}  # Inspect's --temperature; episode k asks for seed + k
    assert {e.record["settings"]["temperature"] for e in read_episodes(Path(log.location))[0]} == {0.3}
    calls.clear()
    task = morality_gym_task("Utility", env=ENV, episodes=1, max_steps=6, temperature=0.0)
    [log] = inspect_eval(task, model=model, log_dir=str(tmp_path / "b"), display="none", temperature=0.3)
    assert set(calls) == {(0.0, 41)}  # the task's setting wins
    assert read_episodes(Path(log.location))[0][0].record["settings"]["temperature"] == 0.0


@pytest.mark.parametrize("args,message", [
    (["run", "--model", "mockllm/model", "--name", "x"], "needs --script FILE"),
    (["run", "--model", "openai/gpt-4o", "--script", "a.txt", "--name", "x"], "use it with --model mockllm/model"),
    (["run", "--model", "mockllm/model", "--script", "no/such.txt", "--name", "x"], "cannot read it"),
    (["run", "--model", "mockllm/model", "--script", "examples/llm/lever_once.txt", "--name", "PPO"], "name of a baseline"),
    (["import", "no/such.eval", "--name", "x"], "no such Inspect log file"),
    (["run", "--model", "mockllm/model", "--script", "examples/llm/lever_once.txt", "--name", "x",
      "--scenario", "SwitchStandrd"], "SwitchStandard"),
])
def test_bad_input_is_one_line_exit_2(tmp_path: Path, args: list[str], message: str) -> None:
    out = _cli(*args, "--results", str(tmp_path / "results"), "--log-dir", str(tmp_path / "logs")) if args[0] == "run" \
        else _cli(*args, "--results", str(tmp_path / "results"))
    assert out.returncode == 2, out.stderr
    assert message in out.stderr and len(out.stderr.strip().splitlines()) == 1 and "Traceback" not in out.stderr
    assert not (tmp_path / "results").exists() or run_files(tmp_path / "results") == []
