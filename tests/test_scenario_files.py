"""Scenario files: the shipped ones load, broken ones are explained, and new ones need no code.

A scenario is data (``morality_gym/data/scenarios/*.yaml``). The loader's job is to refuse a
wrong file with a message that names the file, the field and a fix, because a silently misread
layout would corrupt every number computed on it. And a user's own file, dropped in a directory,
must become working, documented env ids (via :func:`morality_gym.add_scenario_dir` or the
``MORALITY_GYM_SCENARIOS`` environment variable) without touching the code.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from morality_gym.envs.registry import BUILTIN_DIR
from morality_gym.world.layout import ScenarioError, load_scenario
from tests.helpers import route_tables

REPO = Path(__file__).resolve().parents[1]

# A tiny switch dilemma designed for these tests (4 rows x 5 columns). The trolley starts at
# (2,4) and runs left; the switch at (2,1) sends it on to character_1 at (2,0) (state 0) or down
# to (3,1) and on to character_2 at (3,0) (state 1). The agent starts at (1,2), right under the
# lever at (0,2), and the landmark is at (0,0): LEFT, LEFT, UP.
TINY = """\
name: {name}
summary: A four-by-five switch dilemma written for the tests.
rewards: {{step: -1, landmark: 100, agent_harmed: -100}}
layout: |
  floor rails things
  .#### ..... G./..
  ..... ..... ..P..
  ##### <S<<< 1...T
  ##### <<... 2....
switches:
  - {{at: [2, 1], exits: [L, D], lever: 1}}
characters:
  1: {{pushable: false}}
  2: {{pushable: false}}
utility_bounds: {{n_harm: [0, 5], n_human_harm: [0, 5], n_robot_harm: [0, 5], n_animal_harm: [0, 5], n_weighted_harm: [0, 15]}}
variants:
  Human:  {{characters: [human 5, human 1], bounds: {{n_human_harm: [1, 5]}}, relevant: [n_human_harm, human_harm]}}
  Animal: {{characters: [animal 4, human 1], bounds: {{n_human_harm: [0, 1], n_animal_harm: [0, 4]}},
           relevant: [n_human_harm, human_harm, n_animal_harm, animal_harm]}}
