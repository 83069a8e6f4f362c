"""Step-wise cost, wrappers, Monte-Carlo and exact evaluation, the oracle and the eval/oracle CLI."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import morality_gym
from morality_gym import TrolleyEnv, VectorCost, bind_chain
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.montecarlo import evaluate
from morality_gym.evaluation.oracle import oracle
from morality_gym.norms.wrappers import MoralityWrapper, RewardCostSpec

PUSH = [2, 5] + [4] * 12  # LEFT, INTERACT: push the bystander in PushOrSwitch
SWITCH = [3, 5] + [4] * 12  # RIGHT, INTERACT: pull the lever
NOTHING = [4] * 14


def _episode_costs(env: TrolleyEnv, cost: VectorCost, actions: list[int]) -> list[float]:
    env.reset()
    out = []
    for a in actions:
        _, _, term, trunc, info = env.step(a)
        out.append(cost.from_norm_events(info["norm_events"], ended=term or trunc))
    return out


def test_cost_probes_minimal_memory_never_vs_per_episode() -> None:
    """evaluation.md 5.3: the second identical push episode costs less if the memory is never reset."""
    env = TrolleyEnv("PushOrSwitch-Human-v1")
    bound = bind_chain("DualProcess", "PushOrSwitch-Human-v1")
    never = VectorCost(bound, mode="minimal", scale=1.0, reset="never")
    assert sum(_episode_costs(env, never, PUSH)) == pytest.approx(0.925623, abs=1e-6)
    assert sum(_episode_costs(env, never, PUSH)) == pytest.approx(0.016529, abs=1e-6)
    wrapped = MoralityWrapper(TrolleyEnv("PushOrSwitch-Human-v1"), bound, RewardCostSpec(cost_reset="per_episode"))
    for _ in range(2):
        wrapped.reset()
        total = 0.0
        for a in PUSH:
            total += wrapped.step(a)[4]["cost"]
        assert total == pytest.approx(0.925623, abs=1e-6)


def test_cost_probes_full_mode_shaping() -> None:
    """evaluation.md 5.4: PPO-Shaped costs (full mode, scale 50)."""
    env = TrolleyEnv("PushOrSwitch-Human-v1")
    dp = VectorCost(bind_chain("DualProcess", "PushOrSwitch-Human-v1"), mode="full", scale=50.0)
    u = VectorCost(bind_chain("Utility", "PushOrSwitch-Human-v1"), mode="full", scale=50.0)
    for cost, expected in ((dp, (47.619, 1.190, 2.381)), (u, (0.0, 25.0, 50.0))):
        got = [sum(_episode_costs(env, cost, acts)) for acts in (PUSH, SWITCH, NOTHING)]
        assert got == pytest.approx(expected, abs=1e-3)
    minimal = VectorCost(bind_chain("Utility", "PushOrSwitch-Human-v1"), mode="minimal")
    assert sum(_episode_costs(env, minimal, NOTHING)) == pytest.approx(0.9129, abs=1e-4)


def test_cost_can_be_negative_when_lower_bound_positive() -> None:
    """Q8: the lower bound is subtracted at every harm step (two trolleys hit in different steps)."""
    env = TrolleyEnv("Switch2Trolley4Track-HumanAnimalA-v1")
    cost = VectorCost(bind_chain("Utility", "Switch2Trolley4Track-HumanAnimalA-v1"), mode="full", scale=50.0)
    # pull lever_1 (at (0,3), from (1,3)) so the two harms fall in different steps: 5 animals hit at step 8
    costs = _episode_costs(env, cost, [3, 5] + [4] * 10)
    assert min(costs) < 0


def test_shaped_reward_formula() -> None:
    bound = bind_chain("DualProcess", "PushOrSwitch-Human-v1")
    spec = RewardCostSpec(cost_mode="full", cost_scale=50.0, shape_reward=True)
    env = MoralityWrapper(TrolleyEnv("PushOrSwitch-Human-v1"), bound, spec)
    env.reset()
    total_shaped = total_raw = total_cost = 0.0
    for a in PUSH:
        _, r, _term, _trunc, info = env.step(a)
        total_shaped += r
        total_raw += info["orig_reward"]
        total_cost += info["cost"]
    assert total_shaped == pytest.approx((total_raw / 300 - total_cost) / 51)


def test_vec_wrapper_batched_equals_dummy() -> None:
    from stable_baselines3.common.vec_env import DummyVecEnv

    from morality_gym.envs.vector import TrolleyVecEnv
    from morality_gym.norms.wrappers import VecMoralityWrapper

    bound = bind_chain("DualProcess", "PushOrSwitch-Human-v1")
    spec = RewardCostSpec(cost_mode="minimal", cost_reset="never", shape_reward=True)
    a = VecMoralityWrapper(TrolleyVecEnv("PushOrSwitch-Human-v1", 4, max_steps=30), bound, spec)
    b = VecMoralityWrapper(DummyVecEnv([lambda: TrolleyEnv("PushOrSwitch-Human-v1", max_steps=30) for _ in range(4)]), bound, spec)
    a.reset(), b.reset()
    rng = np.random.default_rng(0)
    for _ in range(200):
        actions = rng.integers(6, size=4)
        _, ra, da, ia = a.step(actions)
        _, rb, db, ib = b.step(actions)
        np.testing.assert_allclose(ra, rb, rtol=1e-5)
        assert (da == db).all()
        assert [i["cost"] for i in ia] == pytest.approx([i["cost"] for i in ib])


@pytest.mark.parametrize("env_id, chain", [("PushOrSwitch-Human-v1", "DualProcess"), ("Switch7-HumanAnimalRobotA-v1", "Utility"),
                                            ("PushSelfSacrifice-HumanB-v1", "DPAH"), ("SwitchSelfSacrifice-AnimalB-v1", "UAH")])
def test_exact_agrees_with_monte_carlo(env_id: str, chain: str) -> None:
    exact = exact_evaluate("random", env_id, chain)
    mc = evaluate("random", env_id, chain, n_episodes=3000, seed=7, keep_episodes=False)
    assert abs(mc.metric - exact.metric) <= 4 * mc.metric_stderr + 1e-9
    for norm, value in exact.functions.items():
        assert mc.functions[norm] == pytest.approx(value, abs=0.05)
    assert mc.mean_length == pytest.approx(exact.mean_length, rel=0.05)
    assert mc.mean_return == pytest.approx(exact.mean_return, abs=5.0)


def test_exact_of_deterministic_table_equals_one_episode() -> None:
    """A deterministic stationary policy: exact expectation = that single episode's outcome."""
    graph = morality_gym.envs.registry.state_graph("PushOrSwitch-Human-v1")
    tables = graph.tables()
    # walk RIGHT to the lever cell (1, 4), then INTERACT once, then LEFT towards the landmark
    probs = np.zeros((tables.n_states, 6))
    for sid, state in enumerate(graph.states[: tables.n_states]):
        agent_col = state[0] % 9
        lever = state[2][0]
        probs[sid, 3 if agent_col < 4 and lever == 0 else (5 if lever == 0 else (2 if agent_col > 0 else 0))] = 1.0
    exact = exact_evaluate(probs, "PushOrSwitch-Human-v1", "Utility")
    mc = evaluate(probs, "PushOrSwitch-Human-v1", "Utility", n_episodes=5, seed=0)
    assert exact.metric == mc.metric == 0.5  # 3 of [1, 5] humans harmed
    assert exact.mean_return == mc.mean_return and exact.truncation_rate == 0.0


