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

#: The baselines' classes (``_target_`` of ``conf/algo/*.yaml``); a user learner names its own.
RANDOM = "morality_gym.baselines.learners.RandomLearner"
SB3_PPO = "stable_baselines3.PPO"
PPO_LAG = "morality_gym.baselines.safe.PPOLag"
CPO = "morality_gym.baselines.safe.CPO"
#: The short names that specs, run configs and model sidecars written before learners were named by
#: class (commit c0db801) recorded as ``implementation``, and the class each one meant. Frozen
#: history: read by :mod:`morality_gym.baselines.io` (old sidecars) and ``runners.migrations``.
LEGACY_IMPLEMENTATIONS = {"random": RANDOM, "ppo": SB3_PPO, "ppo_lag": PPO_LAG, "cpo": CPO}
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
    """One learner: which class trains it, how it sees reward and cost, and its hyper-parameters.

    ``target``: the import path of the class (an algo file's ``_target_``): an SB3 algorithm, which
    receives ``hparams`` as constructor arguments, or a self-driving
    :class:`~morality_gym.baselines.learners.Learner` subclass (the random baseline). Any class
    works; see :mod:`morality_gym.baselines.targets`.

    ``cost_reset``: when the cost's first-violation memory is cleared (``never`` is what the paper's
    PPO-Lag and CPO runs did; the corrected protocol resets it ``per_episode``).
    ``step_accounting``: ``rollouts`` = SB3 runs whole rollouts until the budget is reached
    (1,015,808 steps for a 1M budget with 8 x 2048); ``floor`` = whole epochs that fit in the
    budget (999,424 for 2048-step epochs), as OmniSafe does.
    ``protocol``: the protocol whose learner overrides this spec already carries (set by
    :meth:`ProtocolSpec.apply`); ``None`` for a spec that no protocol has touched yet.
    """

    name: str
    label: str
    target: str
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
    protocol: str | None = None

    def __post_init__(self) -> None:
        where = f"learner {self.name!r}"
        if not isinstance(self.target, str) or "." not in self.target.strip("."):
            raise SpecError(f"{where}: _target_ must be the import path of a class, like stable_baselines3.PPO, "
                            f"got {self.target!r}")
        checks = [
            ("vec_env", self.vec_env, VEC_ENVS),
            ("cost_mode", self.cost_mode, COST_MODES),
            ("cost_reset", self.cost_reset, RESET_POLICIES),
            ("step_accounting", self.step_accounting, STEP_ACCOUNTING),
            ("activation", self.activation, ("tanh", "relu")),
        ]
        for key, value, choices in checks:
            if value not in choices:
                raise SpecError(f"{where}: {key}={value!r} is not one of {', '.join(choices)}")
        if not isinstance(self.n_envs, int) or isinstance(self.n_envs, bool) or self.n_envs < 1:
            raise SpecError(f"{where}: n_envs must be a positive integer, got {self.n_envs!r}")

    def reward_cost(self) -> RewardCostSpec:
        """How the training env's reward and cost wrapper is set up for this learner."""
        return RewardCostSpec(
            cost_mode=self.cost_mode,  # type: ignore[arg-type]
            cost_scale=self.cost_scale,
            cost_reset=self.cost_reset,  # type: ignore[arg-type]
            normalise_reward=self.normalise_reward,
            return_bounds=tuple(self.return_bounds),  # type: ignore[arg-type]
            shape_reward=self.shape_reward,
        )

    def with_overrides(self, overrides: Mapping[str, Any]) -> "LearnerSpec":
        """A copy with some fields (and ``hparams`` entries) replaced; unknown keys raise.

        ``_target_`` (the key of the YAML files) is accepted for ``target``.
        """
        overrides = _rename_target(overrides)
        fields = [f.name for f in dataclasses.fields(self) if f.name != "protocol"]  # set by ProtocolSpec.apply only
        _check_keys(f"learner {self.name!r}", overrides, fields)
        if not isinstance(overrides.get("hparams", {}), Mapping):
            raise SpecError(f"learner {self.name!r}: hparams must be a mapping, got {overrides['hparams']!r}")
        values = dict(overrides)
        if "hparams" in values:
            values["hparams"] = {**self.hparams, **values["hparams"]}
        for key in ("return_bounds", "net_arch"):
            if key in values:
                values[key] = tuple(values[key])
        return dataclasses.replace(self, **values)


    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], name: str) -> "LearnerSpec":
        """A spec from an algo file's values (``_target_`` names the class; every field left out
        takes this class's default, ``label`` defaults to ``name``)."""
        values = _rename_target(values)
        fields = [f.name for f in dataclasses.fields(cls) if f.name != "protocol"]
        _check_keys(f"learner {name!r}", values, fields)
        if "target" not in values:
            raise SpecError(f"learner {name!r}: no _target_; name the algorithm class, e.g. _target_: stable_baselines3.A2C")
        values = {"name": name, "label": values.get("label", values.get("name", name)), **values}
        if not isinstance(values.get("hparams", {}), Mapping):
            raise SpecError(f"learner {name!r}: hparams must be a mapping, got {values['hparams']!r}")
        values["hparams"] = dict(values.get("hparams") or {})
        for key in ("return_bounds", "net_arch"):
            if key in values and isinstance(values[key], (list, tuple)):
                values[key] = tuple(values[key])
        return cls(**values)