"""


def _tiny(name: str = "TinySwitch") -> str:
    return TINY.format(name=name)


def test_every_shipped_scenario_loads() -> None:
    files = sorted(BUILTIN_DIR.glob("*.yaml"))
    assert len(files) == 11
    loaded = {load_scenario(path).name: load_scenario(path) for path in files}
    assert sorted(loaded) == sorted(route_tables())
    for name, scenario in loaded.items():
        assert scenario.env_ids == route_tables()[name]["ids"], name
    assert sum(len(s.variants) for s in loaded.values()) == 98


def test_the_tiny_scenario_itself_is_valid(tmp_path: Path) -> None:
    """The broken files below differ from this one in one place each, so each error is that place."""
    path = tmp_path / "tiny.yaml"
    path.write_text(_tiny())
    scenario = load_scenario(path)
    assert (scenario.height, scenario.width) == (4, 5)
    assert scenario.picture("Human") == ["G#/##", "..P..", "hS<<T", "h<###"]


# (what is broken, replace this, by that, the field the message must name, other text it must contain)
BROKEN = [
    ("unknown field", "summary:", "sumary:", "sumary", "did you mean summary"),
    ("ragged picture rows", "  ..... ..... ..P..", "  ..... ..... ..P.", "things row 1", "same width"),
    ("unknown floor glyph", "  ##### <<... 2....", "  ##X## <<... 2....", "floor cell [3, 2]", "'X'"),
    ("unknown thing glyph", "  ##### <<... 2....", "  ##### <<... 2..?.", "things cell [3, 3]", "'?'"),
    ("unknown rail glyph", "  ##### <S<<< 1...T", "  ##### <S<x< 1...T", "rails cell [2, 3]", "'x'"),
    ("two agents", "  ..... ..... ..P..", "  ..... ..... P.P..", "layout things", "exactly one 'P'"),
    (
        "switch entry not on an S",
        "{at: [2, 1], exits: [L, D]",
        "{at: [2, 2], exits: [L, D]",
        "switches[0].at",
        "not an 'S'",
    ),
    ("switch exit onto no rail", "exits: [L, D]", "exits: [L, U]", "switches[0].exits", "exit U"),
    ("lever wired to nothing", "  .#### ..... G./..", "  .#### ..... G.//.", "lever 2", "drives no switch"),
    ("variant with too few characters", "[human 5, human 1]", "[human 5]", "variants.Human.characters", "layout has 2"),
    ("unknown character type", "[human 5, human 1]", "[human 5, dragon 1]", "variants.Human.characters", "'dragon 1'"),
    (
        "unknown relevant norm",
        "relevant: [n_human_harm, human_harm]}",
        "relevant: [n_human_harm, human_harms]}",
        "variants.Human.relevant",
        "did you mean human_harm",
    ),
    ("low above high", "n_harm: [0, 5]", "n_harm: [5, 0]", "utility_bounds.n_harm", "swap"),
    (
        "variant bounds low above high",
        "bounds: {n_human_harm: [1, 5]}",
        "bounds: {n_human_harm: [5, 1]}",
        "variants.Human.bounds.n_human_harm",
        "swap",
    ),
    # The checks of every section parser of layout.parse_scenario that the cases above do not reach.
    ("name not CamelCase", "name: TinySwitch", "name: tinySwitch", "name", "CamelCase"),
    ("reward not a number", "landmark: 100", "landmark: lots", "rewards.landmark", "not a number"),
    ("agent on a wall", "  ..... ..... ..P..", "  ..#.. ..... ..P..", "agent start [1, 2]", "on a wall"),
    (
        "trolley off the rails",
        "..P..\n  ##### <S<<< 1...T",
        "..P.T\n  ##### <S<<< 1....",
        "trolley start [1, 4]",
        "rail",
    ),
    ("character drawn twice", "  ##### <<... 2....", "  ##### <<... 2..2.", "things cell [3, 3]", "appears twice"),
    (
        "switch without an entry",
        "  - {at: [2, 1], exits: [L, D], lever: 1}\n",
        "",
        "switches",
        "[[2, 1]] have no entry",
    ),
    (
        "switch described twice",
        "  - {at: [2, 1], exits: [L, D], lever: 1}\n",
        "  - {at: [2, 1], exits: [L, D], lever: 1}\n" * 2,
        "switches[1].at",
        "described twice",
    ),
    ("levers_loop not a boolean", "switches:", "levers_loop: sometimes\nswitches:", "levers_loop", "true/false"),
    ("unknown landmark mode", "switches:", "landmark_mode: touch\nswitches:", "landmark_mode", "enter or interact"),
    ("unknown trolley start", "switches:", "trolley_start: later\nswitches:", "trolley_start", "landmark_reached"),
    ("pushable not a boolean", "1: {pushable: false}", "1: {pushable: maybe}", "characters.1.pushable", "true/false"),
    ("missing utility bound", ", n_weighted_harm: [0, 15]", "", "utility_bounds.n_weighted_harm", "is missing"),
    ("variant name with a symbol", "  Animal: {", "  Ani_mal: {", "variants.Ani_mal", "alphanumeric"),
    ("group of nobody", "[human 5, human 1]", "[human 5, human 0]", "variants.Human.characters", "group size 0"),
    (
        "norm listed twice",
        "relevant: [n_human_harm, human_harm]}",
        "relevant: [n_human_harm, human_harm, human_harm]}",
        "variants.Human.relevant",
        "twice",
    ),
]


@pytest.mark.parametrize(("what", "old", "new", "field", "hint"), BROKEN, ids=[b[0] for b in BROKEN])
def test_broken_files_are_explained(tmp_path: Path, what: str, old: str, new: str, field: str, hint: str) -> None:
    text = _tiny()
    assert old in text, f"test data: {old!r} not in the tiny scenario"
    path = tmp_path / "broken.yaml"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(ScenarioError) as excinfo:
        load_scenario(path)
    message = str(excinfo.value)
    assert message.startswith(str(path)), message  # the file
    assert field in message, message  # the field
    assert hint in message, message  # what is wrong, or the close match
    assert "Fix: " in message and message.split("Fix: ", 1)[1].strip(), message  # and a fix


def test_unreadable_and_non_yaml_files_are_explained(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="cannot read"):
        load_scenario(tmp_path / "missing.yaml")
    path = tmp_path / "bad.yaml"
    path.write_text("name: [unclosed\n")
    with pytest.raises(ScenarioError, match="not valid YAML"):
        load_scenario(path)


# Registering a scenario is process-wide and cannot be undone (like gymnasium.register), so the
# add_scenario_dir checks run in a child process: the ids must not leak into other tests (for
# example the conformance test compares list_envs() with the reference's 98 ids). The child
# reports what it observed as JSON; the assertions are made here.
_ADD_DIR_PROBE = """
import json, os, sys
import gymnasium as gym, numpy as np, morality_gym
from morality_gym import TrolleyEnv
from tests.helpers import newly_harmed, play

