"""The training environment of a fleet: every run's copies in one simulator, each run's own cost.

What a single run's learner sees through ``TrolleyVecEnv -> VecMonitor -> VecMoralityWrapper``, for
``K`` runs at once: copy ``k * n_envs + i`` is env ``i`` of run ``k``, on run ``k``'s env id. The cost
of a step is the run's chain's (its memory is per copy), and the reward is the learner's transform of
the env reward and that cost, exactly as the wrapper computes them. Nothing is exchanged between runs
except the arrays they are stepped in.

Two simulators give the same bits (tested), and both take and return tensors on the fleet's device:

* :class:`FleetEnv` steps numpy arrays on the host (:class:`~morality_gym.envs.mixed.MixedBatchedTrolleyEnv`,
  :class:`~morality_gym.norms.cost.StackedCost`). On the CPU that is the fastest: numpy's small-array
  operations cost a third of torch's, and the tensors share the arrays' memory.
* :class:`DeviceFleetEnv` keeps the tables and the cost memory on the device
  (:class:`~morality_gym.envs.torch_sim.TorchTrolleySim`, the same :class:`~morality_gym.norms.cost.StackedCost`
  on tensors), so a GPU fleet never sends a step's data to the host and back.

:func:`fleet_env` picks one (``simulator="auto"``: the device's on a GPU, the host's on the CPU).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal, NamedTuple

import numpy as np
import torch as th

from morality_gym.constants import MAX_STEPS
from morality_gym.envs.mixed import MixedBatchedTrolleyEnv
from morality_gym.envs.torch_sim import TorchTrolleySim
from morality_gym.norms.cost import StackedCost, VectorCost
from morality_gym.norms.metric import BoundChain
from morality_gym.norms.reward_cost import RewardCostSpec

#: Which simulator a fleet steps: ``auto`` (the device's on a GPU, else the host's), ``host``, ``device``.
Simulator = Literal["auto", "host", "device"]
SIMULATORS: tuple[str, ...] = ("auto", "host", "device")


class FleetStep(NamedTuple):
    """One step of all copies (tensors of length ``K * n_envs`` on the fleet's device)."""

    obs: th.Tensor  # float32 [N, obs_dim], after auto-reset
    rewards: th.Tensor  # float32: the reward the learner trains on
    costs: th.Tensor  # float64: the step-wise moral cost
    dones: th.Tensor  # terminated | truncated
    truncated: th.Tensor  # truncated and not terminated (SB3's "TimeLimit.truncated")
    final_obs: th.Tensor | None  # last observations of the ended copies (zeros elsewhere); None: none ended


class _FleetEnvBase:
    """What both simulators of a fleet share: the runs' layout (copy ``k * n_envs + i`` is env ``i``
    of run ``k``), the learner's reward and cost settings, and the device steps return tensors on."""

    def __init__(self, bounds: Sequence[BoundChain], n_envs: int, reward_cost: RewardCostSpec, device: str | th.device) -> None:
        self.n_runs = len(bounds)
        self.n_envs = n_envs
        self.reward_cost = reward_cost
        self.device = th.device(device)

    def copies_of(self, runs: th.Tensor) -> th.Tensor:
        """Boolean mask over the copies of the runs where ``runs`` (``[K]`` bool) is true."""
        return runs.repeat_interleave(self.n_envs)

    def _tensor(self, arr: np.ndarray) -> th.Tensor:
        """An array as a tensor on the fleet's device (the same memory on the CPU)."""
        return th.from_numpy(arr).to(self.device)


class _OneCostMemory(_FleetEnvBase):
    """A fleet env whose copies share one cost object (``self.cost``) beside one simulator
    (``self.sim``): the device fleet and the drawn-dilemma fleet. Their checkpoint state is the same
    two parts, in :meth:`FleetEnv.state_dict`'s layout (a list of cost memories, here of one)."""

    sim: Any
    cost: Any

    def state_dict(self) -> dict[str, Any]:
        """The simulator's copies and the cost memory (see :meth:`FleetEnv.state_dict`)."""
        return {"sim": self.sim.state_dict(), "costs": [self.cost.state_dict()]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if len(state["costs"]) != 1:
            raise ValueError(f"cost memories: expected 1, got {len(state['costs'])}")
        self.sim.load_state_dict(state["sim"])
        self.cost.load_state_dict(state["costs"][0])


class FleetEnv(_FleetEnvBase):
    """``n_envs`` copies per run for every bound chain in ``bounds`` (one per run), simulated on the
    host; steps take and return tensors on ``device``."""

    name = "host"

    def __init__(
        self,
        bounds: Sequence[BoundChain],
        n_envs: int,
        reward_cost: RewardCostSpec,
        max_steps: int | None = MAX_STEPS,
        device: str | th.device = "cpu",
    ) -> None:
        super().__init__(bounds, n_envs, reward_cost, device)
        self.sim = MixedBatchedTrolleyEnv([b.env_id for b in bounds for _ in range(n_envs)], max_steps=max_steps, pad_obs=True)
        self.obs_dim = self.sim.obs_dim
        self.run_obs_dims = [self.sim.obs_dims[self.sim.env_ids[k * n_envs]] for k in range(self.n_runs)]
        groups: dict[tuple[str, str, float], list[int]] = {}
        for k, b in enumerate(bounds):
            groups.setdefault((b.env_id, b.chain.name, float(b.beta)), []).append(k)
        self._costs: list[tuple[np.ndarray, VectorCost]] = []
        for runs in groups.values():
            copies = np.concatenate([np.arange(k * n_envs, (k + 1) * n_envs) for k in runs])
            cost = VectorCost(
                bounds[runs[0]], len(copies), mode=reward_cost.cost_mode, scale=reward_cost.cost_scale, reset=reward_cost.cost_reset
            )
            self._costs.append((copies, cost))
        # all groups in one pass (the same bits as the loop over groups; None with a prescribed norm)
        self._stacked = StackedCost.of_groups(self._costs, self.n_runs * n_envs)

    def state_dict(self) -> dict[str, Any]:
        """Everything stepping changes: the simulator's copies and every cost memory (the stacked
        one, or one per group). Nothing here draws random numbers. For a training checkpoint."""
        costs = [self._stacked.state_dict()] if self._stacked is not None else [cost.state_dict() for _, cost in self._costs]
        return {"sim": self.sim.state_dict(), "costs": costs}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict` into a simulator built for the same runs."""
        owners = [self._stacked] if self._stacked is not None else [cost for _, cost in self._costs]
        if len(state["costs"]) != len(owners):
            raise ValueError(f"cost memories: expected {len(owners)}, got {len(state['costs'])}")
        self.sim.load_state_dict(state["sim"])
        for owner, memory in zip(owners, state["costs"]):
            owner.load_state_dict(memory)

    def reset(self, runs: th.Tensor | None = None) -> th.Tensor:
        """Reset every copy (or the copies of the runs where ``runs`` is true); returns all observations.

        As ``VecMoralityWrapper.reset``: the cost memory of the reset copies is cleared only under
        the ``per_episode`` policy (under ``never`` it survives, as in the paper's runs).
        """
        mask = None if runs is None else self.copies_of(runs).cpu().numpy()
        if self.reward_cost.cost_reset == "per_episode":
            if self._stacked is not None:
                self._stacked.reset(mask)
            else:
                for copies, cost in self._costs:
                    cost.reset(None if mask is None else mask[copies])
        return self._tensor(self.sim.reset(mask))

    def step(self, actions: th.Tensor) -> FleetStep:
        res = self.sim.step(actions.cpu().numpy())
        dones = res.terminated | res.truncated
        utility = self.sim.utility(res.transition)
        if self._stacked is not None:
            costs = self._stacked(res.events, utility, dones)
        else:
            costs = np.empty(len(dones), dtype=np.float64)
            for copies, cost in self._costs:
                costs[copies] = cost(res.events[copies], utility[copies], dones[copies])
        rewards = np.asarray(self.reward_cost.transform(res.reward.astype(np.float64), costs), dtype=np.float32)
        final_obs = None if res.final_obs is None else self._tensor(res.final_obs)
        truncated = res.truncated & ~res.terminated
        return FleetStep(*(self._tensor(a) for a in (res.obs, rewards, costs, dones, truncated)), final_obs)


class DeviceFleetEnv(_OneCostMemory):
    """:class:`FleetEnv` with the simulator, the cost and the reward on the fleet's device."""

    name = "device"

    def __init__(
        self,
        bounds: Sequence[BoundChain],
        n_envs: int,
        reward_cost: RewardCostSpec,
        max_steps: int | None = MAX_STEPS,
        device: str | th.device = "cpu",
    ) -> None:
        super().__init__(bounds, n_envs, reward_cost, device)
        copies = [b for b in bounds for _ in range(n_envs)]
        self.cost = StackedCost.for_copies(copies, reward_cost, self.device)  # first: refuses prescribed norms
        self.sim = TorchTrolleySim([b.env_id for b in copies], self.device, max_steps=max_steps)
        self.obs_dim = self.sim.obs_dim
        self.run_obs_dims = [self.sim.obs_dims[self.sim.env_ids[k * n_envs]] for k in range(self.n_runs)]

    def reset(self, runs: th.Tensor | None = None) -> th.Tensor:
        """As :meth:`FleetEnv.reset`."""
        mask = None if runs is None else self.copies_of(runs)
        if self.reward_cost.cost_reset == "per_episode":
            self.cost.reset(mask)
        return self.sim.reset(mask)

    def step(self, actions: th.Tensor) -> FleetStep:
        res = self.sim.step(actions)
        dones = res.terminated | res.truncated
        costs = self.cost(res.events, self.sim.utility(res.transition), dones)
        rewards = self.reward_cost.transform(res.reward.double(), costs).float()
        return FleetStep(res.obs, rewards, costs, dones, res.truncated & ~res.terminated, res.final_obs)


def fleet_env(
    simulator: Simulator,
    bounds: Sequence[BoundChain],
    n_envs: int,
    reward_cost: RewardCostSpec,
    max_steps: int | None,
    device: th.device,
) -> FleetEnv | DeviceFleetEnv:
    """The fleet's simulator: ``host`` (:class:`FleetEnv`), ``device`` (:class:`DeviceFleetEnv`) or
    ``auto``: the device's on a GPU unless a chain has a prescribed norm (which only the host's
    cost handles), the host's on the CPU (faster there, and the same bits)."""
    if simulator not in SIMULATORS:
        raise ValueError(f"simulator={simulator!r}: expected one of {', '.join(SIMULATORS)}")
    prescribed = any(not n.prohibited for b in bounds for n in b.chain.norms)
    if simulator == "device" or (simulator == "auto" and device.type != "cpu" and not prescribed):
        return DeviceFleetEnv(bounds, n_envs, reward_cost, max_steps, device)
    return FleetEnv(bounds, n_envs, reward_cost, max_steps, device)
