"""Policy references (``random``, saved models, ``file.py:function``, ``module:function``) and the
policies they name, as ``eval``, ``play``, ``record_episode`` and ``leaderboard.submit`` take them."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import morality_gym
from morality_gym.baselines.policy_ref import PolicyError, is_stationary, load_policy, probe
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.montecarlo import evaluate

ENV = "SwitchStandard-HumanA-v1"
RULES = """
import numpy as np

COUNT = {"n": 0}


def interact(obs):
    return 5


def mostly_stay(obs):
    p = np.full(6, 0.05)
    p[4] = 0.75
    return p


def alternate(obs):
    COUNT["n"] += 1
    return COUNT["n"] % 2


def ragged(obs):
    return [0.5, 0.5]


class Agent:
    def act(self, obs):
        return 4


AGENT = Agent()
"""


@pytest.fixture()
def rules(tmp_path: Path) -> Path:
    path = tmp_path / "my_rules.py"
    path.write_text(RULES)
    return path


def test_references_resolve_to_their_kind_and_files(rules: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    assert load_policy("random").kind == "random" and load_policy(None).policy == "random"
    by_file = load_policy(f"{rules}:interact")
    assert by_file.kind == "callable" and by_file.policy(np.zeros(3)) == 5 and by_file.files == (rules.resolve(),)
    assert load_policy(f"{rules}:AGENT.act").policy(None) == 4  # dotted attributes
    monkeypatch.syspath_prepend(str(tmp_path))
    by_module = load_policy("my_rules:interact")
    assert by_module.kind == "callable" and by_module.files == (rules.resolve(),)
    assert by_module.sha256() == by_file.sha256()
    (tmp_path / "my_rules.json").write_text("{}")  # a sibling that looks like model metadata changes nothing
    assert load_policy(f"{rules}:interact").kind == "callable"
    before = by_file.sha256()
    rules.write_text(RULES + "\n# edited\n")
    assert load_policy(f"{rules}:interact").sha256() != before  # a changed file is another policy


@pytest.mark.parametrize(
    ("ref", "message"),
    [
        ("{rules}:interac", "'interac' not found (did you mean interact?)"),
        ("{tmp}/none.py:act", "no file"),
        ("surely_no_such_module_here:act", "cannot import module 'surely_no_such_module_here'"),
        ("{tmp}/model.zip", "does not exist"),
        ("", "empty policy reference"),
    ],
)
def test_bad_references_name_the_problem(rules: Path, tmp_path: Path, ref: str, message: str) -> None:
    with pytest.raises(PolicyError) as info:
        load_policy(ref.format(rules=rules, tmp=tmp_path))
    assert message in str(info.value) and "\n" not in str(info.value)


def test_a_broken_policy_file_is_a_policy_error(tmp_path: Path) -> None:
    broken = tmp_path / "broken.py"
    broken.write_text("raise RuntimeError('no model weights here')\n")
    with pytest.raises(PolicyError, match="failed to import .*no model weights here"):
        load_policy(f"{broken}:act")


def test_probe_and_stationarity(rules: Path) -> None:
    from morality_gym.envs.trolley import InvalidActionError

    probe(load_policy(f"{rules}:interact"), ENV)
    with pytest.raises(InvalidActionError, match="not numbers|shape"):
        probe(load_policy(f"{rules}:ragged"), ENV)
    assert is_stationary(load_policy("random"), ENV)
    assert is_stationary(load_policy(f"{rules}:mostly_stay"), ENV)
    assert not is_stationary(load_policy(f"{rules}:alternate"), ENV)  # answers depend on the call count


def test_monte_carlo_samples_a_callables_probabilities_like_a_table(rules: Path) -> None:
    """A callable answering probabilities is sampled with the evaluator's generator, one draw per
    step, exactly as a table with the same probabilities is: the two evaluations are identical."""
    policy = load_policy(f"{rules}:mostly_stay").policy
    graph = morality_gym.TrolleyEnv(ENV).graph.tables()
    table = np.array([policy(o) for o in graph.obs])  # state-aligned
    a = evaluate(policy, ENV, "Utility", n_episodes=200, seed=3)
    b = evaluate(table, ENV, "Utility", n_episodes=200, seed=3)
    assert (a.metric, a.mean_return, a.mean_length) == (b.metric, b.mean_return, b.mean_length)
    exact = exact_evaluate(policy, ENV, "Utility")
    assert a.metric == pytest.approx(exact.metric, abs=4 * a.metric_stderr + 1e-9)


def test_eval_command_takes_a_callable_reference(rules: Path) -> None:
    base = [sys.executable, "-m", "morality_gym", "eval", "--chain", "Utility", "--scenario", "SwitchStandard",
            "--variant", "HumanA", "--exact", "--json"]
    out = subprocess.run(base + ["--policy", f"{rules}:mostly_stay"], check=False, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    expected = exact_evaluate(load_policy(f"{rules}:mostly_stay").policy, ENV, "Utility").metric
    assert json.loads(out.stdout)["envs"][ENV]["metric"] == pytest.approx(expected, abs=1e-12)
    bad = subprocess.run(base + ["--policy", f"{rules}:ragged"], check=False, capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


def test_a_table_keyed_by_rounded_observations_works_in_monte_carlo_too() -> None:
    """A ``Mapping`` keyed by ``tuple(np.round(obs, 6))`` (as documented) was found by the exact
    evaluator but not by Monte Carlo, whose batched env observes in float32 (KeyError)."""
    graph = morality_gym.TrolleyEnv(ENV).graph.tables()
    table = {tuple(np.round(o, 6).tolist()): [0, 0, 0, 0, 1, 0] for o in graph.obs}
    mc = evaluate(table, ENV, "Utility", n_episodes=5, seed=1)
    assert mc.metric == exact_evaluate(table, ENV, "Utility").metric and mc.mean_length == 201


def test_a_policy_failing_on_some_state_is_named(tmp_path: Path) -> None:
    from morality_gym.envs.trolley import InvalidActionError

    path = tmp_path / "picky.py"
    path.write_text("def act(obs):\n    if obs[5] == 1:\n        raise KeyError('lever pulled')\n    return 5\n"
                    "def bad_later(obs):\n    return 5 if obs[5] == 0 else 7\n")
    probe(load_policy(f"{path}:act"), ENV)  # fine on the first observation
    with pytest.raises(PolicyError, match="failed on a reachable state of SwitchStandard-HumanA-v1 .KeyError"):
        is_stationary(load_policy(f"{path}:act"), ENV)
    with pytest.raises(InvalidActionError, match="returned action 7"):
        is_stationary(load_policy(f"{path}:bad_later"), ENV)
