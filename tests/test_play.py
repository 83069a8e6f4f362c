"""The terminal game, driven through ``play.run`` with real streams (pipes, StringIO, a pty)."""

from __future__ import annotations

import argparse
import io
import os
import pty
import select
import termios
from pathlib import Path

import pytest

from morality_gym import play


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="morality_gym play")
    play.add_arguments(parser)
    return parser.parse_args(list(argv))


def _play(keys: str, *argv: str) -> tuple[int, str]:
    out = io.StringIO()
    code = play.run(_args(*(argv or ("SwitchStandard-HumanA-v1",))), stdin=io.StringIO(keys), stdout=out)
    return code, out.getvalue()


def test_arguments_and_defaults() -> None:
    args = _args("SwitchStandard-HumanA-v1")
    assert (args.env_id, args.max_steps, args.no_colour) == ("SwitchStandard-HumanA-v1", 200, False)
    assert _args("X", "--max-steps", "5", "--no-color").no_colour is True
    assert _args("X", "--no-colour").max_steps == 200


def test_pull_the_lever_and_reach_the_landmark() -> None:
    # Start at (1, 2) under the lever: pull it, walk left twice and up onto G, then wait for the
    # trolley, now diverted to the side track, to hit the group of one.
    code, out = _play("e\naaw\n..\nq\n")
    assert code == 0
    assert "\x1b[" not in out  # StringIO is not a terminal: no colours
    assert "step 1: INTERACT" in out and "lever_1=1" in out
    assert "step 4: UP" in out and "reward 100   return 97" in out and "landmark reached" in out
    step6 = out[out.index("step 6: STAY") :]
    assert "  outcome: harm, human_harm, trolley_harm" in step6
    assert "  causal:  impersonal_action_caused_harm, impersonal_action_caused_human_harm" in step6
    assert "n_human_harm=1" in step6 and "n_weighted_harm=3" in step6
    assert "terminated=True truncated=False   (player stopped, trolley_0 stopped)" in step6
    summary = out[out.index("=== episode summary") :]
    assert "terminated: the agent reached the landmark" in summary
    assert "return 97   length 6 steps" in summary
    assert "events: harm, human_harm, trolley_harm, impersonal_action_caused_harm" in summary
    assert "harm: human 1, animal 0, robot 0" in summary
    # Steps without events say so rather than print empty categories.
    step2 = out[out.index("step 2: LEFT") : out.index("step 3: LEFT")]
    assert "no norm events" in step2 and "action:" not in step2


def test_quit_right_away() -> None:
    code, out = _play("q\n")
    assert code == 0
    assert "SwitchStandard-HumanA-v1" in out and "G#/###" in out  # the start picture
    assert "step 1" not in out and "episode summary" not in out
    assert out.rstrip().endswith("bye")


def test_unknown_env_id_gives_the_registry_message_and_code_2(capsys: pytest.CaptureFixture[str]) -> None:
    code, out = _play("q\n", "SwitchStandrd-HumanA-v1")
    assert code == 2 and out == ""
    err = capsys.readouterr().err
    assert "Unknown MoralityGym env id 'SwitchStandrd-HumanA-v1'" in err
    assert "Closest valid ids: SwitchStandard-HumanA-v1" in err
    assert "Traceback" not in err
    err_stream = io.StringIO()
    assert play.run(_args("Nope-v1"), stdin=io.StringIO(""), stdout=io.StringIO(), stderr=err_stream) == 2
    assert "Unknown MoralityGym env id 'Nope-v1'" in err_stream.getvalue()


def test_bad_max_steps_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    code, _out = _play("q\n", "SwitchStandard-HumanA-v1", "--max-steps", "-1")
    assert code == 2
    assert "max_steps" in capsys.readouterr().err


def test_help_unknown_keys_and_arrow_sequences() -> None:
    code, out = _play("?x\n\x1b[D\x1b[Bq\n")
    assert code == 0
    assert "keys: w/up" in out
    assert "unknown key 'x' (? for help)" in out
    assert "step 1: LEFT" in out and "step 2: DOWN" in out


def test_restart_resets_the_world() -> None:
    code, out = _play("e\nr\nq\n")
    assert code == 0
    after = out[out.index("restarting") :]
    assert "lever_1=0" in after and "step" not in after
    # the unfinished episode was summarised before the restart
    assert "=== episode summary: unfinished ===" in out[: out.index("restarting")]


def test_moves_after_the_end_are_refused_and_the_input_may_just_end() -> None:
    code, out = _play("eaaw..d\n")  # no q: the end of the input ends the game
    assert code == 0
    assert "the episode is over: r to restart, q to quit" in out
    assert "step 7" not in out
    assert out.count("=== episode summary") == 1


def test_truncation_ends_the_episode() -> None:
    code, out = _play("...\n", "SwitchStandard-HumanA-v1", "--max-steps", "2")
    assert code == 0
    assert "terminated=False truncated=True" in out
    assert "=== episode summary: truncated after 3 steps ===" in out


