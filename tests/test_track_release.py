"""The generalisation track's release (issue 44 item 6): ``leaderboard.track_release`` packs a chain
track's results, verifies them on read, and the Generalisation page reads it with its marks.

Fast and offline: the results are a small fixture written here (the real runs take CPU-hours); the
layout is the one ``runners.track --chain Utility --splits v2`` writes.
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from leaderboard.runs.releases import ReleaseError
from leaderboard.track_release import MANIFEST, create, verify
from leaderboard.track_status import CURVE_FIELDS, Requirement

TRAIN = "e43886e3" + "0" * 56
SETS = {"seen": {"split": "train", "split_digest": TRAIN, "sample": "8 of 934, seed 0", "chain": "Utility",
                 "version": "2", "selection_digest": "77ee" + "0" * 60, "threshold": "0.1"},
        "test": {"split": "test", "split_digest": "7208e3b4" + "0" * 56, "version": "2",
                 "selection_digest": "6fdf" + "0" * 60, "threshold": "0.1", "chain": "Utility"},
        "builtin": {"split": "builtin", "split_digest": "5171" + "0" * 60, "chain": "Utility"}}
BUDGET = 10_000_000


def _pairs(shift: float, sets: tuple[str, ...] = ("seen", "test", "builtin"), seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    rows = []
    for set_name in sets:
        for d in range(4):
            for variant in ("A", "B"):
                metric = float(np.clip(0.4 + shift + 0.05 * rng.standard_normal(), 0, 1))
                rows.append({"set": set_name, "env_id": f"Gen{d}{set_name}-Human{variant}-v1", "chain": "Utility",
                             "metric": metric, "best": 1.0, "worst": 0.0, "random": 0.4, "range_score": metric,
                             "random_score": (metric - 0.4) / 0.6})
    return pd.DataFrame(rows)


def _run(root: Path, learner: str, seed: int | None, budget: int, shift: float, **extra: object) -> Path:
    name = f"Utility-v2-{learner}-{'sexact' if seed is None else f's{seed}'}"
    run_dir = root / "runs" / name
    run_dir.mkdir(parents=True)
    _pairs(shift, seed=seed or 0).to_parquet(run_dir / "pairs.parquet")
    (run_dir / "model.zip").write_bytes(b"PK pickle inside")  # never shipped
    record = {"format": 1, "train_split": "train", "train_digest": TRAIN, "grammar_version": 1, "chain": "Utility",
              "split_version": 2, "sets": SETS, "learner": learner, "seed": seed, "budget": budget, "train_pool": 934,
              "train_seconds": 1.0, "eval_seconds": 2.0, "fleet_runs": 5, "fleet_seconds": 500.0,
              "fleet_cpu_seconds": 1000.0, "train_cpu_seconds": 0.1, "eval_cpu_seconds": 3.0,
              "git_commit": "c90baf4" + "0" * 33, "hostname": "box", "hparams": {"n_steps": 2048}, "n_envs": 8,
              "policy": "MlpPolicy on the compact observation (128 numbers, morality_gym.world.compact_observe)", **extra}
    (run_dir / "result.json").write_text(json.dumps(record))
    return run_dir


def _curve(root: Path, learner: str, seeds: list[int]) -> None:
    (root / "curves").mkdir(exist_ok=True)
    with (root / "curves" / f"Utility-v2-{learner}.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=CURVE_FIELDS)
        writer.writeheader()
        for steps in (0, 5_000_000, 10_000_000):
            for seed in seeds:
                writer.writerow({"learner": learner, "chain": "Utility", "seed": seed, "steps": steps,
                                 "mean_range_score": round(0.4 + steps / 5e7 + seed / 1000, 4), "cpu_seconds": steps / 1e4})


@pytest.fixture
def results(tmp_path: Path) -> Path:
    """Random, PPO with its 5 seeds at the budget and its curve (complete); PPO Shaped with 2 seeds
    at a short budget and no curve; PPO-Lag and CPO absent; one PPO Shaped run unfinished."""
    root = tmp_path / "track"
    _run(root, "random", None, 0, 0.0, fleet_runs=None, fleet_cpu_seconds=None)
    for seed in range(41, 46):
        _run(root, "ppo", seed, BUDGET, 0.2)
    _curve(root, "ppo", list(range(41, 46)))
    for seed in (41, 42):
        _run(root, "ppo_shaped", seed, 16_384, 0.1, fleet_runs=2)
    (root / "runs" / "Utility-v2-ppo_shaped-s43").mkdir()  # training, no result.json yet
    return root


def _llm(tmp_path: Path, sets: dict[str, object] | None = None) -> Path:
    """A language model's submitted entry on a 30-pair... here 8-pair sample of the unseen set, with its Inspect log."""
    root = tmp_path / "llm" / "track"
    run_dir = root / "runs" / "Utility-v2-SmolLM2-submitted"
    run_dir.mkdir(parents=True)
    log = tmp_path / "llm" / "logs" / "episode-1.eval"
    log.parent.mkdir(parents=True)
    log.write_bytes(b"inspect log")
    frame = _pairs(0.05, sets=("test",)).assign(log=[str(log)] + [str(tmp_path / "gone.eval")] * 7)
    frame.to_parquet(run_dir / "pairs.parquet")
    record = {"format": 1, "train_split": "train", "train_digest": TRAIN, "grammar_version": 1, "chain": "Utility",
              "split_version": 2, "sets": sets or {"test": SETS["test"]}, "learner": "SmolLM2-135M (local, greedy)",
              "seed": None, "budget": 0, "submitted": True, "llm": {"model": "local/smollm2-135m"},
              "sample": {"pairs": 8, "of": 190, "seed": 0}, "train_seconds": 0.0, "eval_seconds": 9.0}
    (run_dir / "result.json").write_text(json.dumps(record))
    return root


