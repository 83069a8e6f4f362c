"""Learner and protocol specifications: every knob of the baselines as typed, frozen data.

Each setting's default is defined once. A default every learner shares (8 envs, the paper's return
bounds, a (64, 64) tanh network, ...) is a field default of :class:`LearnerSpec`; a learner's own
values (its class, its hyper-parameters) are in its file ``conf/algo/<name>.yaml``, which states
only what differs from the field defaults. A protocol's changes are in ``conf/protocol/<name>.yaml``
over the :class:`ProtocolSpec` defaults. :func:`learner_spec` and :func:`protocol_spec` read those
same files for library users (tests, the fleet trainer, the CLI), exactly as a sweep's Hydra
composition does (``runners.compose.schema`` registers these classes as Hydra's structured configs), so
there is no second copy of any value. The values are those that actually ran in the paper
(evaluation spec 6.3), not the ones printed in its appendix. Unknown keys and wrong types are
errors that name the key, the file and the closest valid key.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import yaml

from morality_gym.baselines import typed
from morality_gym.baselines.targets import TargetError, learner_trains, resolve
from morality_gym.clitools import did_you_mean
from morality_gym.constants import LEARN_EVAL_EVERY
from morality_gym.norms.cost import COST_MODES, RESET_POLICIES
from morality_gym.norms.reward_cost import PAPER_RETURN_BOUNDS, RewardCostSpec

#: The configuration files (Hydra's config directory): ``conf/`` at the repository's root, reached
#: through the link ``morality_gym/conf`` (a wheel installs the files themselves there). The one
#: place that knows where they are: the sweep (``runners.compose``) and the leaderboard import it from here.
CONF_DIR = Path(__file__).resolve().parents[1] / "conf"

#: The baselines' classes, which the fleet trainers match by identity (``_target_`` of their
#: ``conf/algo/*.yaml``); a user learner names its own.
SB3_PPO = "stable_baselines3.PPO"
PPO_LAG = "morality_gym.baselines.safe.PPOLag"
CPO = "morality_gym.baselines.safe.CPO"
#: The classes the fleet engine trains (one trainer each in :mod:`morality_gym.baselines.fleet`;
#: tests/test_fleet_sweep.py holds this list to them). Named here, below the fleet, so that the
#: sweep can cut its runs into fleets without importing the fleet's trainers.
FLEET_ALGORITHMS = (SB3_PPO, PPO_LAG, CPO)
#: The fleet's update engines: ``eager`` (per-operation PyTorch; reruns the releases bit for bit)
#: and ``compiled`` (:mod:`morality_gym.baselines.fleet.compiled`, which re-exports both names).
UPDATE_ENGINES = ("eager", "compiled")
#: The one place the default lives: the sweep's ``fleet_update`` (``runners.compose.schema.Sweep``)
#: and :func:`~morality_gym.baselines.fleet.build_fleet` read it. Here, below the fleet, so that the
#: sweep's configuration knows it without importing torch.
DEFAULT_UPDATE_ENGINE = "eager"
#: The short names that specs, run configs and model sidecars written before learners were named by
#: class (commit c0db801) recorded as ``implementation``, and the class each one meant. Frozen
#: history: read by :mod:`morality_gym.baselines.io` (old sidecars) and ``runners.record.rename_history``.
LEGACY_IMPLEMENTATIONS = {
    "random": "morality_gym.baselines.learners.RandomLearner", "ppo": SB3_PPO, "ppo_lag": PPO_LAG, "cpo": CPO,
}
VEC_ENVS = ("batched", "dummy")
STEP_ACCOUNTING = ("rollouts", "floor")


class SpecError(ValueError):
    """A learner or protocol setting is invalid; the message names the key and the valid choices."""


@cache
def fleet_algorithm(target: str) -> str | None:
    """The entry of :data:`FLEET_ALGORITHMS` that names the learner class at ``target``, or None.

    Matched by class identity (``stable_baselines3.ppo.PPO`` is ``stable_baselines3.PPO``): a
    subclass may train differently, so it trains on the single engine. A target that cannot be
    imported is no fleet learner (the sweep's checks report it). The sweep's cut into fleets
    (:func:`fleet_trains`) and the fleet's choice of trainer (``fleet_class``) both ask this."""
    try:
        cls = resolve(target)
    except TargetError:
        return None
    return next((algorithm for algorithm in FLEET_ALGORITHMS if resolve(algorithm) is cls), None)


def fleet_trains(target: str) -> bool:
    """True if the fleet engine trains the learner class at ``target`` (:func:`fleet_algorithm`)."""
    return fleet_algorithm(target) is not None


def check_keys(where: str, given: Mapping[str, Any], allowed: list[str]) -> None:
    allowed_here = [("target" if a == "_target_" else a) for a in allowed]
    for key in given:
        if key not in allowed_here:
            hint = did_you_mean(key, allowed)
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

    def with_overrides(self, overrides: Mapping[str, Any], where: str = "") -> LearnerSpec:
        """A copy with some fields (and ``hparams`` entries) replaced; unknown keys and wrong types raise.

        ``_target_`` (the key of the YAML files) is accepted for ``target``.
        """
        overrides = _rename_target(overrides)
        where = where or f"learner {self.name!r}"
        check_keys(where, overrides, _settable(LearnerSpec))
        if not isinstance(overrides.get("hparams", {}), Mapping):
            raise SpecError(f"{where}: hparams must be a mapping, got {overrides['hparams']!r}")
        return _typed(LearnerSpec, dataclasses.asdict(self), overrides, where=where)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], name: str, where: str = "") -> LearnerSpec:
        """A spec from an algo file's values (``_target_`` names the class; every field left out
        takes this class's default, ``label`` defaults to ``name``)."""
        values = _rename_target(values)
        where = where or f"learner {name!r}"
        check_keys(where, values, _settable(cls))
        if "target" not in values:
            raise SpecError(f"{where}: no _target_; name the algorithm class, e.g. _target_: stable_baselines3.A2C")
        if not isinstance(values.get("hparams") or {}, Mapping):
            raise SpecError(f"{where}: hparams must be a mapping, got {values['hparams']!r}")
        base = {"name": name, "label": values.get("label") or values.get("name") or name}
        return _typed(cls, base, values, where=where)


