"""Results releases (``python -m leaderboard.release``): a real sweep frozen into checksummed files,
shown by the leaderboard alone or beside a user's own runs, refused when damaged."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest

from benchmarks.project_table1 import measured_rates
from leaderboard.release import RELEASE_FORMAT, load, verify
from morality_gym.results.schema import RUN_COLUMNS, run_files

REPO = Path(__file__).resolve().parents[1]
SELECTION = ["chain=utility", "scenario=[switch_standard]", "variant=[HumanA,HumanB]", "preset=smoke", "mlflow=false"]
RULE = """
import numpy as np


def act(obs):
    return 5 if np.asarray(obs)[5] == 0 else 4
"""

pytestmark = pytest.mark.slow


def run(*args: str, cwd: Path = REPO) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, *args], cwd=cwd, capture_output=True, text=True, timeout=900, check=False)


@pytest.fixture(scope="module")
def released(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(results directory of a real smoke sweep of Random and PPO-Lag, the release made from it)."""
    root = tmp_path_factory.mktemp("release")
    results = root / "results"
    done = run("-m", "runners.sweep", "algo=[random,ppo_lag]", *SELECTION, f"results_dir={results}")
    assert done.returncode == 0, done.stdout + done.stderr
    done = run("-m", "leaderboard.release", "create", "--results", str(results), "--name", "smoke-v1",
               "--title", "Smoke test release", "--root", str(root / "releases"), "--update-stride", "2")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "release smoke-v1: 4 runs (4 ok)" in done.stdout
    return results, root / "releases" / "smoke-v1"


def build(*args: str) -> subprocess.CompletedProcess[str]:
    return run("-m", "leaderboard.build", "--no-reference", *args)


def test_release_holds_every_run_and_its_side_tables(released: tuple[Path, Path]) -> None:
    results, release = released
    body = verify(release)
    assert body["format"] == RELEASE_FORMAT and body["name"] == "smoke-v1" and body["runs"] == 4
    assert len(body["commit"]) == 40 and body["machine"]["cores"] >= 1
    assert {"runs.parquet", "learn.parquet", "updates.parquet", "table1.csv", "table1.md", "table1.tex"} <= set(body["files"])
    sweep = body["sweeps"][0]
    assert sweep["planned"] == 4 and sweep["ok"] == 4 and set(sweep["compute_s_per_learner"]) == {"Random", "PPO Lag"}
    # the CPU cost per 1M steps: PPO-Lag's is positive, Random's (no training steps) is left out
    assert set(sweep["cpu_s_per_run_per_1m_steps"]) == {"PPO Lag"} and sweep["cpu_s_per_run_per_1m_steps"]["PPO Lag"] > 0
    loaded = load(release)
    own = pd.concat([pq.read_table(p).to_pandas() for p in run_files(results)], ignore_index=True)
    assert set(RUN_COLUMNS) <= set(loaded.runs.columns)
    assert sorted(loaded.runs["run_id"]) == sorted(own["run_id"])
    merged = loaded.runs.set_index("run_id").loc[own["run_id"]]
    assert list(merged["metric"]) == list(own["metric"]) and merged["model_path"].isna().all()
    # one GIF per (learner, scenario), and only the chosen runs point at one
    gifs = sorted(p.name for p in (release / "gifs").iterdir())
    assert gifs == ["paper__smoke__PPO_Lag__SwitchStandard.gif", "paper__smoke__Random__SwitchStandard.gif"]
    assert loaded.runs["gif_path"].notna().sum() == 2
    # learn-time evaluations whole; update diagnostics thinned to every 2nd update and the last
    own_learn = pd.concat([pq.read_table(p).to_pandas() for p in (results / "runs").glob("*.learn.parquet")])
    assert len(loaded.learn) == len(own_learn)
    for run_id, part in loaded.updates.groupby("run_id"):
        full = pq.read_table(results / "runs" / f"{run_id}.updates.parquet").to_pandas()
        assert list(part["update"]) == sorted({u for u in full["update"] if (u - 1) % 2 == 0} | {full["update"].max()})