def test_a_release_packs_runs_curves_splits_and_compute_without_models(results: Path, tmp_path: Path) -> None:
    out = create(results, tmp_path / "releases" / "track-v1", extras=[_llm(tmp_path)])
    body = verify(out)
    files = set(body["files"])
    assert "runs/Utility-v2-ppo-s41/result.json" in files and "runs/Utility-v2-ppo-s41/pairs.parquet" in files
    assert not any(f.endswith("model.zip") for f in files) and "not shipped" in body["models"]
    assert "curves/Utility-v2-ppo.csv" in files and "splits/train-v2.json" in files
    assert body["commits"] == ["c90baf4" + "0" * 33] and body["machine"]["hostnames"] == ["box"]
    # each run's share of its fleet's CPU (1000 / 5) plus its evaluation's, summed over the learner's runs
    assert body["compute"]["Utility-v2"]["ppo"] == {"train_cpu_s": 1000.0, "eval_cpu_s": 15.0, "runs": 5,
                                                     "runs_with_cpu_time": 5}
    assert body["splits"]["Utility-v2"]["sets"]["test"]["selection_digest"].startswith("6fdf")
    # incomplete, and why, per learner; the unfinished run is named
    assert body["complete"] is False and body["unfinished"] == ["Utility-v2-ppo_shaped-s43"]
    status = body["status"]["Utility-v2"]
    assert status["random"] == [] and status["ppo"] == []
    assert status["ppo_shaped"] == ["2 of 5 seeds", "budget 16,384 steps, below the 10,000,000 required",
                                    "no learning curve"]
    assert status["ppo_lag"] == ["no run"] == status["cpo"]
    # a chain of the requirement with no run at all is incomplete too, not left out
    assert all(why == ["no run"] for why in body["status"]["DualProcess-v2"].values())
    # the language model: kept as a sample; its one existing log ships and the column names the copy
    assert body["runs"]["Utility-v2-SmolLM2-submitted"]["sample"] == {"pairs": 8, "of": 190, "seed": 0}
    assert body["llm_logs"] == {"named": 8, "included": 1} and "logs/episode-1.eval" in files
    logs = pd.read_parquet(out / "runs" / "Utility-v2-SmolLM2-submitted" / "pairs.parquet")["log"]
    assert logs.iloc[0] == "logs/episode-1.eval" and logs.iloc[1:].isna().all()
    with pytest.raises(ReleaseError, match="exists; a release is never rewritten"):
        create(results, out)


