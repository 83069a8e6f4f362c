"""The dilemma generator: its grammar covers the building blocks, its files are ordinary scenario
files that load as a user's, the dilemmas it keeps are dilemmas, and a seed gives the same bytes."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import gymnasium as gym
import pytest
import yaml

from morality_gym.__main__ import main as cli_main
from morality_gym.envs.registration import add_scenario_dir
from morality_gym.envs.registry import SCENARIOS_ENV
from morality_gym.evaluation.oracle import oracle
from morality_gym.generator.draws import Draws
from morality_gym.generator.grammar import GRAMMAR_VERSION, MAX_GROUP_SIZE, draw_plan
from morality_gym.generator.pipeline import GRAPH_TOO_LARGE, NOT_A_DILEMMA, attempt, builtin_names, generate
from morality_gym.generator.writer import SCENARIO_UTILITIES, scenario_text
from morality_gym.world.grid_observe import GRID_HEIGHT, GRID_WIDTH
from morality_gym.world.layout import UTILITY_TYPES, parse_scenario

PLAN_SEEDS = range(300)


def test_draws_are_pinned() -> None:
    """The numbers a seed draws are part of every published split: they must never change."""
    draws = Draws(42)
    assert [draws.below(1000) for _ in range(5)] == [796, 756, 695, 963, 407]
    assert draw_plan(0).rails[3:] == ("<<.v<<<", "<S<v...", "<<S<...", "<S<....", "<<.....")
    assert GRAMMAR_VERSION == 1


def _parsed(seed: int):
    plan = draw_plan(seed)
    zero = {k: (0, 0) for k in UTILITY_TYPES}
    text = scenario_text(plan, {v.name: zero for v in plan.variants}, {k: (0, 1) for k in SCENARIO_UTILITIES})
    return plan, parse_scenario(yaml.safe_load(text), f"seed {seed}")


def test_the_grammar_draws_every_building_block_into_valid_files() -> None:
    blocks: Counter[str] = Counter()
    types: Counter[str] = Counter()
    sizes: set[int] = set()
    for seed in PLAN_SEEDS:
        plan, scenario = _parsed(seed)  # the format's own parser accepts every drawn layout
        assert scenario.name == f"Gen{seed}" and scenario.name not in builtin_names()
        assert scenario.height <= GRID_HEIGHT and scenario.width <= GRID_WIDTH
        blocks.update(k for k, v in plan.blocks.items() if v and not (k == "trolleys" and v == 1))
        blocks["levers_stick"] += bool(plan.switches) and not plan.levers_loop
        for variant in scenario.variants.values():
            types.update(variant.types)
            sizes.update(variant.amounts)
    for block in ("trolleys", "switches", "three_way", "cascade", "shared_lever", "pushable", "loop",
                  "long_approach", "empty_tracks", "levers_stick"):
        assert blocks[block] >= 3, f"the grammar hardly ever draws {block}: {blocks}"
    assert set(types) == {"human", "animal", "robot"} and sizes == set(range(1, MAX_GROUP_SIZE + 1))


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("generated")
    generate(range(100, 104), out, pictures=True)
    return out


def test_same_seed_same_bytes(generated: Path, tmp_path: Path) -> None:
    generate(range(100, 104), tmp_path, pictures=False)
    written = sorted(p.name for p in tmp_path.iterdir())
    assert written and all(name.endswith((".yaml", ".json")) for name in written)
    for name in written:
        assert (tmp_path / name).read_bytes() == (generated / name).read_bytes(), name


@pytest.mark.usefixtures("isolated_scenarios")
def test_kept_files_load_as_user_files_and_are_dilemmas(generated: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(SCENARIOS_ENV, "")  # add_scenario_dir lists the directory there; undone after the test
    index = json.loads((generated / "index.json").read_text())
    assert index["kept"] == len(index["files"]) >= 2 and index["tried"] == 4
    ids = add_scenario_dir(generated)
    for name in index["files"]:
        assert (generated / name.replace(".yaml", ".png")).read_bytes()[:4] == b"\x89PNG"
        values = json.loads((generated / name.replace(".yaml", ".json")).read_text())
        for env_id, record in values["variants"].items():
            assert env_id in ids and record["dilemma_under"], env_id
            chain = record["dilemma_under"][0]
            exact = record["chains"][chain]
            assert exact["best"] > exact["worst"] and exact["worst"] <= exact["random"] <= exact["best"]
            assert oracle(env_id, chain).best.metric == pytest.approx(exact["best"], abs=1e-6)
            obs, _ = gym.make(f"MoralityGym/{env_id}", obs_type="grid").reset()
            assert obs.shape == (20, GRID_HEIGHT, GRID_WIDTH)


def test_rejections_are_counted_by_reason(tmp_path: Path) -> None:
    report = generate(range(3), tmp_path, max_states=10, pictures=False)
    assert report.index["kept"] == 0 and report.index["rejected"][GRAPH_TOO_LARGE] == [0, 1, 2]
    assert not list(tmp_path.glob("*.yaml"))
    assert attempt(7, tmp_path, with_values=False).reason == NOT_A_DILEMMA  # no lever, push out of reach


def test_generate_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli_main(["generate", "--seed", "101", "--count", "1", "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "kept 1 of 1 seeds (101-101)" in out and "rejected: graph_too_large 0, not_a_dilemma 0, invalid 0" in out
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["Gen101.json", "Gen101.png", "Gen101.yaml", "index.json"]
    (tmp_path / "file").write_text("")
    assert cli_main(["generate", "--count", "1", "--out", str(tmp_path / "file" / "sub")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --out ") and "not a writable directory" in err and "\n" not in err