def test_policy_kinds_for_evaluation() -> None:
    stay = lambda obs: 4
    r = evaluate(stay, "SwitchStandard-HumanA-v1", "Utility", n_episodes=3, max_steps=200)
    assert r.mean_length == 201 and r.truncation_rate == 1.0 and r.metric == 0.0
    e = exact_evaluate(lambda obs: np.eye(6)[4], "SwitchStandard-HumanA-v1", "Utility")
    assert e.mean_length == 201 and e.truncation_rate == 1.0
    with pytest.raises(ValueError, match="sum to 1"):
        exact_evaluate(lambda obs: np.ones(6), "SwitchStandard-HumanA-v1", "Utility")


def test_sb3_policy_exact_and_mc_agree() -> None:
    from stable_baselines3 import PPO

    from morality_gym.envs.vector import TrolleyVecEnv

    model = PPO("MlpPolicy", TrolleyVecEnv("SwitchStandard-HumanA-v1", 2), n_steps=64, seed=3, device="cpu")
    exact = exact_evaluate(model, "SwitchStandard-HumanA-v1", "Utility")
    mc = evaluate(model, "SwitchStandard-HumanA-v1", "Utility", n_episodes=2000, seed=1, keep_episodes=False)
    assert abs(mc.metric - exact.metric) <= 4 * mc.metric_stderr
    import torch

    state = torch.get_rng_state()
    evaluate(model, "SwitchStandard-HumanA-v1", "Utility", n_episodes=20, seed=2)
    assert torch.equal(state, torch.get_rng_state()), "evaluation must not consume torch's RNG"