def test_leaderboard_builds_from_the_release_alone(released: tuple[Path, Path], tmp_path: Path) -> None:
    results, release = released
    own = build("--results", str(results), "--out", str(tmp_path / "own"))
    assert own.returncode == 0, own.stderr
    alone = build("--results", str(tmp_path / "no-runs-here"), "--out", str(tmp_path / "rel"), "--release", str(release))
    assert alone.returncode == 0, alone.stderr
    assert "release smoke-v1 (commit " in alone.stdout and "4 of its 4 run(s) shown" in alone.stdout
    # the same numbers as a build of the results directory the release was made from
    a = pd.read_csv(tmp_path / "own" / "table1_all.csv")
    b = pd.read_csv(tmp_path / "rel" / "table1_all.csv")
    pd.testing.assert_frame_equal(a[["learner", "mean", "n_runs"]], b[["learner", "mean", "n_runs"]])
    html = (tmp_path / "rel" / "site" / "index.html").read_text()
    assert "<strong>release smoke-v1</strong> · Smoke test release · commit" in html
    pages = [p for p in (tmp_path / "rel" / "site" / "runs").glob("*.html") if p.name != "index.html"]
    assert len(pages) == 4 and all("smoke-v1" in p.read_text() for p in pages)  # each run page names its source


def test_a_submitted_policy_lands_beside_the_release_baselines(released: tuple[Path, Path], tmp_path: Path) -> None:
    _, release = released
    rule = tmp_path / "rule.py"
    rule.write_text(RULE)
    mine = tmp_path / "mine"
    done = run("-m", "leaderboard.submit", f"{rule}:act", "--name", "Lever rule", "--results", str(mine),
               "--chain", "utility", "--scenario", "switch_standard", "--variant", "HumanA", "--variant", "HumanB",
               "--preset", "smoke", "--no-gif")
    assert done.returncode == 0, done.stderr
    both = build("--results", str(mine), "--release", str(release))
    assert both.returncode == 0, both.stderr
    table = pd.read_csv(mine / "table1_all.csv")
    row = table.loc[(table["chain"] == "Utility") & (table["scenario"] == "SwitchStandard")]
    assert {"Random", "PPO Lag", "Lever rule"} <= set(row["learner"])
    html = (mine / "site" / "index.html").read_text()
    assert re.search(r"<strong>your results</strong> <code>[^<]*mine</code> · 2 runs", html)
    assert "<strong>release smoke-v1</strong>" in html and 'data-learner="Lever rule"' in html
    runs = (mine / "site" / "runs" / "index.html").read_text()  # issue 36: All runs opens on the user's own
    assert '<option value="results" selected>your runs</option>' in runs and "release smoke-v1</td>" in runs


def test_own_copy_of_a_released_run_wins(released: tuple[Path, Path], tmp_path: Path) -> None:
    results, release = released
    done = build("--results", str(results), "--out", str(tmp_path / "o"), "--release", str(release))
    assert done.returncode == 0, done.stderr
    assert f"0 of its 4 run(s) shown (4 replaced by the runs of the same configuration in {results})" in done.stdout
    table = pd.read_csv(tmp_path / "o" / "table1_all.csv")
    assert table.loc[table["learner"] == "Random", "n_runs"].iloc[0] == 2  # not 4: each run counted once
    html = (tmp_path / "o" / "site" / "index.html").read_text()
    assert "(4 replaced by the runs of the same configuration in your runs)" in html


def test_a_release_listed_first_is_credited_with_the_runs_it_replaces(released: tuple[Path, Path], tmp_path: Path) -> None:
    """Two releases sharing run ids (a new release beside an older one): the page names the release that
    won, not the user's results, which hold no runs here."""
    results, release = released
    made = run("-m", "leaderboard.release", "create", "--results", str(results), "--name", "again-v1", "--root", str(tmp_path))
    assert made.returncode == 0, made.stderr
    done = build("--results", str(tmp_path / "none"), "--out", str(tmp_path / "o"),
                 "--release", str(tmp_path / "again-v1"), "--release", str(release))
    assert done.returncode == 0, done.stderr
    assert "0 of its 4 run(s) shown (4 replaced by the runs of the same configuration in release again-v1)" in done.stdout
    html = (tmp_path / "o" / "site" / "index.html").read_text()
    assert "(4 replaced by the runs of the same configuration in release again-v1)" in html
    assert "your runs" not in html.split("Where these numbers come from")[1].split("</ul>")[0]


def test_a_release_is_priced_like_the_results_it_was_made_from(released: tuple[Path, Path]) -> None:
    """benchmarks.project_table1 re-measures a shipped sweep's cost from the release alone."""
    results, release = released
    for engine in ("fleet", "single"):
        assert measured_rates(release, "paper", "smoke", engine) == measured_rates(results, "paper", "smoke", engine)
    assert measured_rates(release, "paper", "smoke", "single") or measured_rates(release, "paper", "smoke", "fleet")


