"""The benchmark report's plumbing: before/after comparisons and partial re-runs (no timings asserted)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks import Section
from benchmarks.baseline import Table, comparison, number, parse_sections
from benchmarks.run import keep_other_sections

ROOT = Path(__file__).resolve().parents[1]


def _section(title: str, rows: list[list[str]]) -> Section:
    return Section(intro="x", headers=["learner", "steps/s", "ratio"], rows=rows, title=title, compare=["steps/s"])


def test_parse_sections_reads_back_what_section_markdown_writes() -> None:
    a = _section("A", [["PPO", "3,275", "1.04x"], ["CPO", "626", "0.98x"]])
    b = _section("B", [["x", "1", "2"]])
    tables = parse_sections("# head\n\n| machine | |\n|---|---|\n\n" + a.markdown() + "\n" + b.markdown())
    assert tables["A"].headers == ["learner", "steps/s", "ratio"]
    assert tables["A"].rows == [["PPO", "3,275", "1.04x"], ["CPO", "626", "0.98x"]]
    assert tables["B"].rows == [["x", "1", "2"]]


def test_number_reads_the_leading_figure_of_a_cell() -> None:
    assert number("3,275") == 3275
    assert number("1.05x") == 1.05
    assert number("**12.5** (wall 13)") == 12.5
    assert number("—") is None


def test_comparison_matches_rows_by_name_and_keeps_new_rows() -> None:
    now = _section("T", [["PPO", "2,000", "1x"], ["PPO Lag", "5,000", "1x"], ["PPO Lag (corrected protocol)", "300", "1x"]])
    before = Table(["learner", "steps/s", "ratio"], [["PPO Lag", "250", "1x"], ["PPO", "1,000", "1x"]])
    out = comparison(now, before, "abc1234")
    assert out.headers == ["learner", "steps/s at abc1234", "steps/s now", "now / before"]
    assert out.rows[0] == ["PPO", "1,000", "2,000", "2.00x"]
    assert out.rows[1] == ["PPO Lag", "250", "5,000", "20.00x"]
    assert out.rows[2] == ["PPO Lag (corrected protocol)", "—", "300", "—"]
    missing = comparison(now, None, "abc1234")
    assert missing.notes and "no section" in missing.notes[0]


def test_keep_other_sections_drops_replaced_sections_and_their_comparisons() -> None:
    doc = "\n".join(
        [
            "# MoralityGym benchmarks", "", "| machine | |", "|---|---|", "",
            _section("A", [["a", "1", "1"]]).markdown(),
            _section("B", [["b", "2", "2"]]).markdown(),
            _section("B: before (abc) and now", [["b", "2", "2"]]).markdown(),
            "Total benchmark time: 3 s.", "",
        ]
    )
    kept = keep_other_sections(doc, {"B"})
    assert [t for t, _ in kept] == ["A"]
    assert "| a | 1 | 1 |" in kept[0][1]
    assert "Total benchmark time" not in kept[0][1]


def test_baseline_run_measures_another_revision_and_partial_runs_keep_other_sections(tmp_path: Path) -> None:
    """End to end: ``--only reset --baseline HEAD`` beside an existing report keeps its other sections."""
    out = tmp_path / "BENCH.md"
    out.write_text(
        "# MoralityGym benchmarks\n\n"
        + _section("Oracle search", [["Switch5", "1", "1"]]).markdown()
        + "\nTotal benchmark time: 1 s.\n"
    )
    cmd = [sys.executable, "-m", "benchmarks.run", "--quick", "--repeats", "1", "--only", "reset", "--no-progress",
           "--baseline", "HEAD", "--output", str(out)]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    text = out.read_text()
    assert "## reset() time" in text
    assert "## reset() time: before (" in text
    assert "## Oracle search" in text and "| Switch5 | 1 | 1 |" in text, "a partial run must keep the other sections"
    assert "keep the figures of an earlier run" in text
    worktrees = subprocess.run(["git", "worktree", "list"], cwd=ROOT, capture_output=True, text=True, check=False).stdout
    assert "morality-gym-baseline-" not in worktrees, "the temporary worktree must be removed"
    bad = subprocess.run([*cmd[:-2], "--output", str(tmp_path / "x.md"), "--baseline", "no-such-rev"],
                         cwd=ROOT, capture_output=True, text=True, timeout=600, check=False)
    assert bad.returncode != 0 and "is not a commit" in bad.stderr


def test_link_results_takes_what_the_build_reads_and_never_its_outputs(tmp_path: Path) -> None:
    from benchmarks.bench_leaderboard import link_results

    source = tmp_path / "source"
    (source / "runs" / "abc").mkdir(parents=True)
    (source / "runs" / ".quarantine").mkdir()
    (source / "manifests").mkdir()
    for name in ("runs/abc.parquet", "runs/abc.learn.parquet", "runs/abc/episode.gif", "runs/abc/model.zip",
                 "runs/.quarantine/bad.parquet", "manifests/m.json", "table1.csv", "cache/stats.json", "mlflow.db"):
        (source / name).parent.mkdir(parents=True, exist_ok=True)
        (source / name).write_text(name)
    target = tmp_path / "target"
    assert link_results(source, target) == 1  # one run row (abc.parquet)
    got = sorted(str(p.relative_to(target)) for p in target.rglob("*") if p.is_file())
    assert got == ["manifests/m.json", "runs/abc.learn.parquet", "runs/abc.parquet", "runs/abc/episode.gif"]
    assert (target / "runs" / "abc.parquet").stat().st_ino == (source / "runs" / "abc.parquet").stat().st_ino  # linked, not copied


@pytest.mark.parametrize("flag", ["--results", "--release"])
def test_real_data_flags_refuse_a_directory_that_is_not_one(flag: str, tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "benchmarks.run", "--only", "leaderboard-release", flag, str(tmp_path),
                          "--output", str(tmp_path / "B.md")], cwd=Path(__file__).resolve().parents[1],
                         capture_output=True, text=True, check=False)
    assert out.returncode == 2 and flag in out.stderr and "not a" in out.stderr, out.stderr
    assert not (tmp_path / "B.md").exists()