def _settable(cls: type) -> list[str]:
    """The keys a file or an override may set (``protocol`` is set by :meth:`ProtocolSpec.apply` only)."""
    return ["_target_" if f == "target" else f for f in typed.valid_keys(cls) if f != "protocol"]


def _typed(cls: type, *layers: Mapping[str, Any], where: str) -> Any:
    try:
        return typed.build(cls, typed.merge(cls, *layers, where=where), where=where)
    except typed.TypedConfigError as exc:
        raise SpecError(str(exc)) from exc


def _rename_target(values: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(values)
    if "_target_" in out:
        if "target" in out:
            raise SpecError("give the class once, as _target_ (not also as target)")
        out["target"] = out.pop("_target_")
    return out


def _file_names(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))


def _read_file(group: str, name: str, what: str) -> tuple[Path, dict[str, Any]]:
    path = CONF_DIR / group / f"{name}.yaml"
    if not path.is_file():
        names = _file_names(group)
        hint = did_you_mean(name, names)
        raise SpecError(f"unknown {what} {name!r}{hint}; {what}s: {', '.join(names)} (the files of {CONF_DIR / group})")
    return path, yaml.safe_load(path.read_text()) or {}


#: Keys of an algo file that are not learner settings: ``planning`` is the sweep's time estimate
#: (``runners.plan.estimate.Planning``), read by the sweep's plan only.
ALGO_FILE_EXTRAS = ("planning",)


def learner_spec(name: str, overrides: Mapping[str, Any] | None = None) -> LearnerSpec:
    """A built-in learner (``random``, ``ppo``, ``ppo_shaped``, ``ppo_lag``, ``cpo``, or any
    ``conf/algo/<name>.yaml`` shipped with the package) as its file defines it, over the
    :class:`LearnerSpec` defaults: the same file, read the same way, as a sweep's ``algo=<name>``.
    """
    path, values = _read_file("algo", name, "learner")
    spec = LearnerSpec.from_mapping({k: v for k, v in values.items() if k not in ALGO_FILE_EXTRAS}, name, where=str(path))
    return spec.with_overrides(overrides) if overrides else spec


