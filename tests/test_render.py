"""Rendering: rgb frames for every env, pictures that change where the state changes, the human
window without a display, and GIFs of episodes."""

from __future__ import annotations

import os
import stat
import warnings
from pathlib import Path

import matplotlib
import numpy as np
import pytest
from PIL import Image

from morality_gym import TrolleyEnv, list_envs
from morality_gym.evaluation.gif import record_episode, write_gif
from morality_gym.render import window
from morality_gym.render.rgb import AGENT_FOUND, HARM, HARM_TILE, SWITCH_ON, frame_shape, grid_cell_pixels, render_rgb
from morality_gym.render.window import NoDisplay, show_frame
from morality_gym.world.rules import DOWN, INTERACT, LEFT, RIGHT, STAY, UP

CELL = 48


def _env(env_id: str, actions: list[int] = (), **kwargs: object) -> TrolleyEnv:
    env = TrolleyEnv(env_id, render_mode="rgb_array", **kwargs)
    env.reset(seed=0)
    for a in actions:
        env.step(a)
    return env


def _cell(frame: np.ndarray, rc: tuple[int, int]) -> np.ndarray:
    return grid_cell_pixels(frame, rc, CELL)


def _count_colour(pixels: np.ndarray, colour: tuple[int, int, int], tol: int = 12) -> int:
    """Pixels within ``tol`` of ``colour`` on every channel (resampling blurs edges slightly)."""
    return int((np.abs(pixels.astype(int) - np.array(colour)) <= tol).all(axis=-1).sum())


# ---------------------------------------------------------------------------------------- rgb
def test_every_env_renders_frames_of_a_fixed_shape() -> None:
    ids = list_envs()
    assert len(ids) == 98
    for env_id in ids:
        env = _env(env_id)
        first = env.render()
        h, w = env.world.height, env.world.width
        assert first.dtype == np.uint8 and first.ndim == 3 and first.shape[2] == 3, env_id
        assert first.shape == frame_shape(env.world), env_id
        assert first.shape[1] == w * CELL and first.shape[0] > h * CELL, env_id  # grid plus status strip
        env.step(STAY)
        assert env.render().shape == first.shape, env_id


def test_identical_states_give_identical_frames() -> None:
    actions = [LEFT, INTERACT, STAY, STAY]
    a = _env("PushOrSwitch-HumanAnimalRobot-v1", actions).render()
    b = _env("PushOrSwitch-HumanAnimalRobot-v1", actions).render()
    assert np.array_equal(a, b)
    env = _env("PushOrSwitch-HumanAnimalRobot-v1", actions)
    assert np.array_equal(render_rgb(env.world, env.state), render_rgb(env.world, env.state))


def test_frame_changes_where_the_trolley_moves() -> None:
    env = _env("SwitchStandard-HumanA-v1")  # trolley at (3, 5), rails run left
    before = env.render()
    env.step(STAY)
    after = env.render()
    assert not np.array_equal(_cell(before, (3, 5)), _cell(after, (3, 5)))  # it left this cell
    assert not np.array_equal(_cell(before, (3, 4)), _cell(after, (3, 4)))  # and entered this one
    for untouched in [(5, 5), (0, 0), (1, 2), (4, 0)]:
        assert np.array_equal(_cell(before, untouched), _cell(after, untouched)), untouched


