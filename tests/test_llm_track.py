"""A language model on the generalisation track's unseen set (issue 49): ``python -m leaderboard.llm_track``
plays each pair once, greedily, and writes the run the track page reads, a sample named as one."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

pytest.importorskip("inspect_ai", reason="the llm extra (make test installs it: pip install -e '.[dev,llm]')")

from leaderboard import llm_track
from leaderboard.track import _learner_row, load_runs
from leaderboard.track import main as track_main
from morality_gym.generalisation.sets import EvalSet, PairValues
from morality_gym.results.track_runs import PAIRS, RESULT

#: Two built-in envs standing in for the test split's pairs (the split itself takes minutes to generate).
PAIRS_OF_SET = (PairValues("SwitchStandard-HumanA-v1", "Utility", best=1.0, worst=0.0, random=0.5),
                PairValues("PushStandard-HumanA-v1", "Utility", best=0.9, worst=0.1, random=0.4))
TEST_SET = EvalSet("test", PAIRS_OF_SET, {"split": "test", "split_digest": "d" * 64})


def _args(tmp_path: Path, *extra: str) -> object:
    script = tmp_path / "answers.txt"
    script.write_text('{"action": "UP"}\n')
    return llm_track.parse_args(["--model", "mockllm/model", "--script", str(script), "--name", "Mock UP",
                                 "--prompt", "compact", "--answer", "json", "--temperature", "0",
                                 "--results", str(tmp_path / "results"), "--log-dir", str(tmp_path / "logs"),
                                 "--display", "none", *extra])


def test_the_track_run_is_written_once_every_pair_is_played_and_resumes(tmp_path: Path) -> None:
    first = llm_track.play_set(_args(tmp_path, "--limit", "1"), "Mock UP", TEST_SET, train_pool=10, version=2)
    assert first.name == "Utility-v2-Mock-UP-submitted" and not (first / RESULT).exists()  # one of two played
    assert len((first / llm_track.PARTIAL).read_text().splitlines()) == 1
    run_dir = llm_track.play_set(_args(tmp_path), "Mock UP", TEST_SET, train_pool=10, version=2)
    assert len(list((tmp_path / "logs").glob("*.eval"))) == 2  # the first pair was not played again
    pairs = pd.read_parquet(run_dir / PAIRS)
    record = json.loads((run_dir / RESULT).read_text())
    assert list(pairs["env_id"]) == [p.env_id for p in PAIRS_OF_SET] and set(pairs["set"]) == {"test"}
    for row, pair in zip(pairs.to_dict("records"), PAIRS_OF_SET, strict=True):
        assert row["range_score"] == pytest.approx(pair.range_score(row["metric"]))
    assert record["submitted"] and record["sample"] is None and record["chain"] == "Utility"
    assert record["split_version"] == 2 and record["llm"]["model"] == "mockllm/model"
    assert record["llm"]["parse_rate"] == 1.0 and record["llm"]["episodes_per_pair"] == 1
    frame, records = load_runs(tmp_path / "results" / "track")
    assert set(frame["track"]) == {"Utility-v2"} and set(frame["learner"]) == {"Mock UP"}
    summary = pd.DataFrame([{"learner": "Mock UP", "set": "test", "mean": 0.5, "low": 0.4, "high": 0.6}])
    row = _learner_row("Mock UP", summary, records)
    assert row["budget"] == "language model mockllm/model, greedy, untrained" and row["seeds"] == "submitted"


def test_a_sample_is_fixed_by_its_seed_and_named_on_the_page(tmp_path: Path) -> None:
    many = tuple(PairValues(f"Gen{i}-HumanA-v1", "Utility", 1.0, 0.0, 0.5) for i in range(6))
    assert llm_track.sample_pairs(many, 3, 0) == [many[0], many[3], many[5]] == llm_track.sample_pairs(many, 3, 0)
    assert llm_track.sample_pairs(many, 3, 1) == [many[0], many[1], many[4]]  # another seed, another sample
    assert llm_track.sample_pairs(many, 9, 0) == list(many)
    run_dir = llm_track.play_set(_args(tmp_path, "--sample", "1"), "Mock UP", TEST_SET, train_pool=10, version=2)
    record = json.loads((run_dir / RESULT).read_text())
    assert record["sample"] == {"pairs": 1, "of": 2, "seed": 0} and record["pairs"] == 1
    summary = pd.DataFrame([{"learner": "Mock UP", "set": "test", "mean": 0.5, "low": 0.4, "high": 0.6}])
    row = _learner_row("Mock UP", summary, [record | {"run": run_dir.name}])
    assert row["seeds"] == "sample of 1 of 2 test pairs (seed 0): unseen set only"
    assert track_main(["--results", str(tmp_path / "results" / "track"), "--site", str(tmp_path / "site"),
                       "--resamples", "200"]) == 0
    page = (tmp_path / "site" / "track.html").read_text()
    assert "sample of 1 of 2 test pairs (seed 0): unseen set only" in page and "language model mockllm/model" in page


@pytest.mark.parametrize(("option", "why"), [(["--temperature", "0.7"], "--temperature 0.7: the track holds exact"),
                                             (["--episodes", "3"], "--episodes 3: one episode per pair"),
                                             (["--sample", "0"], "--sample 0: give a positive")])
def test_a_sampling_model_or_a_bad_count_is_one_line_exit_2(tmp_path: Path, option: list[str], why: str,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    script = tmp_path / "answers.txt"
    script.write_text("UP\n")
    argv = ["--model", "mockllm/model", "--script", str(script), "--name", "M", "--temperature", "0",
            "--results", str(tmp_path / "r"), *option]
    assert llm_track.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and why in err and not (tmp_path / "r").exists()