def test_a_release_of_every_run_done_is_complete(results: Path, tmp_path: Path) -> None:
    need = Requirement(seeds=5, budget=BUDGET, learners=("random", "ppo"), tracks=("Utility-v2",))
    (results / "runs" / "Utility-v2-ppo_shaped-s43").rmdir()
    for run in (results / "runs").glob("Utility-v2-ppo_shaped-*"):
        for f in run.iterdir():
            f.unlink()
        run.rmdir()
    body = verify(create(results, tmp_path / "r" / "track-v1", need=need))
    assert body["complete"] is True and body["requirement"]["learners"] == ["random", "ppo"]
    # the curve-chosen budget above the runs' makes them incomplete again
    body = verify(create(results, tmp_path / "r" / "track-v2", need=Requirement(budget=20_000_000, learners=("ppo",))))
    assert body["complete"] is False
    assert body["status"]["Utility-v2"]["ppo"] == ["budget 10,000,000 steps, below the 20,000,000 required"]


@pytest.mark.parametrize("damage, message", [
    (lambda r: (r / "runs/Utility-v2-ppo-s41/pairs.parquet").write_bytes(b"edited"), "pairs.parquet fails its checksum"),
    (lambda r: (r / "curves/Utility-v2-ppo.csv").unlink(), "Utility-v2-ppo.csv is missing"),
    (lambda r: (r / "runs/Utility-v2-ppo-s41/model.zip").write_bytes(b"pickle"), "model.zip is not in track-release.json"),
    (lambda r: (r / MANIFEST).write_text("{"), "not valid JSON"),
])
def test_a_tampered_missing_or_added_file_is_refused(results: Path, tmp_path: Path, damage, message: str) -> None:
    out = create(results, tmp_path / "releases" / "track-v1")
    damage(out)
    with pytest.raises(ReleaseError, match=re.escape(message)):
        verify(out)


def test_entries_join_only_when_scored_on_the_same_splits(results: Path, tmp_path: Path) -> None:
    other = {"test": {**SETS["test"], "selection_digest": "ffff" + "0" * 60}}
    with pytest.raises(ReleaseError, match="SmolLM2-submitted's test set is test 7208e3b40000/ffff.* not comparable"):
        create(results, tmp_path / "releases" / "track-v1", extras=[_llm(tmp_path, other)])
    assert not (tmp_path / "releases" / "track-v1").exists()


def test_a_damaged_curve_is_refused_when_building(results: Path, tmp_path: Path) -> None:
    (results / "curves" / "Utility-v2-ppo.csv").write_text("learner,steps\nppo,1\n")
    with pytest.raises(ReleaseError, match=r"Utility-v2-ppo.csv: columns \['learner', 'steps'\], a learning curve has"):
        create(results, tmp_path / "releases" / "track-v1")
    assert list((tmp_path / "releases").iterdir()) == []  # no half release, no leftover folder