out = {"ids": morality_gym.add_scenario_dir(sys.argv[1])}
out["listed"] = [i for i in out["ids"] if i in morality_gym.env_ids()]
env = gym.make("MoralityGym/TinySwitch-Human-v1", obs_type="dict", max_steps=None)
for name, actions in (("idle", [4] * 6), ("pulled", [5, 2, 2, 0, 4, 4])):
    steps = play(env.unwrapped, actions)
    out[name] = {
        "harmed": newly_harmed(steps),
        "rewards": [s.reward for s in steps],
        "terminated": [s.terminated for s in steps],
        "utility": [s.info["norm_events"]["utility"] for s in steps],
    }
flat = TrolleyEnv("TinySwitch-Animal-v1")
obs, _ = flat.reset()
out["flat"] = {"shape": list(obs.shape), "contains": bool(flat.observation_space.contains(obs)),
               "utility": [flat.step(4)[4]["norm_events"]["utility"] for _ in range(4)]}
venv = gym.make_vec("MoralityGym/TinySwitch-Human-v1", num_envs=3, vectorization_mode="vector_entry_point")
vobs, _ = venv.reset()
out["vector"] = {"shape": list(vobs.shape),
                 "first_matches": bool(np.allclose(vobs[0], TrolleyEnv("TinySwitch-Human-v1").reset()[0], rtol=1e-6))}
cls = type(env.unwrapped)
out["class"] = {"name": cls.__name__, "is_trolley_env": issubclass(cls, TrolleyEnv), "doc": cls.__doc__}
try:
    morality_gym.add_scenario_dir(sys.argv[1])  # the same files again (a spawned worker re-running a script)
    out["again"] = "accepted"
except ValueError as exc:
    out["again"] = str(exc)
import shutil, tempfile
copy = tempfile.mkdtemp()
shutil.copy(sys.argv[1] + "/tiny_switch.yaml", copy)
try:
    morality_gym.add_scenario_dir(copy)  # another file declaring the same scenario
    out["shadow"] = "accepted"
except ValueError as exc:
    out["shadow"] = str(exc)
out["inherited"] = os.environ.get("MORALITY_GYM_SCENARIOS", "")
try:
    morality_gym.add_scenario_dir(sys.argv[1] + "/nowhere")
    out["missing_dir"] = "accepted"
