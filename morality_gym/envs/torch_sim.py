"""The batched simulator on a torch device: copies of any env ids stepped as a few gathers.

Every environment is a finite state graph, already enumerated (:class:`~morality_gym.world.graph.GraphTables`),
so a step of ``n`` copies is ``next_state = next[state * 6 + action]`` and a gather of the
observation, reward, events and utilities of that row. :class:`~morality_gym.envs.batched.BatchedTrolleyEnv`
does it with numpy arrays on the host; :class:`TorchTrolleySim` does the same with tensors on the
device that trains (a GPU, or the CPU), so a training loop never moves a step's data to the host and
back. It is the engine of the device-resident fleet rollout and of the public
:class:`~morality_gym.envs.torch_vector.TorchTrolleyVectorEnv`.

It is the host simulator on tensors, not a second one: its tables are the host's, built and laid out
by the same code (:func:`~morality_gym.envs.batched.sim_tables`, :func:`~morality_gym.envs.batched.lay_out`:
the graphs of all env ids end to end, observations zero-padded to one width, so it mixes scenarios),
and a step's transition is the host's :func:`~morality_gym.envs.batched.advance`. Only the restart of
the copies that ended is its own, written without a data-dependent branch.

Same transitions as the host simulator, bit for bit (tested on all registered envs): observations are
the graph's float64 values rounded to float32, rewards the float64 table rounded to float32, events
the same bit masks (as int64: torch has no unsigned 32-bit bit operations on every device), and
utilities the integer table as float64. Only ``same_step`` auto-reset is offered: a copy that ends is
reset in the step it ends and its last observation returned in ``final_obs`` (zeros for the other
copies), with no data-dependent branch, so a step never waits for the device.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch as th

from morality_gym.constants import MAX_STEPS
from morality_gym.envs.batched import Layout, advance, lay_out, sim_tables
from morality_gym.envs.registry import canonical_env_id
from morality_gym.envs.trolley import _overrides


class TorchStep(NamedTuple):
    """One step of every copy, as tensors on the simulator's device (length ``num_envs``)."""

    obs: th.Tensor  # float32 [n, obs_dim], after auto-reset
    reward: th.Tensor  # float32 [n]
    terminated: th.Tensor  # bool [n]
    truncated: th.Tensor  # bool [n]
    events: th.Tensor  # int64 [n]: bit masks over vocab.EVENTS
    transition: th.Tensor  # int64 [n]: the row of each copy's transition (for utility, goal_reached)
    final_obs: th.Tensor  # float32 [n, obs_dim]: last observation of the copies that ended, zeros elsewhere