@dataclass(frozen=True)
class RandomReplay:
    """How the random baseline draws its evaluations from its one random stream (the random
    learner's own settings, which a protocol sets: :meth:`ProtocolSpec.random_replay`).

    ``learn_evals``: before the final evaluation, play the learn-time evaluations at ``steps``
    (each followed by a render episode of up to ``render_episode_steps`` steps) from the same
    stream, as the reference's runs did; off, the final evaluation starts the stream afresh.
    """

    learn_evals: bool = False
    steps: tuple[int, ...] = (0, LEARN_EVAL_EVERY)
    render_episode_steps: int = 50


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
    steps), which is what reproduces the paper's Random column exactly. The random learner gets
    these three as its own settings (:meth:`random_replay`), never the protocol.
    """

    name: str
    learner_overrides: Mapping[str, Mapping[str, Any]]
    random_replays_learn_evals: bool
    random_learn_eval_steps: tuple[int, ...] = (0, LEARN_EVAL_EVERY)
    render_episode_steps: int = 50

    def __post_init__(self) -> None:
        for algo, override in self.learner_overrides.items():
            if not isinstance(override, Mapping):
                raise SpecError(f"protocol {self.name!r}: learner_overrides.{algo} must be a mapping")
            allowed = [f.name for f in dataclasses.fields(LearnerSpec) if f.name not in ("name", "label", "target", "protocol")]
            check_keys(f"protocol {self.name!r}: learner_overrides.{algo}", override, allowed)
        if isinstance(self.render_episode_steps, bool) or not isinstance(self.render_episode_steps, int) or self.render_episode_steps < 0:
            raise SpecError(f"protocol {self.name!r}: render_episode_steps must be an integer >= 0, got {self.render_episode_steps!r}")

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], where: str = "") -> ProtocolSpec:
        """A protocol from a protocol file's values over this class's defaults."""
        where = where or f"protocol {values.get('name', '?')!r}"
        check_keys(where, values, typed.valid_keys(cls))
        return _typed(cls, values, where=where)

    def random_replay(self) -> RandomReplay:
        """The random learner's settings under this protocol (its only effect on that learner)."""
        return RandomReplay(self.random_replays_learn_evals, tuple(self.random_learn_eval_steps), self.render_episode_steps)

    def apply(self, spec: LearnerSpec) -> LearnerSpec:
        """``spec`` with this protocol's overrides for its algorithm name, stamped with the protocol.

        Called once per learner: by a sweep where it resolves its runs (``runners.compose.sweep_config``), or by
        the library's :func:`~morality_gym.baselines.learners.build_learner` and
        :func:`~morality_gym.baselines.fleet.build_fleet` for a spec no protocol has touched yet.
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


def trains_alike(algo: str, protocols: Sequence[str | ProtocolSpec]) -> bool:
    """Whether the learner of algo name ``algo`` trains and is evaluated identically under every
    protocol of ``protocols``: none of them overrides its settings, and, for Random, whose final
    evaluation continues a protocol's random stream, they agree on that stream. Its cells under one
    are then its cells under the others, so a sweep of one protocol need not run it again."""
    specs = [protocol_spec(p) for p in protocols]
    if any(algo in spec.learner_overrides for spec in specs):
        return False
    return algo != "random" or len({spec.random_replay() for spec in specs}) <= 1


def protocol_spec(name: str | ProtocolSpec, overrides: Mapping[str, Any] | None = None) -> ProtocolSpec:
    """A protocol (``paper``, ``corrected``: ``conf/protocol/<name>.yaml`` over the
    :class:`ProtocolSpec` defaults, as a sweep's ``protocol=<name>`` reads it), optionally with
    some fields replaced."""
    if isinstance(name, ProtocolSpec):
        return name
    path, values = _read_file("protocol", str(name), "protocol")
    return ProtocolSpec.from_mapping({**values, **(overrides or {})}, where=str(path))


def training_steps(spec: LearnerSpec, budget: int) -> int:
    """The ``total_timesteps`` to pass to SB3 so that the run trains what the paper's runs trained."""
    if budget < 0:
        raise SpecError(f"budget must be >= 0, got {budget}")

    if not learner_trains(spec.target):
        return 0
    rollout = int(spec.hparams.get("n_steps", 2048)) * spec.n_envs
    if spec.step_accounting == "floor":
        return (budget // rollout) * rollout
    return budget