def _read_all(fd: int) -> str:
    chunks = []
    while select.select([fd], [], [], 0.2)[0]:
        try:
            data = os.read(fd, 65536)
        except OSError:
            break
        if not data:
            break
        chunks.append(data)
    return b"".join(chunks).decode(errors="replace")


def test_terminal_mode_reads_single_keys_and_restores_the_terminal() -> None:
    master, slave = pty.openpty()
    try:
        before = termios.tcgetattr(slave)
        os.write(master, b"e\x1b[Dq")  # typed ahead: interact, left arrow, quit (no Enter needed)
        with os.fdopen(os.dup(slave), "r") as tty_in:
            out = io.StringIO()
            code = play.run(_args("SwitchStandard-HumanA-v1"), stdin=tty_in, stdout=out)
        assert code == 0
        text = out.getvalue()
        assert "step 1: INTERACT" in text and "step 2: LEFT" in text and "step 3" not in text
        assert termios.tcgetattr(slave) == before
    finally:
        os.close(master)
        os.close(slave)


def test_colour_only_on_a_terminal_and_not_with_no_colour() -> None:
    master, slave = pty.openpty()
    try:
        with os.fdopen(os.dup(slave), "w") as tty_out:
            assert play.run(_args("SwitchStandard-HumanA-v1"), stdin=io.StringIO("q\n"), stdout=tty_out) == 0
        assert "\x1b[" in _read_all(master)
        with os.fdopen(os.dup(slave), "w") as tty_out:
            args = _args("SwitchStandard-HumanA-v1", "--no-colour")
            assert play.run(args, stdin=io.StringIO("q\n"), stdout=tty_out) == 0
        plain = _read_all(master)
        assert "G#/###" in plain and "\x1b[" not in plain
    finally:
        os.close(master)
        os.close(slave)


_CTRL_C_CHILD = """
import fcntl, signal, sys, termios
fcntl.ioctl(0, termios.TIOCSCTTY, 0)  # make the pty our controlling terminal, so Ctrl-C is SIGINT
# A user's shell starts a command with Ctrl-C at its default; the test run may not have: a test
# suite started as a background job ('make test &') inherits SIGINT ignored, and so would this child.
signal.signal(signal.SIGINT, signal.default_int_handler)
before = termios.tcgetattr(0)
from morality_gym import play
import argparse
parser = argparse.ArgumentParser()
play.add_arguments(parser)
code = play.run(parser.parse_args(["SwitchStandard-HumanA-v1", "--no-colour"]))
print("EXIT", code, "RESTORED", termios.tcgetattr(0) == before, "END", flush=True)
"""


def _read_until(fd: int, marker: str, timeout: float = 10.0) -> str:
    import time

    text, deadline = "", time.monotonic() + timeout
    while marker not in text and time.monotonic() < deadline:
        if select.select([fd], [], [], 0.1)[0]:
            try:
                text += os.read(fd, 65536).decode(errors="replace")
            except OSError:
                break
    return text


def test_ctrl_c_in_a_real_terminal_restores_it() -> None:
    import subprocess
    import sys

    master, slave = pty.openpty()
    child = subprocess.Popen(
        [sys.executable, "-c", _CTRL_C_CHILD], stdin=slave, stdout=slave, stderr=slave, start_new_session=True
    )
    os.close(slave)
    try:
        assert "keys:" in _read_until(master, "keys:")
        os.write(master, b"e")  # a single key, no Enter
        assert "step 1: INTERACT" in _read_until(master, "step 1: INTERACT")
        os.write(master, b"\x03")  # Ctrl-C
        tail = _read_until(master, "END")
        assert "interrupted" in tail and "EXIT 130 RESTORED True" in tail
        assert child.wait(timeout=10) == 0
    finally:
        if child.poll() is None:
            child.kill()
        os.close(master)


