"""A fleet's simulator on the generalisation track's mixture: each run's copies draw their dilemmas.

:class:`~.env.FleetEnv` gives every copy of a run the run's one env id. Here a run has a *pool* of
bound chains (the train split's dilemmas under the run's chain) and every episode of each of its
copies is the pool entry its own stream draws (:class:`~morality_gym.envs.drawn.DrawnBatchedTrolleyEnv`,
stream ``k`` = run ``k``, seeded by the run's seed), seen through the compact observation
(:mod:`morality_gym.world.compact_observe`): one width for every dilemma. The cost of a step is the
run's chain under the *current* dilemma's normalisation (:class:`~morality_gym.norms.drawn_cost.DrawnCost`),
and the reward the learner's transform of the env reward and that cost, as :class:`~.env.FleetEnv`.

Host only: the tables of a pool (the Utility train pool: 934 graphs, 559k states) live in host
memory, and the networks may still train on a GPU (steps are moved as tensors, as the host fleet
env does).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch as th

from morality_gym.baselines.fleet.env import FleetStep, _OneCostMemory
from morality_gym.constants import MAX_STEPS
from morality_gym.envs.drawn import DrawnBatchedTrolleyEnv
from morality_gym.norms.drawn_cost import DrawnCost
from morality_gym.norms.metric import BoundChain
from morality_gym.norms.reward_cost import RewardCostSpec


class DrawnFleetEnv(_OneCostMemory):
    """``n_envs`` copies per run, run ``k`` drawing from ``pools[k]`` with seed ``seeds[k]``;
    ``table_cache``: where the pools' tables are kept between processes (:mod:`morality_gym.envs.table_cache`)."""

    name = "host-drawn"

    def __init__(
        self,
        pools: Sequence[Sequence[BoundChain]],
        seeds: Sequence[int],
        n_envs: int,
        reward_cost: RewardCostSpec,
        max_steps: int | None = MAX_STEPS,
        device: str | th.device = "cpu",
        table_cache: Path | None = None,
    ) -> None:
        super().__init__([pool[0] for pool in pools], n_envs, reward_cost, device)
        self.sim = DrawnBatchedTrolleyEnv([[b.env_id for b in pool] for pool in pools], n_envs, seeds,
                                          max_steps=max_steps, obs_type="compact", table_cache=table_cache)
        self.obs_dim = self.sim.obs_dim
        self.run_obs_dims = [self.obs_dim] * self.n_runs
        rows: dict[tuple[str, str, float], int] = {}
        entries: list[BoundChain] = []
        pool_rows = []
        for pool in pools:
            for b in pool:
                key = (b.env_id, b.chain.name, float(b.beta))
                if key not in rows:
                    rows[key] = len(entries)
                    entries.append(b)
            pool_rows.append([rows[(b.env_id, b.chain.name, float(b.beta))] for b in pool])
        #: Per run, its pool entries' rows in the cost table, laid end to end.
        self._rows_flat = np.concatenate([np.asarray(r, dtype=np.int64) for r in pool_rows])
        self._rows_offset = np.concatenate([[0], np.cumsum([len(r) for r in pool_rows])[:-1]]).astype(np.int64)
        self.cost = DrawnCost(entries, self.n_runs * n_envs, mode=reward_cost.cost_mode, scale=reward_cost.cost_scale)

    def _current_rows(self) -> np.ndarray:
        """Each copy's cost row: its run's pool entry of the current episode."""
        return self._rows_flat[self._rows_offset[self.sim.stream_of_copy] + self.sim.copy_entry]

    def reset(self, runs: th.Tensor | None = None) -> th.Tensor:
        """Reset every copy (or the copies of the runs where ``runs`` is true): each draws its next
        dilemma, its cost memory cleared. Returns all observations."""
        mask = np.ones(self.n_runs * self.n_envs, dtype=bool) if runs is None else self.copies_of(runs).cpu().numpy()
        obs = self.sim.reset(mask)
        self.cost.assign(mask, self._current_rows())
        return self._tensor(obs)

    def step(self, actions: th.Tensor) -> FleetStep:
        res = self.sim.step(actions.cpu().numpy())
        dones = res.terminated | res.truncated
        costs = self.cost(res.events, self.sim.utility(res.transition), dones)  # the ended episodes' own dilemmas
        if dones.any():
            self.cost.assign(dones, self._current_rows())  # the dilemmas the ended copies restarted on
        rewards = np.asarray(self.reward_cost.transform(res.reward.astype(np.float64), costs), dtype=np.float32)
        final_obs = None if res.final_obs is None else self._tensor(res.final_obs)
        truncated = res.truncated & ~res.terminated
        return FleetStep(*(self._tensor(a) for a in (res.obs, rewards, costs, dones, truncated)), final_obs)
