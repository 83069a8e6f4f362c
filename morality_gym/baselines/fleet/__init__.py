"""Train many runs at once: K independent runs of one learner in one process (issue 14).

    from morality_gym.baselines.fleet import FleetRun, build_fleet
    fleet = build_fleet(learner_spec("ppo_lag"), [FleetRun(bound, seed) for seed in range(12)], protocol="paper")
    fleet.learn(1_000_000)
    for learner in fleet.learners():   # single-run learners holding the trained weights
        learner.final_evaluation()

Read first: the single-run learners are the plain-autograd version of every update a fleet makes,
and the reference its tests hold it to (SB3's ``PPO.train``; :mod:`morality_gym.baselines.safe.ppo_lag`
and :mod:`morality_gym.baselines.safe.cpo`); tests/test_fleet.py checks each fleet learner against
them, and tests/test_fleet_math.py each hand-written gradient here against autograd.

A fleet's runs share a learner spec, a protocol and a budget; their scenarios, variants, chains
and seeds may differ (observations of different sizes are zero-padded to the widest, and each run's
first layers keep zero weights there: tests/test_fleet_mixed.py holds every run of a mixed fleet to
the bits of a fleet of its scenario alone). Every run reproduces its single run's
arithmetic (tested: a fleet of one and the single learner end at the same parameters to float
tolerance; changing one run's seed changes no other run). Modules: :mod:`.env` (all runs' copies
in one simulator, per-run cost and reward), :mod:`.nets` (parameters stacked along a run axis,
batched matrix products), :mod:`.optim` (per-run Adam and clipping), :mod:`.base` (start, learn loop,
the state as its parts' states), :mod:`.rollout` (one rollout of every run, on the device), :mod:`.streams` (each run's
random streams), :mod:`.ppo`, :mod:`.ppo_lag`, :mod:`.cpo` (the updates; CPO's actor step run by run,
or all runs at once on accelerators: :mod:`.cpo_batch`, with :mod:`.cpo_math` what both use), :mod:`.state` and
:mod:`.checkpoint` (a killed fleet resumes bit for bit).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from morality_gym.baselines.device import Device
from morality_gym.baselines.fleet.base import FleetRun, FleetTrainer
from morality_gym.baselines.fleet.checkpoint import FleetCheckpoint
from morality_gym.baselines.fleet.compiled import DEFAULT_UPDATE_ENGINE
from morality_gym.baselines.fleet.cpo import FleetCPO
from morality_gym.baselines.fleet.env import Simulator
from morality_gym.baselines.fleet.ppo import FleetPPO
from morality_gym.baselines.fleet.ppo_lag import FleetPPOLag
from morality_gym.baselines.specs import LearnerSpec, ProtocolSpec, SpecError, fleet_algorithm, protocol_spec
from morality_gym.baselines.targets import resolve
from morality_gym.constants import MAX_STEPS

#: The trainer of each class in :data:`morality_gym.baselines.specs.FLEET_ALGORITHMS`, which the
#: sweep reads to cut its runs into fleets without importing these (a test holds the two together).
TRAINERS: dict[str, type[FleetTrainer]] = {trainer.algorithm: trainer for trainer in (FleetPPO, FleetPPOLag, FleetCPO)}


def fleet_class(target: str) -> type[FleetTrainer]:
    """The fleet trainer that reproduces the algorithm class at ``target`` (SB3's PPO, PPOLag, CPO).

    Matched as the sweep matches it (:func:`~morality_gym.baselines.specs.fleet_algorithm`): by
    class identity, so a subclass, which may train differently, has no fleet trainer.
    """
    algorithm = fleet_algorithm(target)
    if algorithm is None:
        resolve(target)  # a target that cannot be imported says so (TargetError), as before
        raise SpecError(f"the fleet engine does not train {target!r}; fleet learners: {', '.join(TRAINERS)}")
    return TRAINERS[algorithm]


def build_fleet(
    spec: LearnerSpec,
    runs: Sequence[FleetRun],
    protocol: ProtocolSpec | str = "paper",
    max_steps: int | None = MAX_STEPS,
    device: str | Device = "cpu",
    simulator: Simulator = "auto",
    update: str = DEFAULT_UPDATE_ENGINE,
    table_cache: Path | None = None,
) -> FleetTrainer:
    """The fleet trainer for ``runs`` of the learner ``spec`` under ``protocol``, its networks,
    rollouts and updates on ``device`` (``cpu``, or ``cuda`` when torch sees a GPU). ``simulator``:
    ``auto`` steps the envs on the device on a GPU and with numpy on the CPU (the faster there;
    both give the same bits), ``host`` or ``device`` force one (:mod:`.env`). ``update``: ``eager``
reruns the releases bit for bit, ``compiled`` runs the minibatch steps compiled (:mod:`.compiled`;
float rounding differs). The sampling streams
    and the single-run learners it hands back stay on the CPU. ``table_cache``: a folder where the
    tables of mixture runs' pools are kept between processes (:mod:`morality_gym.envs.table_cache`:
    a fleet on the track's train pool then starts in seconds). The library's entry: ``spec`` is
    resolved for the protocol here (:meth:`~morality_gym.baselines.specs.ProtocolSpec.apply`), then
    :func:`make_fleet`."""
    protocol = protocol_spec(protocol)
    return make_fleet(protocol.apply(spec), runs, protocol, max_steps=max_steps, device=device, simulator=simulator,
                      update=update, table_cache=table_cache)


def make_fleet(
    spec: LearnerSpec,
    runs: Sequence[FleetRun],
    protocol: ProtocolSpec,
    max_steps: int | None = MAX_STEPS,
    device: str | Device = "cpu",
    simulator: Simulator = "auto",
    update: str = DEFAULT_UPDATE_ENGINE,
    table_cache: Path | None = None,
) -> FleetTrainer:
    """The fleet trainer of a ``spec`` already resolved for ``protocol`` (a sweep's runs carry one);
    a sweep's ``device`` arrives as the :class:`~morality_gym.baselines.device.Device` it resolved
    and checked once, which the fleet takes as it is."""
    return fleet_class(spec.target)(spec, runs, protocol=protocol, max_steps=max_steps, device=device, simulator=simulator,
                                    update=update, table_cache=table_cache)


__all__ = ["FleetCheckpoint", "FleetRun", "FleetTrainer", "build_fleet", "fleet_class", "make_fleet"]