@pytest.mark.skipif(
    not (Path(play.__file__).parent / "__main__.py").is_file(),
    reason="the main CLI (morality_gym/__main__.py) is absent",
)
def test_the_cli_through_a_pipe() -> None:
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "morality_gym", "play", "SwitchStandard-HumanA-v1"]
    done = subprocess.run(cmd, input="e\naaw..\nq\n", capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert "return 97   length 6 steps" in done.stdout and "\x1b[" not in done.stdout


# ---------------------------------------------------------------------------------------- watching an agent
_RULES = '''
import numpy as np

PLAN = {"calls": 0}


def pull_then_stay(obs):
    """Interact once (the lever is adjacent at the start), then stay."""
    PLAN["calls"] += 1
    return 5 if PLAN["calls"] <= 2 else 4


def always_left(obs):
    return 2


def thirds(obs):
    p = np.zeros(6)
    p[[2, 4, 5]] = 1 / 3
    return p


def bad(obs):
    return 9


NOT_CALLABLE = 3
'''


@pytest.fixture()
def rules(tmp_path: Path) -> Path:
    path = tmp_path / "rules.py"
    path.write_text(_RULES)
    return path


def _watch(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    code = play.run(_args(*argv), stdin=io.StringIO(""), stdout=out, stderr=err)
    return code, out.getvalue(), err.getvalue()


def test_watch_a_callable_policy_prints_the_human_mode_steps(rules: Path) -> None:
    code, out, err = _watch("SwitchStandard-HumanA-v1", "--policy", f"{rules}:always_left", "--delay", "0",
                            "--max-steps", "4")
    assert code == 0, err
    assert f"policy: {rules}:always_left" in out and "keys:" not in out
    assert out.count("step 1: LEFT") == 1 and "step 5: LEFT" in out and "step 6" not in out
    assert "=== episode summary: truncated after 5 steps ===" in out and "r to play again" not in out
    assert out.rstrip().endswith("bye")


def test_watch_several_episodes_with_sampled_probabilities_is_reproducible(rules: Path) -> None:
    argv = ("SwitchStandard-HumanA-v1", "--policy", f"{rules}:thirds", "--delay", "0", "--episodes", "3", "--seed", "5")
    code, out, _ = _watch(*argv)
    assert code == 0
    assert "##### episode 3 of 3" in out and out.count("=== episode summary") == 3
    steps = [line for line in out.splitlines() if line.startswith("step ")]
    assert {line.split(": ")[1] for line in steps} <= {"LEFT", "STAY", "INTERACT"}
    assert _watch(*argv)[1] == out  # same seed, same episodes


def test_watch_waits_delay_seconds_between_steps() -> None:
    env = __import__("morality_gym").TrolleyEnv("SwitchStandard-HumanA-v1", max_steps=2)
    slept: list[float] = []
    game = play.Game(env, io.StringIO(), colour=False, watching="random")
    assert play.watch(game, lambda obs, sid: 4, episodes=1, delay=0.25, sleep=slept.append) == 0
    assert slept == [0.25, 0.25, 0.25]  # three steps: truncation on step max_steps + 1


def test_watch_random_and_a_gif_per_episode(tmp_path: Path) -> None:
    target = tmp_path / "out.gif"
    code, out, err = _watch("SwitchStandard-HumanA-v1", "--policy", "random", "--episodes", "2", "--seed", "1",
                            "--render", str(target))
    assert code == 0, err
    assert target.is_file() and (tmp_path / "out-2.gif").is_file()
    lines = out.strip().splitlines()
    assert len(lines) == 2 and lines[0].startswith(f"{target}: ") and "return" in lines[0]


@pytest.mark.parametrize(
    ("policy", "message"),
    [
        ("{rules}:always_lef", "'always_lef' not found (did you mean always_left?)"),
        ("{rules}:NOT_CALLABLE", "is a int, not a callable"),
        ("{rules}:bad", "the policy returned action 9"),
        ("no_such_module_xyz:act", "cannot import module 'no_such_module_xyz'"),
        ("{tmp}/nope.zip", "does not exist"),
    ],
)
def test_watch_policy_errors_are_one_line_exit_2(rules: Path, tmp_path: Path, policy: str, message: str) -> None:
    code, out, err = _watch("SwitchStandard-HumanA-v1", "--policy", policy.format(rules=rules, tmp=tmp_path))
    assert code == 2 and out == ""
    assert message in err and len(err.strip().splitlines()) == 1 and err.startswith("morality_gym play: error:")


def test_render_needs_a_policy_and_a_gif_name(rules: Path) -> None:
    code, _, err = _watch("SwitchStandard-HumanA-v1", "--render", "x.gif")
    assert code == 2 and "--render needs --policy" in err
    code, _, err = _watch("SwitchStandard-HumanA-v1", "--policy", "random", "--render", "x.png")
    assert code == 2 and "ending in .gif, or 'window'" in err


def test_play_policy_from_the_command_line(rules: Path, tmp_path: Path) -> None:
    import subprocess
    import sys

    ok = subprocess.run([sys.executable, "-m", "morality_gym", "play", "SwitchStandard-HumanA-v1", "--policy",
                         f"{rules}:pull_then_stay", "--delay", "0", "--max-steps", "6"],
                        check=False, capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stderr
    assert "step 1: INTERACT" in ok.stdout and "step 3: STAY" in ok.stdout and "lever_1=1" in ok.stdout
    bad = subprocess.run([sys.executable, "-m", "morality_gym", "play", "SwitchStandard-HumanA-v1", "--policy",
                          f"{rules}:bad"], check=False, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and "the policy returned action 9" in bad.stderr
    delay = subprocess.run([sys.executable, "-m", "morality_gym", "play", "SwitchStandard-HumanA-v1", "--policy",
                            "random", "--delay", "-1"], check=False, capture_output=True, text=True, timeout=120)
    assert delay.returncode == 2 and "--delay" in delay.stderr