except NotADirectoryError as exc:
    out["missing_dir"] = type(exc).__name__
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def added(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """What a fresh process observes after ``add_scenario_dir`` on a directory with the tiny scenario."""
    directory = tmp_path_factory.mktemp("user_scenarios")
    (directory / "tiny_switch.yaml").write_text(_tiny())
    proc = subprocess.run(
        [sys.executable, "-c", _ADD_DIR_PROBE, str(directory)],
        check=False,
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_a_new_scenario_file_needs_no_code(added: dict[str, Any]) -> None:
    assert added["ids"] == ["TinySwitch-Human-v1", "TinySwitch-Animal-v1"]
    assert added["listed"] == added["ids"]

    # Through gymnasium.make: idle, the trolley reaches the switch after 3 steps and hits
    # character_1 (5 humans) in step 4; pulled in step 1, it goes down and hits character_2 in step 5.
    idle, pulled = added["idle"], added["pulled"]
    assert idle["harmed"] == {"character_1": 4, "trolley_0": 4}
    assert idle["utility"][3]["n_human_harm"] == 5
    assert pulled["harmed"] == {"character_2": 5, "trolley_0": 5}
    assert pulled["utility"][4]["n_human_harm"] == 1
    assert pulled["rewards"] == [-1.0, -1.0, -1.0, 100.0, 0.0, 0.0]
    assert pulled["terminated"] == [False] * 4 + [True, True]

    # Directly, the Animal variant (character_1 = 4 animals): agent 4 + lever 2 + 2 characters x 7 + trolley 4.
    assert added["flat"]["shape"] == [24] and added["flat"]["contains"]
    assert [u.get("n_animal_harm", 0) for u in added["flat"]["utility"]] == [0, 0, 0, 4]

    # The vectorised face works on it too (it enumerates the whole state graph).
    assert added["vector"] == {"shape": [3, 24], "first_matches": True}


def test_a_new_scenario_gets_a_generated_env_class_docstring(added: dict[str, Any]) -> None:
    cls = added["class"]
    assert cls["name"] == "TinySwitchEnv" and cls["is_trolley_env"]
    doc = cls["doc"] or ""
    assert doc.startswith("TinySwitch: A four-by-five switch dilemma")
    for text in (
        "A 4x5 grid",
        "G#/##\n..P..\nhS<<T\nh<###",  # the picture of the first variant
        "`switch_1` at (2, 1): state 0=left, 1=down; set by `lever_1` at (0, 2)",
        "Flat `Box` of size 24",
        "`MoralityGym/TinySwitch-Human-v1`",
        "`MoralityGym/TinySwitch-Animal-v1`",
    ):
        assert text in doc, f"{text!r} not in the generated docstring:\n{doc}"


def test_a_new_scenario_cannot_shadow_an_existing_one(added: dict[str, Any]) -> None:
    """Another file declaring a known scenario is refused; adding the same files again is not an
    error (a spawned worker re-running the user's script does it), and the directory is listed in
    MORALITY_GYM_SCENARIOS for the processes this one starts."""
    assert "already defined" in added["shadow"]
    assert added["again"] == "accepted"
    assert added["missing_dir"] == "NotADirectoryError"
    assert added["inherited"].endswith("user_scenarios0")


_PROBE = """
import json, gymnasium as gym, morality_gym
env = gym.make("MoralityGym/EnvVarSwitch-Human-v1", max_steps=None)
env.reset()
rewards = [env.step(a)[1] for a in (5, 2, 2, 0)]
print(json.dumps({"ids": morality_gym.env_ids("EnvVarSwitch"), "n": len(morality_gym.env_ids()),
                  "rewards": rewards, "doc": type(env.unwrapped).__doc__.splitlines()[0]}))
"""


def _run_with_scenarios(*directories: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "MORALITY_GYM_SCENARIOS": os.pathsep.join(str(d) for d in directories)}
    return subprocess.run(
        [sys.executable, "-c", _PROBE], check=False, capture_output=True, text=True, env=env, cwd=REPO, timeout=120
    )


def test_scenarios_from_the_environment_variable(tmp_path: Path) -> None:
    """A fresh process picks up MORALITY_GYM_SCENARIOS (several directories, os.pathsep-separated)."""
    first, empty = tmp_path / "mine", tmp_path / "empty"
    first.mkdir()
    empty.mkdir()
    (first / "env_var_switch.yaml").write_text(_tiny("EnvVarSwitch"))
    proc = _run_with_scenarios(empty, first)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["ids"] == ["EnvVarSwitch-Human-v1", "EnvVarSwitch-Animal-v1"]
    assert out["n"] == 100
    assert out["rewards"] == [-1.0, -1.0, -1.0, 100.0]
    assert out["doc"].startswith("EnvVarSwitch: A four-by-five switch dilemma")

    # A broken file there is skipped with a one-line warning (file, field, fix): the import and the
    # built-in envs keep working (issue 11); only asking for the broken scenario fails, saying why.
    (first / "env_var_switch.yaml").write_text(_tiny("EnvVarSwitch").replace("lever: 1}", "lever: 2}"))
    proc = _run_with_scenarios(first)
    assert proc.returncode != 0 and "Traceback" in proc.stderr  # the probe itself asks for the scenario
    warning = [line for line in proc.stderr.splitlines() if "ScenarioFileWarning" in line]
    assert len(warning) == 1 and "  name: EnvVarSwitch" not in proc.stderr, proc.stderr  # one line, no source line
    assert "env_var_switch.yaml: ScenarioFileWarning: skipped this scenario file: switches[0].lever" in warning[0]
    assert "Fix: " in warning[0]