def _rename_target(values: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(values)
    if "_target_" in out:
        if "target" in out:
            raise SpecError("give the class once, as _target_ (not also as target)")
        out["target"] = out.pop("_target_")
    return out


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

#: What the paper's OmniSafe runs of PPO-Lag and CPO shared: the values that actually ran, not
#: the paper's appendix tables (docs/protocols.md has one entry per reproduced behaviour).
_OMNISAFE_COMMON = {
    "n_steps": 256,  # 2048 steps per epoch over 8 envs, as OmniSafe's steps_per_epoch
    "batch_size": 64,
    "learning_rate": 3e-4,
    "anneal_lr": True,  # the actor's rate decays linearly to 0 ...
    "anneal_lr_timing": "epoch",  # ... stepped after each epoch, so epoch k of E trains at lr (1 - k/E)
    "anneal_critic_lr": False,  # the critics keep 3e-4
    "gamma": 0.99,
    "gae_lambda": 0.95,
    "cost_gamma": 0.99,
    "cost_gae_lambda": 0.95,
    "max_grad_norm": 40.0,
    "critic_grad_clip": "per_critic",  # each critic clips its own gradient norm
    "critic_l2_coef": 0.001,
    "cost_limit": 0.0,
    "ep_cost_window": 50,
    "reward_advantage_normalization": "standardize",
    "cost_advantage_normalization": "center",  # OmniSafe only centres cost advantages
    "reset_envs_each_rollout": True,  # OmniSafe restarts every training env at each epoch
    "weight_init": "kaiming_uniform",
    "adam_eps": 1e-8,
}

DEFAULT_LEARNERS: dict[str, LearnerSpec] = {
    "random": LearnerSpec("random", "Random", RANDOM, n_envs=1, normalise_reward=False),
    "ppo": LearnerSpec("ppo", "PPO", SB3_PPO, hparams=dict(_SB3_PPO)),
    "ppo_shaped": LearnerSpec(
        "ppo_shaped", "PPO Shaped", SB3_PPO, shape_reward=True, cost_mode="full", cost_scale=50.0, hparams=dict(_SB3_PPO)
    ),
    "ppo_lag": LearnerSpec(
        "ppo_lag",
        "PPO Lag",
        PPO_LAG,
        cost_reset="never",
        step_accounting="floor",
        hparams={
            **_OMNISAFE_COMMON,
            "n_epochs": 40,
            "target_kl": 0.02,
            "kl_early_stop_reduction": "sum",
            "clip_range": 0.2,
            "ent_coef": 0.0,
            "lagrange_init": 0.001,
            "lagrange_lr": 0.035,
        },
    ),
    "cpo": LearnerSpec(
        "cpo",
        "CPO",
        CPO,
        cost_reset="never",
        step_accounting="floor",
        hparams={
            **_OMNISAFE_COMMON,
            "n_critic_updates": 10,
            "target_kl": 0.01,
            "cg_damping": 0.1,
            "cg_max_steps": 15,
            "cg_residual_tol": 1e-10,
            "cg_eps": 1e-6,
            "dual_solution": "omnisafe",
            "line_search_max_iter": 20,
            "line_search_shrinking_factor": 0.8,
            "line_search_accept": "omnisafe",
            "trust_region_rescale": False,
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
    """What a protocol changes (docs/protocols.md; the reasons are in ``conf/protocol/*.yaml``).

    ``learner_overrides``: per *algorithm name* (an algo file's ``name``: ``ppo_lag``, ``cpo``), the
    spec fields and ``hparams`` the protocol sets, applied on top of the algorithm's own values by
    :meth:`apply`. Keyed by name, not by class, so that a protocol changes exactly the baselines it
    was written for: a user's learner (even one built on PPOLag) is never silently changed by it
    (a protocol file may list it by its name). ``paper`` reproduces the reference's runs where it
    changes numbers (OmniSafe's arithmetic, bugs included, and a cost memory that is never reset); ``corrected`` fixes only what
    is a bug (the memory resets each episode, PPO-Lag's early stop uses the mean KL, CPO solves its
    dual exactly) and keeps OmniSafe's design choices.

    ``random_replays_learn_evals``: Random's final evaluation continues the random stream of its
    learn-time evaluations (each followed by a render episode of up to ``render_episode_steps``
    steps), which is what reproduces the paper's Random column exactly.
    """

    name: str
    learner_overrides: Mapping[str, Mapping[str, Any]]
    random_replays_learn_evals: bool
    random_learn_eval_steps: tuple[int, ...] = (0, 50_000)
    render_episode_steps: int = 50

    def __post_init__(self) -> None:
        for algo, override in self.learner_overrides.items():
            if not isinstance(override, Mapping):
                raise SpecError(f"protocol {self.name!r}: learner_overrides.{algo} must be a mapping")
            allowed = [f.name for f in dataclasses.fields(LearnerSpec) if f.name not in ("name", "label", "target", "protocol")]
            _check_keys(f"protocol {self.name!r}: learner_overrides.{algo}", override, allowed)

    def apply(self, spec: LearnerSpec) -> LearnerSpec:
        """``spec`` with this protocol's overrides for its algorithm name, stamped with the protocol.

        A spec already stamped with this protocol is returned unchanged (so that settings changed
        after the protocol, e.g. on a sweep's command line, are not overwritten); one stamped with
        another protocol is an error, never a silent mix of the two.
        """
        if spec.protocol == self.name:
            return spec
        if spec.protocol is not None:
            raise SpecError(
                f"learner {spec.name!r} was resolved for protocol {spec.protocol!r} and cannot run under {self.name!r}; "
                "start from learner_spec(name) instead"
            )
        override = self.learner_overrides.get(spec.name)
        resolved = spec.with_overrides(override) if override else spec
        return dataclasses.replace(resolved, protocol=self.name)


#: Each protocol's learner overrides. Both protocols state every protocol-dependent setting, so that
#: what differs between them is visible in one place, and an algorithm file cannot change it.
PROTOCOLS: dict[str, ProtocolSpec] = {
    "paper": ProtocolSpec(
        "paper",
        {
            "ppo_lag": {"cost_reset": "never", "hparams": {"kl_early_stop_reduction": "sum"}},
            "cpo": {"cost_reset": "never", "hparams": {"dual_solution": "omnisafe"}},
        },
        random_replays_learn_evals=True,
    ),
    "corrected": ProtocolSpec(
        "corrected",
        {
            "ppo_lag": {"cost_reset": "per_episode", "hparams": {"kl_early_stop_reduction": "mean"}},
            "cpo": {"cost_reset": "per_episode", "hparams": {"dual_solution": "exact"}},
        },
        random_replays_learn_evals=False,
    ),
}


def protocol_spec(name: str | ProtocolSpec, overrides: Mapping[str, Any] | None = None) -> ProtocolSpec:
    """A protocol by name (``paper`` or ``corrected``), optionally with some fields replaced."""
    if isinstance(name, ProtocolSpec):
        return name
    if name not in PROTOCOLS:
        close = difflib.get_close_matches(str(name), list(PROTOCOLS), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise SpecError(f"unknown protocol {name!r}{hint}; protocols: {', '.join(PROTOCOLS)}")
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
    from morality_gym.baselines.targets import learner_trains

    if not learner_trains(spec.target):
        return 0
    rollout = int(spec.hparams.get("n_steps", 2048)) * spec.n_envs
    if spec.step_accounting == "floor":
        return (budget // rollout) * rollout
    return budget