class TorchTrolleySim:
    """``len(env_ids)`` copies, copy ``i`` running ``env_ids[i]`` (any scenarios, any mix).

    Args:
        env_ids: one registered id per copy.
        device: where the tables and the copies' states live (``"cpu"``, ``"cuda"``, ...).
        max_steps: truncation on step ``max_steps + 1`` (``None``: never), as the single env.
        obs_dim: pad observations to this width (default: the widest of the env ids').
        normalise_obs: the observation codec's normalisation, as the single env's option.
        overrides: variant overrides, as the single env's ``overrides``.
        obs_type: the observation rows, as the host simulator's (``flat``, ``grid``, ``compact``).
        table_cache: a folder that keeps the graphs' tables between processes, as the host's.

    The tables are the host simulator's (:func:`~morality_gym.envs.batched.sim_tables`, laid out by
    :func:`~morality_gym.envs.batched.lay_out`), moved to the device once.
    """

    def __init__(
        self,
        env_ids: Sequence[str],
        device: str | th.device = "cpu",
        *,
        max_steps: int | None = MAX_STEPS,
        obs_dim: int | None = None,
        normalise_obs: bool = True,
        overrides: dict | None = None,
        obs_type: str = "flat",
        table_cache: Path | None = None,
    ) -> None:
        _check_arguments(env_ids, max_steps)
        self.device = th.device(device)
        self.env_ids = [canonical_env_id(e) for e in env_ids]
        self.unique_env_ids: list[str] = list(dict.fromkeys(self.env_ids))
        self.num_envs = len(self.env_ids)
        self.max_steps = max_steps
        tables = [sim_tables(e, obs_type, np.float32, overrides=_overrides(overrides), normalise=normalise_obs,
                             cache_dir=table_cache) for e in self.unique_env_ids]
        width = max(int(t.obs.shape[1]) for t in tables) if obs_dim is None else int(obs_dim)
        laid = lay_out(tables, self.unique_env_ids, width)
        self.obs_dims = laid.obs_dims
        self.obs_dim = width
        self._load_tables(laid)
        index = {e: i for i, e in enumerate(self.unique_env_ids)}
        self.copy_graph = th.tensor([index[e] for e in self.env_ids], dtype=th.int64, device=self.device)
        offsets = laid.graph_offsets.astype(np.int64)
        self._start = th.as_tensor(offsets, dtype=th.int64, device=self.device)[self.copy_graph]
        #: One past each copy's last state in the tables (a restored state must lie in its own graph's block).
        ends = offsets + np.array([t.n_states for t in tables], dtype=np.int64)
        self._end = th.as_tensor(ends, dtype=th.int64, device=self.device)[self.copy_graph]
        self._limit = np.iinfo(np.int32).max if max_steps is None else max_steps
        self.state = self._start.clone()
        self.elapsed = th.zeros(self.num_envs, dtype=th.int64, device=self.device)

    def _load_tables(self, laid: Layout) -> None:
        """The laid-out tables as tensors on the device: states and event masks as int64 (torch has
        no unsigned 32-bit bit operations on every device), utilities as float64. Copied, never
        shared: a host table may be a cached, read-only array of the graph."""
        dev = self.device
        self._next = th.tensor(laid.next.astype(np.int64), device=dev)
        self._reward = th.tensor(laid.reward, device=dev)
        self._events = th.tensor(laid.events.astype(np.int64), device=dev)
        self._utility = th.tensor(laid.utility.astype(np.float64), device=dev)
        self._goal = th.tensor(laid.goal, device=dev)
        self._done = th.tensor(laid.done, device=dev)
        self._obs = th.tensor(laid.obs.astype(np.float32, copy=False), device=dev)

    # ------------------------------------------------------------------ API
    def reset(self, mask: th.Tensor | None = None) -> th.Tensor:
        """Reset every copy (or those where the bool tensor ``mask`` is true); returns all observations."""
        if mask is None:
            self.state = self._start.clone()
            self.elapsed = th.zeros_like(self.elapsed)
        else:
            self.state = th.where(mask, self._start, self.state)
            self.elapsed = th.where(mask, th.zeros_like(self.elapsed), self.elapsed)
        return self._obs[self.state]

    def step(self, actions: th.Tensor) -> TorchStep:
        """Advance every copy by one action (an integer tensor of 0..5 per copy, on the device).

        Actions are not range-checked here (that would make every step wait for the device);
        :class:`~morality_gym.envs.torch_vector.TorchTrolleyVectorEnv` checks them by default.
        """
        k, nxt, self.elapsed, terminated, truncated = advance(self._next, self._done, self.state, self.elapsed,
                                                              actions.to(th.int64), self._limit)
        ended = terminated | truncated
        final_obs = th.where(ended.unsqueeze(1), self._obs[nxt], 0.0)
        self.state = th.where(ended, self._start, nxt)
        self.elapsed = th.where(ended, th.zeros_like(self.elapsed), self.elapsed)
        return TorchStep(self._obs[self.state], self._reward[k], terminated, truncated, self._events[k], k, final_obs)

    def utility(self, transition: th.Tensor) -> th.Tensor:
        """Utility values ``[n, 5]`` float64 (``vocab.UTILITIES`` order, 0 when absent) of the given transitions."""
        return self._utility[transition]

    def goal_reached(self, transition: th.Tensor) -> th.Tensor:
        """Whether each transition reached the landmark."""
        return self._goal[transition]

    def observations(self) -> th.Tensor:
        """The current observation of every copy."""
        return self._obs[self.state]

    def state_dict(self) -> dict[str, th.Tensor]:
        """What a step changes (each copy's state and steps taken), as CPU copies, for a checkpoint."""
        return {"state": self.state.cpu().clone(), "elapsed": self.elapsed.cpu().clone()}

    def load_state_dict(self, state: dict[str, th.Tensor]) -> None:
        """Restore :meth:`state_dict` (shapes must match this simulator's)."""
        for name in ("state", "elapsed"):
            value = th.as_tensor(state[name])
            if value.shape != getattr(self, name).shape:
                raise ValueError(f"simulator {name}: expected shape {tuple(getattr(self, name).shape)}, got {tuple(value.shape)}")
            setattr(self, name, value.to(device=self.device, dtype=th.int64).clone())
        self._check_range("state", (self.state < self._start) | (self.state >= self._end), self._start, self._end - 1)
        self._check_range("elapsed", (self.elapsed < 0) | (self.elapsed > self._limit), th.zeros_like(self.elapsed),
                          th.full_like(self.elapsed, self._limit))

    def _check_range(self, name: str, bad: th.Tensor, low: th.Tensor, high: th.Tensor) -> None:
        """Refuse a restored ``name`` outside each copy's ``low..high`` (a damaged checkpoint: a state
        outside its copy's block of the tables would step another env's graph, or past the tables)."""
        if bool(bad.any()):
            i = int(th.nonzero(bad)[0, 0])
            raise ValueError(f"simulator {name}: copy {i} holds {int(getattr(self, name)[i])}, "
                             f"outside {int(low[i])}..{int(high[i])}")

    def __repr__(self) -> str:
        return (
            f"<TorchTrolleySim {len(self.unique_env_ids)} env id(s) x{self.num_envs} on {self.device} "
            f"obs_dim={self.obs_dim} max_steps={self.max_steps}>"
        )


def _check_arguments(env_ids: Sequence[str], max_steps: int | None) -> None:
    if isinstance(env_ids, str) or not env_ids:
        raise ValueError("TorchTrolleySim needs a non-empty list of env ids, one per copy")
    if max_steps is not None and (isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 0):
        raise ValueError(f"max_steps must be a non-negative int or None, got {max_steps!r}")
