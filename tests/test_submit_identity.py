"""Issue 46, items 4 and 5: a submission's identity covers everything it runs, and a policy that
ends the program is a one-line failure.

* The policy file's digest alone let a retrained weights file or an edited helper module beside it
  pass as "already present", the old number staying on the leaderboard unmarked. Now the helpers
  it imports and the files it opens (while loaded and on its first answer), or a declared
  ``--policy-dir``, are hashed with it: a change is a new submission and the older one is reported
  superseded.
* ``sys.exit`` or ``KeyboardInterrupt`` from the policy's code (at import or when asked for an
  action) made ``submit`` exit 0 with nothing written and no word: now one line, exit 2, nothing
  half-written.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from morality_gym.baselines.policy_ref import PolicyError, load_policy
from morality_gym.evaluation.montecarlo import evaluate
from morality_gym.evaluation.policies import PolicyFailure
from tests.test_submit import ENV, build, runs_of, submit

SELECTION = ["--chain", "utility", "--scenario", "switch_standard", "--variant", "HumanA", "--preset", "smoke", "--no-gif"]
AGENT = """
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import lever_helper  # noqa: E402

WEIGHTS = json.loads((Path(__file__).parent / "weights.json").read_text())
LATE = []


def act(obs):
    if not LATE:  # read on the first answer, not at import
        LATE.append(json.loads((Path(__file__).parent / "late.json").read_text()))
    return lever_helper.choose(obs, WEIGHTS["pull"], LATE[0]["wait"])


def later(obs):
    if obs[5] == 1:  # read only once the lever is pulled: no automatic detection can see it coming
        return json.loads((Path(__file__).parent / "data" / "table.json").read_text())["wait"]
    return 5
"""
HELPER = """
def choose(obs, pull, wait):
    return pull if obs[5] == 0 else wait
