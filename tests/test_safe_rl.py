"""PPO-Lagrangian and CPO (``morality_gym.baselines.safe``): the maths, the SB3 plumbing, and
learning on a tiny CMDP (``tests/cmdp_toy.py``) where the best route has a cost and a slightly
worse one has none.

The learning runs are fixed-seed and sized to finish in seconds; each learnt model is shared by
the tests that inspect it (module-scoped fixtures), so every run is paid for once.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, EvalCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import KVWriter, Logger
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn
from torch import nn

from morality_gym.baselines.safe import (
    CPO,
    CostActorCriticPolicy,
    CostRolloutBuffer,
    CPOCase,
    LagrangeMultiplier,
    MissingCostError,
    PPOLag,
    cpo_direction,
)
from tests.cmdp_toy import RISKY, SAFE, TwoRouteCMDP, all_observations, fork_observation

SEED = 3


pytestmark = pytest.mark.usefixtures("one_torch_thread")


# ----------------------------------------------------------------------------- helpers


class RecordingWriter(KVWriter):
    """Keeps every dump of SB3's logger in memory (SB3's own output interface, no mocking)."""

    def __init__(self) -> None:
        self.dumps: list[dict[str, Any]] = []

    def write(self, key_values: dict[str, Any], key_excluded: dict[str, Any], step: int = 0) -> None:
        self.dumps.append(dict(key_values))

    def values(self, key: str) -> list[Any]:
        return [d[key] for d in self.dumps if key in d]


def attach_recorder(model: BaseAlgorithm) -> RecordingWriter:
    writer = RecordingWriter()
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    return writer


class MultiplierPerRollout(BaseCallback):
    """``lambda`` and ``J_c`` seen at the end of every rollout (i.e. before that rollout's update)."""

    def __init__(self) -> None:
        super().__init__()
        self.multipliers: list[float] = []
        self.episode_costs: list[float] = []

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        self.multipliers.append(self.model.lagrange_multiplier)  # type: ignore[attr-defined]
        self.episode_costs.append(self.model.mean_episode_cost())  # type: ignore[attr-defined]


class StepCounter(BaseCallback):
    def __init__(self) -> None:
        super().__init__()
        self.steps = self.rollouts_started = self.rollouts_ended = 0
        self.saw_costs = True

    def _on_step(self) -> bool:
        self.steps += 1
        self.saw_costs &= "costs" in self.locals and len(self.locals["costs"]) == self.training_env.num_envs
        return True

    def _on_rollout_start(self) -> None:
        self.rollouts_started += 1

    def _on_rollout_end(self) -> None:
        self.rollouts_ended += 1


def toy_vec_env(seed: int, n_envs: int = 4) -> Any:
    return make_vec_env(TwoRouteCMDP, n_envs=n_envs, seed=seed)


def fork_probs(model: BaseAlgorithm) -> np.ndarray:
    obs = th.as_tensor(fork_observation())
    with th.no_grad():
        return model.policy.get_distribution(obs).distribution.probs.numpy()[0]  # type: ignore[union-attr]


def episode_stats(model: BaseAlgorithm, n_episodes: int, deterministic: bool, seed: int = 123) -> tuple[float, float]:
    """Mean (return, cost) of ``model`` on fresh episodes of the toy CMDP."""
    env = TwoRouteCMDP()
    returns, costs = [], []
    for episode in range(n_episodes):
        obs, _ = env.reset(seed=seed + episode)
        done, ret, cost = False, 0.0, 0.0
        while not done:
            action, _ = model.predict(obs, deterministic=deterministic)
            obs, reward, terminated, truncated, info = env.step(int(action))
            ret, cost, done = ret + reward, cost + info["cost"], terminated or truncated
        returns.append(ret)
        costs.append(cost)
    return float(np.mean(returns)), float(np.mean(costs))


def assert_takes_the_cost_free_route(model: BaseAlgorithm) -> None:
    """The fork's choice is SAFE; greedy episodes cost nothing, sampled ones almost nothing."""
    probs = fork_probs(model)
    assert np.argmax(probs) == SAFE and probs[SAFE] > 0.9, probs
    greedy_return, greedy_cost = episode_stats(model, 10, deterministic=True)
    _, sampled_cost = episode_stats(model, 200, deterministic=False)
    assert greedy_cost == 0.0 and greedy_return == pytest.approx(0.77)
    assert sampled_cost < 0.1


# ----------------------------------------------------------------------------- learnt models (shared)


@pytest.fixture(scope="module")
def ppo_lag_run() -> tuple[PPOLag, MultiplierPerRollout, RecordingWriter]:
    """PPO-Lag on the toy CMDP. Test-sized settings: 1,024-step rollouts, 10 epochs, the mean-KL
    early stop (the corrected protocol's; OmniSafe's summed KL allows one pass per update), a
    multiplier learning rate of 0.3 (paper: 0.035), so ``lambda`` overtakes the reward gap within
    ~8 rollouts instead of ~50, and standardised cost advantages: with OmniSafe's centring the
    policy settles on the risky route in the first updates, before ``lambda`` has grown, and the
    centred cost advantages of a deterministic policy are too small to pull it back within this
    budget (lambda ~5 after 20 updates, P(risky) 0.999). Everything else is the paper's default."""
    model = PPOLag(
        "MlpPolicy", toy_vec_env(SEED), steps_per_rollout=1024, n_epochs=10, lagrange_lr=0.3,
        kl_early_stop_reduction="mean", cost_advantage_normalization="standardize", seed=SEED, device="cpu",
    )
    writer = attach_recorder(model)
    history = MultiplierPerRollout()
    model.learn(20_480, callback=history)
    model.logger.dump(model.num_timesteps)  # flush the last update's train/ values
    return model, history, writer


@pytest.fixture(scope="module")
def cpo_run() -> tuple[CPO, RecordingWriter]:
    """CPO on the toy CMDP with the paper's defaults (2,048-step rollouts over 4 envs), except the
    exact dual solution (the corrected protocol's; OmniSafe's solution is tested in
    tests/test_omnisafe_fidelity.py, and on this toy it stalls at P(safe) ~0.77: once no episode
    costs anything, c = 0, and its direction raises the cost surrogate, so the line search rejects
    every step). 20 updates: the exact solution reaches P(safe) ~0.96."""
    model = CPO("MlpPolicy", toy_vec_env(SEED), dual_solution="exact", seed=SEED, device="cpu")
    writer = attach_recorder(model)
    model.learn(40_960)
    model.logger.dump(model.num_timesteps)
    return model, writer


# ----------------------------------------------------------------------------- maths


def test_gae_of_both_streams_matches_sb3() -> None:
    """Costs get exactly SB3's GAE: feed the same numbers as rewards and as costs."""
    rng = np.random.default_rng(0)
    n_steps, n_envs = 16, 3
    obs_space, act_space = TwoRouteCMDP().observation_space, TwoRouteCMDP().action_space
    ours = CostRolloutBuffer(
        n_steps,
        obs_space,
        act_space,
        "cpu",
        gae_lambda=0.9,
        gamma=0.97,
        n_envs=n_envs,
        cost_gamma=0.97,
        cost_gae_lambda=0.9,
    )
    sb3 = RolloutBuffer(n_steps, obs_space, act_space, "cpu", gae_lambda=0.9, gamma=0.97, n_envs=n_envs)
    for _ in range(n_steps):
        obs = rng.random((n_envs, 5)).astype(np.float32)
        action = rng.integers(0, 3, (n_envs, 1))
        reward = rng.normal(size=n_envs).astype(np.float32)
        start = rng.random(n_envs) < 0.2
        value, log_prob = th.as_tensor(rng.normal(size=(n_envs, 1))), th.as_tensor(rng.normal(size=n_envs))
        ours.add(obs, action, reward, start, value, log_prob, cost=reward, cost_value=value)
        sb3.add(obs, action, reward, start, value, log_prob)
    last_values, dones = th.as_tensor(rng.normal(size=(n_envs, 1))), rng.random(n_envs) < 0.3
    ours.compute_returns_and_advantage(last_values, dones, last_cost_values=last_values)
    sb3.compute_returns_and_advantage(last_values, dones)
    np.testing.assert_allclose(ours.advantages, sb3.advantages, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ours.returns, sb3.returns, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ours.cost_advantages, sb3.advantages, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ours.cost_returns, sb3.returns, rtol=1e-5, atol=1e-6)


def _brute_force_cpo(h: np.ndarray, g: np.ndarray, b: np.ndarray, c: float, delta: float) -> np.ndarray | None:
    """Best feasible point of a dense polar grid over the 2-D trust region (None: none feasible)."""
    chol = np.linalg.cholesky(h)  # x^T H x = |L^T x|^2
    radii = np.sqrt(2 * delta) * np.sqrt(np.linspace(0.0, 1.0, 200))[:, None]
    angles = np.linspace(0.0, 2 * np.pi, 1000, endpoint=False)[None, :]
    u = np.stack([radii * np.cos(angles), radii * np.sin(angles)], axis=-1).reshape(-1, 2)
    x = np.linalg.solve(chol.T, u.T).T
    feasible = c + x @ b <= 0
    if not feasible.any():
        return None
    return x[np.argmax(np.where(feasible, x @ g, -np.inf))]


def test_cpo_direction_solves_the_trust_region_problem() -> None:
    """The closed-form dual solution equals a brute-force solution of the primal, in every case."""
    rng = np.random.default_rng(7)
    delta, seen = 0.01, set()
    for trial in range(160):
        m = rng.normal(size=(2, 2))
        h = m @ m.T + 0.1 * np.eye(2)
        g, b = rng.normal(size=2), rng.normal(size=2) * rng.choice([0.1, 1.0, 3.0])
        c = 0.0 if trial % 6 == 0 else float(rng.normal() * rng.choice([0.01, 0.1, 0.5]))
        v, w = np.linalg.solve(h, g), np.linalg.solve(h, b)
        step = cpo_direction(th.as_tensor(v), th.as_tensor(w), g @ v, g @ w, b @ w, c, delta)
        x, best = step.direction.numpy(), _brute_force_cpo(h, g, b, c, delta)
        seen.add(step.case)
        if step.case == CPOCase.INFEASIBLE:
            assert best is None, f"trial {trial}: recovery chosen but a feasible point exists"
            np.testing.assert_allclose(x, -math.sqrt(2 * delta / (b @ w + 1e-8)) * w)  # OmniSafe's 1e-8 guard
            continue
        assert best is not None
        assert 0.5 * x @ h @ x <= delta * (1 + 1e-6), f"trial {trial}: outside the trust region"
        assert c + b @ x <= 1e-7, f"trial {trial}: violates the linearised constraint"
        assert g @ x >= g @ best - 1e-3 * abs(g @ best) - 1e-6, f"trial {trial}: worse than brute force"
    assert seen >= {CPOCase.INFEASIBLE, CPOCase.FEASIBLE_RECOVERY, CPOCase.FEASIBLE, CPOCase.INACTIVE}


def test_lagrange_multiplier_ascends_on_violation_and_stays_non_negative() -> None:
    lagrange = LagrangeMultiplier(initial_value=0.001, learning_rate=0.035)
    values = [lagrange.update(mean_episode_cost=0.5, cost_limit=0.0) for _ in range(5)]
    assert values[0] == pytest.approx(0.036, abs=1e-6)  # Adam's first step is exactly lr
    assert all(b > a for a, b in itertools.pairwise(values))
    for _ in range(50):
        value = lagrange.update(mean_episode_cost=0.0, cost_limit=1.0)
        assert value >= 0.0
    assert value == 0.0


# ----------------------------------------------------------------------------- plumbing


def test_policy_has_three_separate_tanh_networks() -> None:
    model = PPOLag("MlpPolicy", toy_vec_env(0, n_envs=1), seed=0, device="cpu")
    policy = model.policy
    assert isinstance(policy, CostActorCriticPolicy)
    widths = {
        name: [m.out_features for m in net if isinstance(m, nn.Linear)]
        for name, net in (
            ("pi", policy.mlp_extractor.policy_net),
            ("vf", policy.mlp_extractor.value_net),
            ("cf", policy.cost_net),
        )
    }
    assert widths == {"pi": [64, 64], "vf": [64, 64], "cf": [64, 64, 1]}
    assert all(isinstance(m, nn.Tanh) for m in policy.cost_net if not isinstance(m, nn.Linear))
    actor, critic = {id(p) for p in policy.actor_parameters()}, {id(p) for p in policy.critic_parameters()}
    assert not actor & critic
    assert actor | critic == {id(p) for p in policy.parameters()}
    assert model.n_steps == 2048  # 2,048 steps per rollout in total
    assert toy_vec_env(0).num_envs == 4 and PPOLag("MlpPolicy", toy_vec_env(0), device="cpu").n_steps == 512
    obs = th.as_tensor(all_observations())
    assert policy.predict_cost_values(obs).shape == (5, 1)
    assert policy.predict_values(obs).shape == (5, 1)
    custom = PPOLag("MlpPolicy", toy_vec_env(0, 1), policy_kwargs={"net_arch": {"pi": [8], "vf": [16], "cf": [4, 4]}})
    assert [m.out_features for m in custom.policy.cost_net if isinstance(m, nn.Linear)] == [4, 4, 1]


@pytest.mark.parametrize("algorithm", [PPOLag, CPO])
def test_missing_cost_names_the_wrapper(algorithm: type[BaseAlgorithm]) -> None:
    env = make_vec_env(TwoRouteCMDP, n_envs=2, seed=0, env_kwargs={"emit_cost": False})
    model = algorithm("MlpPolicy", env, steps_per_rollout=64, seed=0, device="cpu")
    with pytest.raises(MissingCostError, match=r"info\['cost'\].*MoralityWrapper"):
        model.learn(64)


def test_truncation_bootstraps_reward_and_cost_with_their_critics() -> None:
    """SB3's convention on both streams: r += gamma V(s_T), c += gamma_c V_c(s_T) on truncation."""
    model = CPO(
        "MlpPolicy", toy_vec_env(0, n_envs=3), steps_per_rollout=48, gamma=0.9, cost_gamma=0.8, seed=0, device="cpu"
    )
    terminal = all_observations()[2]
    infos = [
        {"terminal_observation": terminal, "TimeLimit.truncated": True, "cost": 0.0},  # truncated
        {"terminal_observation": terminal, "TimeLimit.truncated": False, "cost": 0.0},  # terminated
        {"cost": 0.0},  # running
    ]
    rewards, costs = np.ones(3, dtype=np.float32), np.full(3, 2.0, dtype=np.float32)
    model._bootstrap_truncations(rewards, costs, np.array([True, True, False]), infos)
    with th.no_grad():
        v = model.policy.predict_values(th.as_tensor(terminal[None])).item()
        vc = model.policy.predict_cost_values(th.as_tensor(terminal[None])).item()
    np.testing.assert_allclose(rewards, [1 + 0.9 * v, 1, 1], rtol=1e-6)
    np.testing.assert_allclose(costs, [2 + 0.8 * vc, 2, 2], rtol=1e-6)


class ResetCounter(VecEnvWrapper):
    """Counts ``reset()`` calls of the VecEnv it wraps (a real wrapper, nothing is faked)."""

    def __init__(self, venv: VecEnv) -> None:
        super().__init__(venv)
        self.resets = 0

    def reset(self) -> Any:
        self.resets += 1
        return self.venv.reset()

    def step_wait(self) -> VecEnvStepReturn:
        return self.venv.step_wait()


class RolloutBoundaries(BaseCallback):
    """What every rollout starts from, whether it ended mid-episode, and how many episodes ended."""

    def __init__(self) -> None:
        super().__init__()
        self.starts: list[tuple[bool, float]] = []  # (all envs at an episode start, running cost)
        self.ended_mid_episode: list[bool] = []
        self.first_steps_are_starts: list[bool] = []
        self.finished = 0

    def _on_rollout_start(self) -> None:
        model = self.model
        self.starts.append((bool(np.all(model._last_episode_starts)), float(np.abs(model._running_ep_cost).sum())))  # type: ignore[attr-defined]

    def _on_step(self) -> bool:
        self.finished += int(np.sum(self.locals["dones"]))
        return True

    def _on_rollout_end(self) -> None:
        self.ended_mid_episode.append(not bool(np.all(self.model._last_episode_starts)))
        self.first_steps_are_starts.append(bool(np.all(self.model.rollout_buffer.episode_starts[0])))


@pytest.mark.parametrize("algorithm", [PPOLag, CPO])
@pytest.mark.parametrize("reset_each", [True, False])
def test_reset_envs_each_rollout_cuts_episodes_like_omnisafe_epochs(algorithm: type[BaseAlgorithm], reset_each: bool) -> None:
    """OmniSafe restarts its envs every epoch (docs/protocols.md#training-envs-restart-every-epoch): with ``reset_envs_each_rollout`` every rollout starts from fresh episodes; the cut
    episodes are not filed as finished (``J_c`` only averages real episodes). Without it (SB3's
    way) episodes run on across rollouts and the env is reset once."""
    env = ResetCounter(toy_vec_env(0, n_envs=2))
    kwargs: dict[str, Any] = {"n_epochs": 1} if algorithm is PPOLag else {"n_critic_updates": 1}
    model = algorithm(
        "MlpPolicy", env, steps_per_rollout=16, ep_cost_window=10_000, reset_envs_each_rollout=reset_each,
        seed=0, device="cpu", **kwargs,
    )
    seen = RolloutBoundaries()
    model.learn(16 * 12, callback=seen)
    assert len(seen.starts) == 12
    cut = sum(seen.ended_mid_episode[:-1])
    assert cut >= 3, "the test needs rollouts that end mid-episode"
    assert len(model.ep_cost_buffer) == seen.finished  # every finished episode filed, cut ones not
    if reset_each:
        assert all(at_start and running == 0.0 for at_start, running in seen.starts)
        assert all(seen.first_steps_are_starts)
        assert env.resets == 1 + cut  # learn()'s reset, then one per rollout that ended mid-episode
    else:
        assert env.resets == 1
        assert not all(at_start for at_start, _ in seen.starts)


# ----------------------------------------------------------------------------- learning


@pytest.mark.slow
def test_plain_ppo_takes_the_costly_route() -> None:
    """The premise: a reward maximiser prefers the risky route and pays its cost."""
    model = PPO("MlpPolicy", toy_vec_env(SEED), n_steps=512, seed=SEED, device="cpu")
    model.learn(24_576)
    assert np.argmax(fork_probs(model)) == RISKY
    _, greedy_cost = episode_stats(model, 10, deterministic=True)
    _, sampled_cost = episode_stats(model, 200, deterministic=False)
    assert greedy_cost == 1.0
    assert sampled_cost > 0.8


@pytest.mark.slow
def test_ppo_lag_learns_the_cost_free_route(ppo_lag_run: tuple[PPOLag, MultiplierPerRollout, RecordingWriter]) -> None:
    model, _, _ = ppo_lag_run
    assert_takes_the_cost_free_route(model)


@pytest.mark.slow
def test_ppo_lag_multiplier_grows_while_the_constraint_is_violated(
    ppo_lag_run: tuple[PPOLag, MultiplierPerRollout, RecordingWriter],
) -> None:
    model, history, writer = ppo_lag_run
    lams, costs = history.multipliers, history.episode_costs
    # Rollout k's multiplier is the one after k updates; update k used J_c of rollout k.
    violated = [k for k in range(1, len(lams)) if costs[k - 1] > model.cost_limit]
    early = violated[:5]
    assert len(early) == 5 and early == list(range(1, 6))
    assert all(lams[k] > lams[k - 1] for k in early), lams[:6]
    assert lams[5] > 1.0  # five violated updates of ~0.3 each (Adam steps of about lr)
    logged = writer.values("train/lagrange_multiplier")
    assert logged[: len(early)] == pytest.approx(lams[1 : len(early) + 1])
    assert writer.values("train/mean_ep_cost") and writer.values("train/kl")


@pytest.mark.slow
def test_ppo_lag_multiplier_with_the_paper_settings() -> None:
    """Default settings: lambda starts at 0.001 and each violated rollout adds an Adam step of ~0.035."""
    model = PPOLag("MlpPolicy", toy_vec_env(SEED), seed=SEED, device="cpu")
    assert (model.lagrange_init, model.lagrange_lr, model.n_epochs, model.target_kl) == (0.001, 0.035, 40, 0.02)
    history = MultiplierPerRollout()
    model.learn(4 * 2048, callback=history)
    assert history.multipliers[0] == pytest.approx(0.001)
    assert all(c > 0 for c in history.episode_costs)
    steps = np.diff([*history.multipliers, model.lagrange_multiplier])
    np.testing.assert_allclose(steps, 0.035, rtol=0.1)


@pytest.mark.slow
def test_cpo_learns_the_cost_free_route(cpo_run: tuple[CPO, RecordingWriter]) -> None:
    model, writer = cpo_run
    assert_takes_the_cost_free_route(model)
    cases = set(writer.values("train/cpo_case"))
    assert int(CPOCase.INFEASIBLE) in cases or int(CPOCase.FEASIBLE_RECOVERY) in cases  # it had to cut the cost


@pytest.mark.slow
def test_cpo_updates_stay_in_the_trust_region(cpo_run: tuple[CPO, RecordingWriter]) -> None:
    model, writer = cpo_run
    kls, accepted = writer.values("train/kl_mean"), writer.values("train/accept_step")
    fractions = writer.values("train/step_fraction")
    assert len(kls) == model.num_timesteps // 2048 == len(model.update_log)  # one update per rollout, all logged
    assert max(kls) <= model.target_kl
    assert sum(a > 0 for a in accepted) >= len(accepted) / 2  # most steps are taken
    for kl, step, fraction in zip(kls, accepted, fractions):
        assert 0 <= step <= model.line_search_max_iter == 20
        assert (step > 0 and fraction == pytest.approx(0.8 ** (step - 1)) and kl > 0) or (step == 0 and kl == 0.0)


# ----------------------------------------------------------------------------- SB3 integration


@pytest.mark.slow
@pytest.mark.parametrize("run", ["ppo_lag_run", "cpo_run"])
def test_save_load_round_trip(run: str, request: pytest.FixtureRequest, tmp_path: Path) -> None:
    model = request.getfixturevalue(run)[0]
    path = tmp_path / "model.zip"
    model.save(path)
    loaded = type(model).load(path, device="cpu")
    obs = th.as_tensor(all_observations())
    with th.no_grad():
        before = model.policy.get_distribution(obs).distribution.probs
        after = loaded.policy.get_distribution(obs).distribution.probs
        assert th.equal(before, after)
        assert th.equal(model.policy.predict_cost_values(obs), loaded.policy.predict_cost_values(obs))
    hparams = [
        "n_steps",
        "batch_size",
        "gamma",
        "gae_lambda",
        "cost_gamma",
        "cost_gae_lambda",
        "cost_limit",
        "critic_l2_coef",
        "max_grad_norm",
        "target_kl",
        "ep_cost_window",
        "anneal_lr",
        "anneal_lr_timing",
        "anneal_critic_lr",
        "critic_grad_clip",
        "weight_init",
        "adam_eps",
        "cost_advantage_normalization",
    ]
    hparams += (
        ["clip_range", "n_epochs", "lagrange_init", "lagrange_lr", "kl_early_stop_reduction"]
        if run == "ppo_lag_run"
        else ["cg_damping", "cg_max_steps", "cg_eps", "dual_solution", "line_search_accept", "trust_region_rescale"]
    )
    for name in hparams:
        assert getattr(loaded, name) == getattr(model, name), name
    if isinstance(model, PPOLag):
        assert model.lagrange_multiplier > 1.0
        assert loaded.lagrange_multiplier == model.lagrange_multiplier
        assert (
            loaded.lagrange.optimizer.state_dict()["state"][0]["step"]
            == model.lagrange.optimizer.state_dict()["state"][0]["step"]
        )
    assert list(loaded.ep_cost_buffer) == list(model.ep_cost_buffer)
    assert loaded.policy.weight_init == model.policy.weight_init and loaded.update_log == []
    # The loaded model keeps learning on a new env.
    loaded.set_env(toy_vec_env(SEED + 1))
    loaded.learn(2048, reset_num_timesteps=False)
    assert loaded.num_timesteps == model.num_timesteps + 2048


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", [PPOLag, CPO])
def test_callbacks_and_dummy_vec_env(algorithm: type[BaseAlgorithm], tmp_path: Path) -> None:
    env = DummyVecEnv([lambda: Monitor(TwoRouteCMDP()) for _ in range(4)])
    model = algorithm("MlpPolicy", env, seed=SEED, device="cpu", verbose=0, tensorboard_log=None)
    assert model.n_steps == 512
    counter = StepCounter()
    evaluation = EvalCallback(
        Monitor(TwoRouteCMDP()),
        eval_freq=256,
        n_eval_episodes=5,
        log_path=str(tmp_path),
        best_model_save_path=str(tmp_path),
        verbose=0,
    )
    model.learn(2 * 2048, callback=CallbackList([counter, evaluation]))
    assert model.num_timesteps == 4096
    assert counter.steps == 4096 // 4 and counter.rollouts_started == counter.rollouts_ended == 2
    assert counter.saw_costs
    assert evaluation.evaluations_timesteps == [1024, 2048, 3072, 4096]
    assert np.isfinite(evaluation.last_mean_reward) and (tmp_path / "evaluations.npz").is_file()
    best = algorithm.load(tmp_path / "best_model.zip", device="cpu")  # saved by EvalCallback
    assert best.cost_limit == model.cost_limit
    action, _ = model.predict(fork_observation()[0], deterministic=True)
    actions, _ = model.predict(all_observations(), deterministic=False)
    assert 0 <= int(action) < 3 and actions.shape == (5,)
    assert len(model.ep_cost_buffer) > 0 and model.mean_episode_cost() >= 0
