"""Learner and protocol specifications: every knob of the baselines as data, with the paper's values.

The defaults below are the hyper-parameters that actually ran in the paper (evaluation spec 6.3),
not the ones printed in its appendix. Sweeps take these values from ``conf/algo/*.yaml`` and
``conf/protocol/*.yaml`` (a test keeps the files and these defaults identical); library users get
them by name via :func:`learner_spec`. Unknown keys are errors that name the key and the choices.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from morality_gym.norms.cost import COST_MODES, RESET_POLICIES
from morality_gym.norms.wrappers import PAPER_RETURN_BOUNDS, RewardCostSpec

IMPLEMENTATIONS = ("random", "ppo", "ppo_lag", "cpo")
VEC_ENVS = ("batched", "dummy")
STEP_ACCOUNTING = ("rollouts", "floor")


class SpecError(ValueError):
    """A learner or protocol setting is invalid; the message names the key and the valid choices."""


def _check_keys(where: str, given: Mapping[str, Any], allowed: list[str]) -> None:
    for key in given:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), allowed, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise SpecError(f"{where}: unknown key {key!r}{hint}; valid keys: {', '.join(allowed)}")


@dataclass(frozen=True)
class LearnerSpec:
    """One learner: which implementation, how it sees reward and cost, and its hyper-parameters.

    ``cost_reset="protocol"`` defers the first-violation memory policy to the protocol (PPO-Lag and
    CPO: ``never`` under the paper protocol, ``per_episode`` under the corrected one).
    ``step_accounting``: ``rollouts`` = SB3 runs whole rollouts until the budget is reached
    (1,015,808 steps for a 1M budget with 8 x 2048); ``floor`` = whole epochs that fit in the
    budget (999,424 for 2048-step epochs), as OmniSafe does.
    """

    name: str
    label: str
    implementation: str
    n_envs: int = 8
    vec_env: str = "batched"
    normalise_reward: bool = True
    return_bounds: tuple[float, float] = PAPER_RETURN_BOUNDS
    shape_reward: bool = False
    cost_mode: str = "minimal"
    cost_scale: float = 1.0
    cost_reset: str = "per_episode"
    step_accounting: str = "rollouts"
    net_arch: tuple[int, ...] = (64, 64)
    activation: str = "tanh"
    hparams: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        where = f"learner {self.name!r}"
        checks = [
            ("implementation", self.implementation, IMPLEMENTATIONS),
            ("vec_env", self.vec_env, VEC_ENVS),
            ("cost_mode", self.cost_mode, COST_MODES),
            ("cost_reset", self.cost_reset, (*RESET_POLICIES, "protocol")),
            ("step_accounting", self.step_accounting, STEP_ACCOUNTING),
            ("activation", self.activation, ("tanh", "relu")),
        ]
        for key, value, choices in checks:
            if value not in choices:
                raise SpecError(f"{where}: {key}={value!r} is not one of {', '.join(choices)}")
        if not isinstance(self.n_envs, int) or isinstance(self.n_envs, bool) or self.n_envs < 1:
            raise SpecError(f"{where}: n_envs must be a positive integer, got {self.n_envs!r}")

    def reward_cost(self, protocol: "ProtocolSpec") -> RewardCostSpec:
        reset = protocol.constrained_cost_reset if self.cost_reset == "protocol" else self.cost_reset
        return RewardCostSpec(
            cost_mode=self.cost_mode,  # type: ignore[arg-type]
            cost_scale=self.cost_scale,
            cost_reset=reset,  # type: ignore[arg-type]
            normalise_reward=self.normalise_reward,
            return_bounds=tuple(self.return_bounds),  # type: ignore[arg-type]
            shape_reward=self.shape_reward,
        )

    def with_overrides(self, overrides: Mapping[str, Any]) -> "LearnerSpec":
        """A copy with some fields (and ``hparams`` entries) replaced; unknown keys raise."""
        fields = [f.name for f in dataclasses.fields(self)]
        _check_keys(f"learner {self.name!r}", overrides, fields)
        values = dict(overrides)
        if "hparams" in values:
            values["hparams"] = {**self.hparams, **values["hparams"]}
        for key in ("return_bounds", "net_arch"):
            if key in values:
                values[key] = tuple(values[key])
        return dataclasses.replace(self, **values)


_SB3_PPO = {
    "n_steps": 2048,
    "batch_size": 64,
    "n_epochs": 10,
    "learning_rate": 3e-4,
    "gamma": 0.99,
    "gae_lambda": 0.95,
    "clip_range": 0.2,
    "ent_coef": 0.0,
    "vf_coef": 0.5,
    "max_grad_norm": 0.5,
}

#: What the paper's OmniSafe runs of PPO-Lag and CPO shared (evaluation spec 6.3 and Q3, Q20).
_OMNISAFE_COMMON = {
    "n_steps": 256,  # 2048 steps per epoch over 8 envs, as OmniSafe's steps_per_epoch
    "batch_size": 64,
    "learning_rate": 3e-4,
    "anneal_lr": True,
    "gamma": 0.99,
    "gae_lambda": 0.95,
    "cost_gamma": 0.99,
    "cost_gae_lambda": 0.95,
    "max_grad_norm": 40.0,
    "critic_l2_coef": 0.001,
    "cost_limit": 0.0,
    "ep_cost_window": 50,
    "reward_advantage_normalization": "standardize",
    "cost_advantage_normalization": "standardize",
    "reset_envs_each_rollout": True,  # OmniSafe resets all envs every epoch (spec Q20)
}

DEFAULT_LEARNERS: dict[str, LearnerSpec] = {
    "random": LearnerSpec("random", "Random", "random", n_envs=1, normalise_reward=False),
    "ppo": LearnerSpec("ppo", "PPO", "ppo", hparams=dict(_SB3_PPO)),
    "ppo_shaped": LearnerSpec(
        "ppo_shaped", "PPO Shaped", "ppo", shape_reward=True, cost_mode="full", cost_scale=50.0, hparams=dict(_SB3_PPO)
    ),
    "ppo_lag": LearnerSpec(
        "ppo_lag",
        "PPO Lag",
        "ppo_lag",
        cost_reset="protocol",
        step_accounting="floor",
        hparams={
            **_OMNISAFE_COMMON,
            "n_epochs": 40,
            "target_kl": 0.02,
            "clip_range": 0.2,
            "ent_coef": 0.0,
            "lagrange_init": 0.001,
            "lagrange_lr": 0.035,
        },
    ),
    "cpo": LearnerSpec(
        "cpo",
        "CPO",
        "cpo",
        cost_reset="protocol",
        step_accounting="floor",
        hparams={
            **_OMNISAFE_COMMON,
            "n_critic_updates": 10,
            "target_kl": 0.01,
            "cg_damping": 0.1,
            "cg_max_steps": 15,
            "line_search_max_iter": 15,
            "line_search_shrinking_factor": 0.8,
        },
    ),
}


def learner_spec(name: str, overrides: Mapping[str, Any] | None = None) -> LearnerSpec:
    """The paper's spec of a learner (``random``, ``ppo``, ``ppo_shaped``, ``ppo_lag``, ``cpo``)."""
    if name not in DEFAULT_LEARNERS:
        close = difflib.get_close_matches(name, list(DEFAULT_LEARNERS), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise SpecError(f"unknown learner {name!r}{hint}; learners: {', '.join(DEFAULT_LEARNERS)}")
    spec = DEFAULT_LEARNERS[name]
    return spec.with_overrides(overrides) if overrides else spec


@dataclass(frozen=True)
class ProtocolSpec:
    """What a protocol changes (evaluation spec 6 and the issue on baselines).

    ``paper``: reproduce the reference's runs where it changes numbers: the cost memory of PPO-Lag
    and CPO is never reset (spec Q1), and Random's final evaluation continues the random stream of
    its learn-time evaluations (each followed by a render episode of up to 50 steps), which is what
    reproduces the paper's Random column exactly. ``corrected``: the cost memory is reset every
    episode, as the paper describes; Random's final evaluation starts a fresh stream.
    """

    name: str
    constrained_cost_reset: str
    random_replays_learn_evals: bool
    random_learn_eval_steps: tuple[int, ...] = (0, 50_000)
    render_episode_steps: int = 50

    def __post_init__(self) -> None:
        if self.constrained_cost_reset not in RESET_POLICIES:
            raise SpecError(f"protocol {self.name!r}: constrained_cost_reset must be one of {', '.join(RESET_POLICIES)}")


PROTOCOLS: dict[str, ProtocolSpec] = {
    "paper": ProtocolSpec("paper", "never", True),
    "corrected": ProtocolSpec("corrected", "per_episode", False),
}


def protocol_spec(name: str | ProtocolSpec, overrides: Mapping[str, Any] | None = None) -> ProtocolSpec:
    if isinstance(name, ProtocolSpec):
        return name
    if name not in PROTOCOLS:
        raise SpecError(f"unknown protocol {name!r}; protocols: {', '.join(PROTOCOLS)}")
    spec = PROTOCOLS[name]
    if overrides:
        _check_keys(f"protocol {name!r}", overrides, [f.name for f in dataclasses.fields(spec)])
        values = dict(overrides)
        if "random_learn_eval_steps" in values:
            values["random_learn_eval_steps"] = tuple(values["random_learn_eval_steps"])
        spec = dataclasses.replace(spec, **values)
    return spec


def training_steps(spec: LearnerSpec, budget: int) -> int:
    """The ``total_timesteps`` to pass to SB3 so that the run trains what the paper's runs trained."""
    if budget < 0:
        raise SpecError(f"budget must be >= 0, got {budget}")
    if spec.implementation == "random":
        return 0
    rollout = int(spec.hparams.get("n_steps", 2048)) * spec.n_envs
    if spec.step_accounting == "floor":
        return (budget // rollout) * rollout
    return budget