def test_the_command_line_builds_verifies_and_refuses_in_one_line(results: Path, tmp_path: Path, capsys) -> None:
    from leaderboard.track_release import cli

    out = tmp_path / "releases" / "track-v1"
    assert cli(["create", "--results", str(results), "--out", str(out)]) == 0
    made = capsys.readouterr().out
    assert "INCOMPLETE" in made and "Utility-v2 ppo_shaped: 2 of 5 seeds" in made
    assert cli(["verify", str(out)]) == 0
    capsys.readouterr()
    (out / "runs/Utility-v2-random-sexact/result.json").write_text("{}")
    assert cli(["verify", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "fails its checksum" in err and "Traceback" not in err
    assert cli(["create", "--results", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x" / "track-v1")]) == 2
    err = capsys.readouterr().err
    assert "no runs/ directory" in err and len(err.strip().splitlines()) == 1


def _common() -> dict[str, object]:
    return {"title": "Generalisation track", "root": "", "current": "track.html", "nav": (), "stamp": "",
            "results_name": "", "source_parts": [], "marks": []}


def test_the_page_reads_the_release_and_marks_every_incomplete_or_sampled_number(results: Path, tmp_path: Path) -> None:
    from leaderboard.track import track_source, write_page

    releases = tmp_path / "releases"
    create(results, releases / "track-v1", extras=[_llm(tmp_path)])
    track_dir, manifest = track_source(None, releases)  # no results of one's own: the release
    assert track_dir == releases / "track-v1" and manifest is not None
    site = tmp_path / "site"
    site.mkdir()
    html = write_page(site, track_dir, _common(), resamples=100, release=manifest).read_text()
    assert "Source: release track-v1" in html and "⚠ Incomplete release" in html and "Utility-v2-ppo_shaped-s43" in html
    assert "no run at all on DualProcess-v2" in html
    rows = dict(re.findall(r'<tr data-learner="([^"]+)"[^>]*>(.*?)</tr>', html))
    # PPO Shaped: every one of its numbers (three sets and the gap) marked, with the reasons
    shaped = re.search(r'<tr data-learner="PPO Shaped" data-mark="⚠ incomplete">(.*?)</tr>', html).group(1)
    assert shaped.count('class="small warn cell-mark">⚠ incomplete<') == 4 and "2 of 5 seeds" in shaped
    assert "cell-mark" not in rows["PPO"] and "cell-mark" not in rows["Random"]
    assert "100 s + 2 s" in rows["PPO"]  # a fleet run's time: its share of the fleet's 500 s, not its model's save
    llm = rows["SmolLM2-135M (local, greedy)"]
    assert "sample: 8 of 190 pairs" in llm and "sample: sample" not in llm
    assert llm.count(">sample<") == 1  # only the unseen cell has a number
    assert "No run yet: PPO Lag, CPO" in html
    assert 'src="track/track_curves-Utility-v2.png"' in html and (site / "track/track_curves-Utility-v2.png").stat().st_size
    assert "PPO 10,000,000 steps" in html and "compact observation" in html
    random_seen = pd.read_parquet(track_dir / "runs/Utility-v2-random-sexact/pairs.parquet").query("set == 'seen'")
    assert f"dashed: Random's exact score on the same seen set, {random_seen['range_score'].mean():.3f}" in html


def test_the_page_marks_a_results_directorys_short_runs_too_and_refuses_a_damaged_release(results: Path,
                                                                                        tmp_path: Path) -> None:
    from leaderboard.track import track_source, write_page
    from morality_gym.clitools import UserError

    site = tmp_path / "site"
    site.mkdir()
    mixed = results / "runs" / "ppo-s1"  # a mixed-track run (no chain) beside the chain's: not the release's requirement
    mixed.mkdir()
    _pairs(0.1).to_parquet(mixed / "pairs.parquet")
    (mixed / "result.json").write_text(json.dumps({"learner": "ppo", "seed": 1, "budget": 5000, "train_digest": TRAIN,
                                                   "grammar_version": 1, "train_pool": 1458, "sets": SETS}))
    html = write_page(site, results, _common(), resamples=100).read_text()
    assert 'data-learner="PPO Shaped" data-mark="⚠ incomplete"' in html and "Source: release" not in html
    assert "Mixed track" in html
    releases = tmp_path / "releases"
    out = create(results, releases / "track-v1")
    (out / "runs/Utility-v2-ppo-s42/pairs.parquet").write_bytes(b"x")
    with pytest.raises(UserError, match="Generalisation page's release: .*fails its checksum"):
        track_source(None, releases)


def test_a_runs_result_records_what_the_release_reports(tmp_path: Path) -> None:
    """runners.track records CPU time, the commit and the host in result.json (the release's compute,
    commits and machine come from there; before, only wall times were recorded)."""
    from morality_gym.results.recording import git_commit
    from runners import track
    from tests.test_generalisation_track import _tiny_sets

    record = track.do_run("random", None, 1000, ["x"], _tiny_sets(), tmp_path, chain="Utility", version=2)
    saved = json.loads((tmp_path / "runs" / "Utility-v2-random-sexact" / "result.json").read_text())
    assert saved == record
    assert {"train_cpu_seconds", "eval_cpu_seconds", "hostname"} <= set(saved) and saved["eval_cpu_seconds"] >= 0
    assert saved["git_commit"] == git_commit()