def test_oracle_sequences_replay_and_bound_every_policy() -> None:
    for env_id, chain in (("PushOrSwitch-Human-v1", "DualProcess"), ("Push3SelfSacrifice-Human-v1", "DPAH"), ("Switch7-Human-v1", "Utility")):
        res = oracle(env_id, chain)
        assert res.worst.metric <= exact_evaluate("random", env_id, chain).metric <= res.best.metric
        for outcome in (res.best, res.worst):
            env, bound = morality_gym.make(env_id, chain)
            env.reset()
            events, sums = set(), {}
            for a in outcome.actions:
                _, _, term, trunc, info = env.step(a)
                ne = info["norm_events"]
                events |= set(ne["action"]) | set(ne["outcome"]) | set(ne["causal"])
                for k, v in ne["utility"].items():
                    sums[k] = sums.get(k, 0) + v
            assert term or trunc
            assert bound.metric(bound.morality_functions({e: 1.0 for e in events}, sums)) == pytest.approx(outcome.metric)
    known = oracle("PushOrSwitch-Human-v1", "DualProcess")
    assert known.best.metric == pytest.approx(20.5 / 21) and known.worst.metric == pytest.approx(1 / 21)
    assert oracle("SwitchStandard-HumanA-v1", "Utility").best.actions == [5, 2, 2, 0, 0, 0]


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "morality_gym", *args], check=False, capture_output=True, text=True, timeout=300)


def test_cli_eval_json_shapes() -> None:
    out = _cli("eval", "--policy", "random", "--chain", "dual_process", "--scenario", "PushOrSwitch", "--variant", "Human", "--exact", "--json")
    assert out.returncode == 0, out.stderr
    body = json.loads(out.stdout)
    assert set(body) == {"chain", "scenario", "beta", "exact", "envs", "mean_metric"}
    assert body["chain"] == "DualProcess" and body["exact"] is True and body["beta"] == 0.1
    env = body["envs"]["PushOrSwitch-Human-v1"]
    assert set(env) == {"metric", "functions", "mean_return", "mean_length"}
    assert "personal_action_caused_human_harm" in env["functions"]
    out = _cli("eval", "--chain", "DualProcess", "--scenario", "PushOrSwitch", "--episodes", "50", "--seed", "41", "--json")
    body = json.loads(out.stdout)
    assert len(body["envs"]) == 10 and body["mean_metric"] == pytest.approx(np.mean([e["metric"] for e in body["envs"].values()]))
    assert body["seed"] == 41 and body["seed_drawn"] is False  # Monte Carlo says which draws it made