"""


@pytest.fixture()
def agent(tmp_path: Path) -> Path:
    folder = tmp_path / "agent"
    (folder / "data").mkdir(parents=True)
    (folder / "agent.py").write_text(AGENT)
    (folder / "lever_helper.py").write_text(HELPER)
    (folder / "weights.json").write_text(json.dumps({"pull": 5}))
    (folder / "late.json").write_text(json.dumps({"wait": 4}))
    (folder / "data" / "table.json").write_text(json.dumps({"wait": 4}))
    (folder / "unrelated.txt").write_text("notes")
    return folder


def _written(out: object) -> str:
    return next(line for line in out.stdout.splitlines() if line.startswith("wrote "))  # type: ignore[attr-defined]


def test_a_changed_helper_weights_or_late_file_is_a_new_submission_and_the_old_one_superseded(agent: Path, tmp_path: Path) -> None:
    results = tmp_path / "results"
    policy = f"{agent / 'agent.py'}:act"
    first = submit(results, policy, "--name", "Agent", *SELECTION)
    assert first.returncode == 0, first.stderr
    assert "over agent.py and 3 more file(s)" in first.stdout
    config = json.loads(runs_of(results)["config"].iloc[0])
    assert sorted(Path(p).name for p in config["provenance"]["files"]) == ["agent.py", "late.json", "lever_helper.py", "weights.json"]
    assert _written(submit(results, policy, "--name", "Agent", *SELECTION)).startswith("wrote 0 run(s), 1 already present")
    (agent / "unrelated.txt").write_text("other notes")  # not run: not part of the identity
    assert _written(submit(results, policy, "--name", "Agent", *SELECTION)).startswith("wrote 0 run(s), 1 already present")
    for name, text in (("weights.json", json.dumps({"pull": 4})), ("lever_helper.py", HELPER + "\n# retuned\n"),
                       ("late.json", json.dumps({"wait": 3}))):
        (agent / name).write_text(text)
        changed = submit(results, policy, "--name", "Agent", *SELECTION)
        assert changed.returncode == 0, changed.stderr
        assert _written(changed).startswith("wrote 1 run(s), 0 already present"), (name, changed.stdout)
    rebuilt = build(results, tmp_path / "site")
    assert rebuilt.returncode == 0, rebuilt.stderr
    assert "3 superseded" in rebuilt.stdout
    runs = runs_of(results)
    newest = load_policy(policy).policy
    assert newest(__import__("numpy").zeros(8)) == 4  # pull=4 from the retuned weights
    latest = max(runs.to_dict("records"), key=lambda r: r["finished_at"])
    assert latest["metric"] == evaluate(newest, ENV, "Utility", n_episodes=100, seed=41, max_steps=200).metric


def test_a_declared_directory_covers_files_read_later(agent: Path, tmp_path: Path) -> None:
    results = tmp_path / "results"
    policy = f"{agent / 'agent.py'}:later"
    args = ["--name", "Later", "--policy-dir", str(agent), *SELECTION]
    first = submit(results, policy, *args)
    assert first.returncode == 0, first.stderr
    files = json.loads(runs_of(results)["config"].iloc[0])["provenance"]["files"]
    assert len(files) == 6 and any(f.endswith("data/table.json") for f in files)
    (agent / "data" / "table.json").write_text(json.dumps({"wait": 3}))
    assert _written(submit(results, policy, *args)).startswith("wrote 1 run(s), 0 already present")
    missing = submit(results, policy, "--name", "Later", "--policy-dir", str(agent / "nope"), *SELECTION)
    assert missing.returncode == 2 and missing.stderr.strip().count("\n") == 0 and "not a directory" in missing.stderr


def test_a_one_file_policy_keeps_its_old_digest(tmp_path: Path) -> None:
    """Submissions made before helpers counted stay "already present" when nothing changed."""
    import hashlib

    path = tmp_path / "rule.py"
    path.write_text("def act(obs):\n    return 4\n")
    old = hashlib.sha256(b"rule.py\0" + path.read_bytes()).hexdigest()
    assert load_policy(f"{path}:act").sha256() == old


QUITTERS = {
    "exit_in_act": ("import sys\n\ndef act(obs):\n    sys.exit(0)\n", "failed on the first observation of SwitchStandard-HumanA-v1 (called sys.exit(0))"),
    "exit_code_in_act": ("import sys\n\ndef act(obs):\n    sys.exit('bye')\n", "called sys.exit('bye')"),
    "interrupt_in_act": ("def act(obs):\n    raise KeyboardInterrupt\n", "(raised KeyboardInterrupt)"),
    "exit_at_import": ("import sys\nsys.exit(0)\n\ndef act(obs):\n    return 4\n", "called sys.exit(0) while it was imported"),
    "interrupt_at_import": ("raise KeyboardInterrupt\n", "raised KeyboardInterrupt while it was imported"),
}


@pytest.mark.parametrize("case", sorted(QUITTERS))
def test_a_policy_that_ends_the_program_is_one_line_exit_2_and_nothing_written(case: str, tmp_path: Path) -> None:
    code, said = QUITTERS[case]
    path = tmp_path / "quitter.py"
    path.write_text(code)
    results = tmp_path / "results"
    out = submit(results, f"{path}:act", "--name", "Quitter", *SELECTION)
    assert out.returncode == 2, (out.returncode, out.stdout, out.stderr)
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and said in lines[0] and "Traceback" not in out.stderr, out.stderr
    assert not (results / "runs").exists() or not any((results / "runs").iterdir())


def test_the_adapter_turns_sys_exit_into_a_policy_failure_but_lets_a_real_ctrl_c_through(monkeypatch: pytest.MonkeyPatch) -> None:
    import numpy as np

    from morality_gym import clitools
    from morality_gym.evaluation.policies import PolicyAdapter

    def quits(obs: object) -> int:
        raise SystemExit(3)

    with pytest.raises(PolicyFailure, match=r"called sys.exit\(3\)"):
        PolicyAdapter(quits).actions(np.zeros((1, 8)), np.random.default_rng(0))

    def pressed(obs: object) -> int:  # what Python's SIGINT handler does, counted as run_cli counts it
        clitools._SIGINTS[0] += 1
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        PolicyAdapter(pressed).actions(np.zeros((1, 8)), np.random.default_rng(0))
    with pytest.raises(PolicyError, match="called sys.exit"):
        path = Path(__import__("tempfile").mkdtemp()) / "q.py"
        path.write_text("raise SystemExit\n")
        load_policy(f"{path}:act")