def test_damaged_release_is_refused_naming_the_file(released: tuple[Path, Path], tmp_path: Path) -> None:
    _, release = released
    copy = tmp_path / "copy"
    subprocess.run(["cp", "-r", str(release), str(copy)], check=True)
    data = bytearray((copy / "table1.md").read_bytes())
    data[10] ^= 1
    (copy / "table1.md").write_bytes(bytes(data))
    for out in (run("-m", "leaderboard.release", "verify", str(copy)),
                build("--results", str(tmp_path / "none"), "--release", str(copy))):
        assert out.returncode == 2
        assert out.stderr.strip().count("\n") == 0 and "Traceback" not in out.stderr
        assert f"{copy / 'table1.md'} fails its checksum" in out.stderr
    (copy / "table1.md").write_bytes((release / "table1.md").read_bytes())
    assert run("-m", "leaderboard.release", "verify", str(copy)).returncode == 0
    (copy / "updates.parquet").unlink()
    out = run("-m", "leaderboard.release", "verify", str(copy))
    assert out.returncode == 2 and "updates.parquet is missing" in out.stderr
    manifest = json.loads((release / "release.json").read_text())
    manifest["files"]["../escape"] = {"sha256": "0", "bytes": 0}
    (copy / "release.json").write_text(json.dumps(manifest))
    out = run("-m", "leaderboard.release", "verify", str(copy))
    assert out.returncode == 2 and "points outside the release" in out.stderr
    out = build("--results", str(tmp_path / "none"), "--release", str(tmp_path / "nope"))
    assert out.returncode == 2 and "--release" in out.stderr and "no release.json there" in out.stderr


def test_create_refuses_bad_input_and_never_overwrites(released: tuple[Path, Path], tmp_path: Path) -> None:
    results, release = released
    before = (release / "release.json").read_bytes()
    cases = {
        ("--name", "smoke-v1", "--root", str(release.parent)): "exists; a release is never rewritten",
        ("--name", "bad name!", "--root", str(tmp_path)): "release name 'bad name!'",
    }
    for args, message in cases.items():
        out = run("-m", "leaderboard.release", "create", "--results", str(results), *args)
        assert out.returncode == 2 and message in out.stderr, out.stderr
    empty = tmp_path / "empty"
    (empty / "runs").mkdir(parents=True)
    out = run("-m", "leaderboard.release", "create", "--results", str(empty), "--name", "x", "--root", str(tmp_path))
    assert out.returncode == 2 and "holds no runs" in out.stderr
    assert (release / "release.json").read_bytes() == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no half release left behind


def test_label_names_every_commit_of_a_mixed_release() -> None:
    from leaderboard.release import Release, runs_commit

    empty = pd.DataFrame()
    one = Release(Path("r"), {"name": "r", "commit": "657de81aaaa", "created": "2026-11-26T10:00:00+00:00"}, empty, empty, empty)
    assert one.label == "release r (commit 657de81, 2026-11-26)"
    commit = runs_commit(pd.DataFrame({"git_commit": ["9c3783bffff", "657de81aaaa", "9c3783bffff"]}))
    assert commit == "mixed:657de81,9c3783b"
    mixed = Release(Path("r"), {"name": "r", "commit": commit, "created": "2026-11-26T10:00:00+00:00"}, empty, empty, empty)
    assert mixed.label == "release r (commits 657de81, 9c3783b, 2026-11-26)"


def test_the_index_names_every_commit_of_a_mixed_release(released: tuple[Path, Path], tmp_path: Path) -> None:
    """The index's 'where these numbers come from' used to cut a mixed release's commit to 'mixed:6'."""
    import shutil

    from leaderboard.release import MANIFEST

    _, release = released
    mixed = tmp_path / "smoke-v1"
    shutil.copytree(release, mixed)
    manifest = json.loads((mixed / MANIFEST).read_text())
    manifest["commit"] = "mixed:657de81,9c3783b"  # the checksums cover the files the manifest lists, not itself
    (mixed / MANIFEST).write_text(json.dumps(manifest))
    out = build("--results", str(tmp_path / "no-runs-here"), "--out", str(tmp_path / "rel"), "--release", str(mixed))
    assert out.returncode == 0, out.stderr
    assert "release smoke-v1 (commits 657de81, 9c3783b, " in out.stdout
    html = (tmp_path / "rel" / "site" / "index.html").read_text()
    assert "commits <code>657de81, 9c3783b</code>" in html and "mixed:6" not in html