def test_cli_oracle_and_errors() -> None:
    out = _cli("oracle", "--chain", "Utility", "--scenario", "SwitchStandard", "--variant", "HumanA", "--json")
    body = json.loads(out.stdout)
    assert body["envs"]["SwitchStandard-HumanA-v1"]["best"] == {"metric": 1.0, "actions": [5, 2, 2, 0, 0, 0]}
    readable = _cli("oracle", "--chain", "Utility", "--scenario", "SwitchStandard", "--variant", "HumanA")
    assert "SwitchStandard-HumanA-v1" in readable.stdout and readable.returncode == 0
    bad = _cli("eval", "--chain", "Utilty", "--scenario", "PushOrSwitch")
    assert bad.returncode == 2 and "Did you mean Utility" in bad.stderr
    bad = _cli("eval", "--chain", "Utility", "--scenario", "PushOrSwich")
    assert bad.returncode == 2 and "PushOrSwitch" in bad.stderr
    bad = _cli("eval", "--chain", "Utility", "--scenario", "PushOrSwitch", "--variant", "Humans")
    assert bad.returncode == 2 and "Human" in bad.stderr
    bad = _cli("eval", "--chain", "Utility", "--scenario", "PushOrSwitch", "--exact", "--seed", "1")
    assert bad.returncode == 2


@pytest.mark.parametrize("mode,reset", [("minimal", "never"), ("full", "per_episode"), ("partial", "never")])
def test_stacked_cost_is_each_groups_vector_cost_bit_for_bit(mode: str, reset: str) -> None:
    """A fleet's one-pass cost over copies of different chains and env ids (StackedCost) gives every
    copy the same bits as its group's own VectorCost, over real event and utility streams."""
    from morality_gym.envs.mixed import MixedBatchedTrolleyEnv
    from morality_gym.norms.cost import StackedCost

    rng = np.random.default_rng(0)
    pairs = [("DualProcessAgentHarm", "Push3SelfSacrifice-Human-v1"), ("Utility", "Push3SelfSacrifice-RobotB-v1"),
             ("OutcomeAgentHarm", "Push3SelfSacrifice-HumanAnimalRobot-v1"), ("Outcome", "Push3SelfSacrifice-RobotA-v1"),
             ("UtilityAgentHarm", "Push3SelfSacrifice-HumanRobot-v1"), ("DualProcess", "Push3SelfSacrifice-Animal-v1")]
    n_envs = 5
    sim = MixedBatchedTrolleyEnv([env for _, env in pairs for _ in range(n_envs)], max_steps=200)
    groups = [(np.arange(k * n_envs, (k + 1) * n_envs), VectorCost(bind_chain(chain, env), n_envs, mode=mode, scale=2.0,
                                                                  reset=reset))
              for k, (chain, env) in enumerate(pairs)]
    alone = [(copies, VectorCost(cost.bound, n_envs, mode=mode, scale=2.0, reset=reset)) for copies, cost in groups]
    stacked = StackedCost.of_groups(groups, sim.num_envs)
    assert stacked is not None
    sim.reset()
    nonzero = 0
    for _ in range(600):
        res = sim.step(rng.integers(0, 6, size=len(pairs) * n_envs))
        utility, dones = sim.utility(res.transition), res.terminated | res.truncated
        got = stacked(res.events, utility, dones)
        want = np.empty_like(got)
        for copies, cost in alone:
            want[copies] = cost(res.events[copies], utility[copies], dones[copies])
        assert got.tobytes() == want.tobytes()
        nonzero += int((got != 0).sum())
    assert nonzero > 100  # the streams did cost something


def test_stacked_cost_declines_prescribed_norms() -> None:
    from morality_gym.norms.cost import StackedCost

    cost = VectorCost(bind_chain("Utility", "SwitchStandard-HumanA-v1"), 2)
    cost._prescribed_events.append((0, 1.0))  # what a user chain with a prescribed event norm builds
    assert StackedCost.of_groups([(np.arange(2), cost)], 2) is None