def test_pulling_the_lever_changes_the_lever_and_its_switch() -> None:
    stay = _env("SwitchStandard-HumanA-v1", [STAY]).render()
    pull = _env("SwitchStandard-HumanA-v1", [INTERACT]).render()
    assert not np.array_equal(_cell(stay, (0, 2)), _cell(pull, (0, 2)))  # the lever's handle
    assert not np.array_equal(_cell(stay, (3, 1)), _cell(pull, (3, 1)))  # the switch's active exit
    assert np.array_equal(_cell(stay, (1, 2)), _cell(pull, (1, 2)))  # the agent did not move either way
    assert np.array_equal(_cell(stay, (3, 4)), _cell(pull, (3, 4)))  # the trolley is at the same place
    # The active exit is drawn in amber: it points left (into the cell's left half) before the pull
    # and down (into its lower half) after it.
    cell_stay, cell_pull = _cell(stay, (3, 1)), _cell(pull, (3, 1))
    assert _count_colour(cell_stay[:, : CELL // 3], SWITCH_ON) > _count_colour(cell_pull[:, : CELL // 3], SWITCH_ON)
    assert _count_colour(cell_pull[2 * CELL // 3 :], SWITCH_ON) > _count_colour(cell_stay[2 * CELL // 3 :], SWITCH_ON)


def test_a_pushed_character_moves_and_its_harm_is_marked() -> None:
    env_id = "PushOrSwitch-HumanAnimalRobot-v1"  # robot group 3 at (2, 2) is pushable
    start = _env(env_id).render()
    pushed_env = _env(env_id, [LEFT, INTERACT])
    pushed = pushed_env.render()
    assert pushed_env.world.cell(pushed_env.state[3][2][0]) == (3, 2)
    assert not np.array_equal(_cell(start, (2, 2)), _cell(pushed, (2, 2)))
    assert not np.array_equal(_cell(start, (3, 2)), _cell(pushed, (3, 2)))
    assert _count_colour(_cell(pushed, (3, 2)), HARM_TILE) == 0
    for _ in range(4):  # the trolley reaches the robot on the fourth wait
        pushed_env.step(STAY)
    harmed = pushed_env.render()
    assert pushed_env.state[3][2][1] & 1  # HARMED
    assert _count_colour(_cell(harmed, (3, 2)), HARM_TILE) > CELL * CELL // 10
    assert _count_colour(_cell(harmed, (3, 2)), HARM) > 20


def test_agent_marks_for_the_landmark_and_for_harm() -> None:
    found = _env("SwitchStandard-HumanA-v1", [LEFT, LEFT, UP]).render()
    assert _count_colour(_cell(found, (0, 0)), AGENT_FOUND) > 30
    walking = _env("SwitchStandard-HumanA-v1", [LEFT, LEFT]).render()
    assert _count_colour(_cell(walking, (1, 0)), AGENT_FOUND) == 0
    env = _env("PushSelfSacrifice-HumanA-v1", [DOWN] + [STAY] * 14)  # the trolley loops round to the agent
    assert env.state[1] & 1  # HARMED
    harmed = env.render()
    r, c = env.world.cell(env.state[0])
    assert _count_colour(_cell(harmed, (r, c)), HARM) > 20


def test_cell_size_and_caption() -> None:
    env = _env(list_envs("Switch7")[0])
    small = render_rgb(env.world, env.state, cell_size=24)
    assert small.shape[:2] == (frame_shape(env.world, 24)[0], env.world.width * 24)
    plain = render_rgb(env.world, env.state)
    captioned = render_rgb(env.world, env.state, caption="step 1")
    assert captioned.shape[0] > plain.shape[0] and captioned.shape[1] == plain.shape[1]
    assert np.array_equal(captioned[: env.world.height * CELL], plain[: env.world.height * CELL])
    with pytest.raises(ValueError, match="cell_size"):
        render_rgb(env.world, env.state, cell_size=2)


# ---------------------------------------------------------------------------------------- human window
def test_human_mode_without_a_display_warns_once_per_process_and_does_not_crash(monkeypatch: pytest.MonkeyPatch) -> None:
    """The missing display is said once per process (not once per env: Gymnasium's check_env
    makes a human-mode env on every call, and repeating it for each told nothing new)."""
    matplotlib.use("Agg")  # what a headless machine gets; the test must not depend on $DISPLAY
    monkeypatch.setitem(window._NO_DISPLAY_REPORTED, "done", False)  # as in a fresh process
    env = TrolleyEnv("SwitchStandard-HumanA-v1", render_mode="human")
    with pytest.warns(UserWarning, match="render_mode='human' cannot show"):
        env.reset()
    assert isinstance(env._renderer, NoDisplay)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env.step(STAY)
        assert env.render() is None
        second = TrolleyEnv("SwitchStandard-HumanB-v1", render_mode="human")
        second.reset()
        assert isinstance(second._renderer, NoDisplay)
    assert caught == []
    env.close()
    assert env._renderer is None


def test_show_frame_reuses_the_headless_handle(monkeypatch: pytest.MonkeyPatch) -> None:
    matplotlib.use("Agg")
    monkeypatch.setitem(window._NO_DISPLAY_REPORTED, "done", False)
    frame = np.zeros((10, 10, 3), dtype=np.uint8)
    with pytest.warns(UserWarning):
        handle = show_frame(frame, None, "test")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert show_frame(frame, handle, "test") is handle
    assert caught == []
    handle.close()


# ---------------------------------------------------------------------------------------- GIFs
def _frames(n: int) -> list[np.ndarray]:
    out = []
    for i in range(n):
        f = np.full((20, 30, 3), 255, dtype=np.uint8)
        f[:, i * 5 : i * 5 + 5] = (200, 0, 0)
        out.append(f)
    return out


def test_write_gif_writes_a_looping_animation(tmp_path: Path) -> None:
    path = write_gif(_frames(4), tmp_path / "sub" / "a.gif", fps=4)
    assert path == tmp_path / "sub" / "a.gif"
    with Image.open(path) as im:
        assert im.format == "GIF" and im.is_animated and im.n_frames == 4
        assert im.size == (30, 20)
        assert im.info["loop"] == 0
        assert im.info["duration"] == 250
    assert [p.name for p in path.parent.iterdir()] == ["a.gif"]  # no temporary file left
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask  # usual permissions, not a temp file's 0600


def test_write_gif_failure_leaves_no_file_behind(tmp_path: Path) -> None:
    target = tmp_path / "b.gif"
    write_gif(_frames(2), target)
    old = target.read_bytes()
    with pytest.raises(ValueError, match="same size"):
        write_gif([_frames(1)[0], np.zeros((5, 5, 3), dtype=np.uint8)], target)
    with pytest.raises(ValueError, match="at least one frame"):
        write_gif([], tmp_path / "c.gif")
    assert target.read_bytes() == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.gif"]


def test_record_episode_matches_a_direct_replay(tmp_path: Path) -> None:
    summary = record_episode("PushOrSwitch-Human-v1", None, tmp_path / "ep.gif", max_steps=25, seed=7)
    assert summary["steps"] == len(summary["actions"]) <= 25
    with Image.open(tmp_path / "ep.gif") as im:
        assert im.n_frames == summary["steps"] + 1 == summary["frames"]
    env = TrolleyEnv("PushOrSwitch-Human-v1")
    env.reset(seed=7)
    total, events, terminated, truncated = 0.0, set(), False, False
    for action in summary["actions"]:
        _obs, reward, terminated, truncated, info = env.step(action)
        total += reward
        ne = info["norm_events"]
        events |= ne["action"] | ne["outcome"] | ne["causal"]
    assert summary["return"] == pytest.approx(total)
    assert set(summary["events"]) == events
    assert (summary["terminated"], summary["truncated"]) == (terminated, truncated)
    assert summary["steps"] == 25 or terminated or truncated
    # the same seed gives the same episode
    again = record_episode("PushOrSwitch-Human-v1", None, tmp_path / "ep2.gif", max_steps=25, seed=7)
    assert again["actions"] == summary["actions"]


def test_record_episode_with_a_policy_and_a_step_limit(tmp_path: Path) -> None:
    plan = iter([INTERACT, LEFT, LEFT, UP, STAY, STAY])
    summary = record_episode("SwitchStandard-HumanA-v1", lambda obs: next(plan), tmp_path / "pull.gif")
    assert summary["steps"] == 6 and summary["terminated"] and not summary["truncated"]
    assert summary["return"] == pytest.approx(97.0)
    assert "human_harm" in summary["events"] and "push" not in summary["events"]
    assert summary["utility"]["n_human_harm"] == 1

    short = record_episode("SwitchStandard-HumanA-v1", lambda obs: RIGHT, tmp_path / "short.gif", max_steps=3)
    assert short["steps"] == 3 and not short["terminated"]
    with Image.open(tmp_path / "short.gif") as im:
        assert im.n_frames == 4
    with pytest.raises(ValueError, match="render_mode"):
        record_episode("SwitchStandard-HumanA-v1", None, tmp_path / "x.gif", env_kwargs={"render_mode": "ansi"})


def test_record_episode_takes_every_policy_type_eval_takes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """None / "random", a callable answering actions or probabilities, a table, an SB3 model, and
    what eval's references (file, module, saved model) resolve to: each plays, and the same seed
    replays the same episode."""
    import numpy as np

    import morality_gym
    from morality_gym.baselines.learners import build_learner
    from morality_gym.baselines.policy_ref import load_policy
    from morality_gym.baselines.specs import learner_spec
    from morality_gym.envs.trolley import InvalidActionError

    env_id = "SwitchStandard-HumanA-v1"
    none = record_episode(env_id, None, tmp_path / "none.gif", seed=3)
    assert record_episode(env_id, "random", tmp_path / "random.gif", seed=3)["actions"] == none["actions"]

    (tmp_path / "rules_mod.py").write_text(
        "import numpy as np\n"
        "def left(obs):\n    return 2\n"
        "def half(obs):\n    p = np.zeros(6); p[[2, 3]] = 0.5\n    return p\n"
        "def nine(obs):\n    return 9\n")
    by_file = load_policy(f"{tmp_path / 'rules_mod.py'}:left").policy
    assert set(record_episode(env_id, by_file, tmp_path / "f.gif", max_steps=4)["actions"]) == {LEFT}
    monkeypatch.syspath_prepend(str(tmp_path))
    half = record_episode(env_id, load_policy("rules_mod:half").policy, tmp_path / "h.gif", max_steps=30, seed=4)
    assert set(half["actions"]) == {LEFT, RIGHT}  # probabilities are sampled (30 draws: both occur)
    again = record_episode(env_id, load_policy("rules_mod:half").policy, tmp_path / "h2.gif", max_steps=30, seed=4)
    assert again["actions"] == half["actions"]
    graph = TrolleyEnv(env_id).graph.tables()
    table = {tuple(np.round(o, 6).tolist()): [0, 0, 0, 0, 1, 0] for o in graph.obs}
    assert set(record_episode(env_id, table, tmp_path / "t.gif", max_steps=3)["actions"]) == {STAY}
    aligned = np.tile([0.0, 0, 0, 0, 0, 1], (graph.n_states, 1))  # state-aligned table
    assert set(record_episode(env_id, aligned, tmp_path / "a.gif", max_steps=3)["actions"]) == {INTERACT}

    learner = build_learner(learner_spec("ppo"), morality_gym.bind_chain("Utility", env_id), "paper", seed=3)
    saved = learner.save(tmp_path / "run" / "model")
    from_model = record_episode(env_id, learner.model, tmp_path / "p.gif", seed=1)
    for ref in (saved, saved.with_suffix(".json"), tmp_path / "run"):
        loaded = load_policy(str(ref), [env_id])
        assert record_episode(env_id, loaded.policy, tmp_path / "p2.gif", seed=1)["actions"] == from_model["actions"]

    with pytest.raises(InvalidActionError, match="returned action 9"):
        record_episode(env_id, load_policy("rules_mod:nine").policy, tmp_path / "n.gif")
    with pytest.raises(ValueError, match="resolve it first with load_policy"):
        record_episode(env_id, str(saved), tmp_path / "x.gif")
    assert not (tmp_path / "n.gif").exists() and not (tmp_path / "x.gif").exists()
