"""One rollout of every run of a fleet: ``n_steps`` steps of all copies, as SB3's ``collect_rollouts``.

Each step: every run's actor, critic (and cost critic) on its copies' observations in one fused
network, an action sampled per run from that run's own noise, one step of the simulator, the
critics' bootstrap of truncated episodes, and the step written into the rollout buffers. Everything
a step touches stays on the fleet's device: the simulator may be the device's
(:class:`~.env.DeviceFleetEnv`), the buffers are tensors there, and nothing is read back on the host
until the rollout ends. Then the rollout goes to the host once for what the single runs compute
with numpy (GAE, the per-run advantage normalisation, the episode-cost bookkeeping), so those keep
their bits.

Truncated episodes are bootstrapped with the run's critics as SB3 does, in the same float precision
as the single learner (PPO adds a float32 product, the constrained learners a float64 one). On the
CPU the bootstrap is computed only in the steps where an episode was truncated (asking is free
there); on a GPU it is computed in every step, since asking would make each step wait for the device.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th

from morality_gym.baselines.fleet.drawn_env import DrawnFleetEnv
from morality_gym.baselines.fleet.env import DeviceFleetEnv, FleetEnv, FleetStep
from morality_gym.baselines.fleet.losses import Policy
from morality_gym.baselines.fleet.nets import FleetNetworks
from morality_gym.baselines.fleet.streams import RunStreams
from morality_gym.baselines.safe.functional import gae


@dataclass
class Rollout:
    """One rollout of all runs, flattened per run as SB3's buffers flatten it (env-major:
    transition ``e * n_steps + t`` of run ``k`` is step ``t`` of its env ``e``)."""

    obs: th.Tensor  # [K, M, obs_dim]
    actions: th.Tensor  # [K, M] int64
    values: th.Tensor  # [K, M]
    log_probs: th.Tensor  # [K, M]
    advantages: th.Tensor  # [K, M]
    returns: th.Tensor  # [K, M]
    cost_values: th.Tensor | None = None
    cost_advantages: th.Tensor | None = None
    cost_returns: th.Tensor | None = None
    #: The advantages before flattening, ``(T, K * E)`` numpy, for per-run normalisation on the host.
    raw: dict[str, np.ndarray] | None = None

    def gather(self, index: th.Tensor, *names: str, runs: th.Tensor | None = None) -> list[th.Tensor]:
        """The named fields at per-run positions ``index`` (``[K, B]``; with ``runs``, ``index`` has
        one row per listed run). One ``index_select`` over the runs' rows laid end to end (4x
        faster than indexing by run and position)."""
        rows = (th.arange(index.shape[0], device=index.device) if runs is None else runs).unsqueeze(1)
        fields = [getattr(self, n) for n in names]
        size = fields[0].shape[1]
        flat = (index + rows * size).reshape(-1)
        return [f.reshape(-1, *f.shape[2:]).index_select(0, flat).view(*index.shape, *f.shape[2:]) for f in fields]

    def minibatches(
        self, order: th.Tensor, batch_size: int, *names: str, runs: th.Tensor | None = None
    ) -> Iterator[tuple[th.Tensor, ...]]:
        """The named fields in each run's ``order`` (``[K, M]``, or one row per run of ``runs``),
        ``batch_size`` transitions at a time (the last batch may be shorter, as SB3's). Gathered
        once per call; the minibatches are contiguous blocks when ``batch_size`` divides ``M``
        (faster batched products)."""
        fields = self.gather(order, *names, runs=runs)
        size = order.shape[1]
        if size % batch_size == 0:
            blocks = [f.reshape(f.shape[0], size // batch_size, batch_size, *f.shape[2:]).movedim(1, 0).contiguous() for f in fields]
            for i in range(size // batch_size):
                yield tuple(b[i] for b in blocks)
            return
        for start in range(0, size, batch_size):
            yield tuple(f[:, start : start + batch_size] for f in fields)


def flatten_runs(arr: np.ndarray, n_runs: int) -> np.ndarray:
    """``[T, K * E, ...] -> [K, E * T, ...]`` in SB3's env-major order (``swap_and_flatten`` per run)."""
    t, n = arr.shape[:2]
    e = n // n_runs
    out = arr.reshape(t, n_runs, e, *arr.shape[2:]).swapaxes(0, 1).swapaxes(1, 2)
    return np.ascontiguousarray(out).reshape(n_runs, e * t, *arr.shape[2:])


def flatten_runs_tensor(t: th.Tensor, n_runs: int) -> th.Tensor:
    """:func:`flatten_runs` of a tensor, on its device."""
    steps, n = t.shape[:2]
    e = n // n_runs
    return t.reshape(steps, n_runs, e, *t.shape[2:]).transpose(0, 1).transpose(1, 2).reshape(n_runs, e * steps, *t.shape[2:])


@dataclass(frozen=True)
class RolloutSettings:
    """What a rollout reads of the learner (the same for every run): SB3's model attributes."""

    n_steps: int
    gamma: float
    gae_lambda: float
    cost_aware: bool = False
    cost_gamma: float = 0.0
    cost_gae_lambda: float = 0.0
    reset_each_rollout: bool = False
    ep_cost_window: int = 1

    @classmethod
    def of(cls, model: Any, cost_aware: bool) -> RolloutSettings:
        """The settings of an SB3 (cost) on-policy model."""
        return cls(
            n_steps=int(model.n_steps),
            gamma=float(model.gamma),
            gae_lambda=float(model.gae_lambda),
            cost_aware=cost_aware,
            cost_gamma=float(getattr(model, "cost_gamma", 0.0)),
            cost_gae_lambda=float(getattr(model, "cost_gae_lambda", 0.0)),
            reset_each_rollout=bool(getattr(model, "reset_envs_each_rollout", False)),
            ep_cost_window=int(getattr(model, "ep_cost_window", 1)),
        )


class _Buffers:
    """A rollout's per-step tensors, ``[T, N, ...]`` on the device."""

    def __init__(self, t_steps: int, n: int, obs_dim: int, cost_aware: bool, device: th.device) -> None:
        def zeros(*shape: int, dtype: th.dtype = th.float32) -> th.Tensor:
            return th.zeros(*shape, dtype=dtype, device=device)

        self.obs = zeros(t_steps, n, obs_dim)
        self.actions = zeros(t_steps, n, dtype=th.int64)
        self.rewards = zeros(t_steps, n)
        self.starts = zeros(t_steps, n)
        self.values = zeros(t_steps, n)
        self.log_probs = zeros(t_steps, n)
        self.dones = zeros(t_steps, n, dtype=th.bool)
        if cost_aware:
            self.step_costs = zeros(t_steps, n)  # before the bootstrap: the episode costs' terms
            self.costs = zeros(t_steps, n)
            self.cost_values = zeros(t_steps, n)


class RolloutCollector:
    """Steps a fleet's copies and keeps what carries over from one rollout to the next: the last
    observations and episode starts, and each run's episode-cost record (``CostOnPolicyAlgorithm``'s
    ``_running_ep_cost`` and ``ep_cost_buffer``, per run)."""

    def __init__(self, env: FleetEnv | DeviceFleetEnv | DrawnFleetEnv, n_runs: int, n_envs: int, settings: RolloutSettings, device: th.device) -> None:
        self.env = env
        self.n_runs = n_runs
        self.n_envs = n_envs
        self.settings = settings
        self.device = device
        #: Compute the truncation bootstrap in every step (no host sync) rather than when one is due.
        self.dense_bootstrap = device.type != "cpu"
        self.start()

    def start(self) -> None:
        """The state of a run at step 0: every copy reset, no episode cost recorded yet."""
        n = self.n_runs * self.n_envs
        self.last_obs = self.env.reset()
        self.last_starts = th.ones(n, dtype=th.bool, device=self.device)
        self.running_ep_cost = np.zeros(n, dtype=np.float64)
        self.ep_cost_buffers: list[deque[float]] = [deque(maxlen=self.settings.ep_cost_window) for _ in range(self.n_runs)]

    # ------------------------------------------------------------------ one rollout
    def collect(self, nets: FleetNetworks, heads: Sequence[str], streams: RunStreams, on_step: Callable[[], None]) -> Rollout:
        """One rollout of every run (``on_step`` is called after each simulator step, as SB3's
        callbacks are: the trainer counts steps and evaluates there)."""
        s, k_runs, e = self.settings, self.n_runs, self.n_envs
        n, d = k_runs * e, self.env.obs_dim
        if s.cost_aware and s.reset_each_rollout:
            self._reset_runs_for_rollout()
        buf = _Buffers(s.n_steps, n, d, s.cost_aware, self.device)
        noise = streams.action_noise((s.n_steps, e, 6), self.device)
        policy_nets = nets.fused(heads)
        for t in range(s.n_steps):
            with th.no_grad():
                actions, values, log_probs, cost_values = self._policy_step(policy_nets, noise[:, t])
            step = self.env.step(actions.reshape(n))
            on_step()
            rewards, costs = self._bootstrap(nets, step)
            buf.obs[t], buf.actions[t], buf.rewards[t] = self.last_obs, actions.reshape(n), rewards
            buf.starts[t], buf.values[t], buf.log_probs[t] = self.last_starts, values.reshape(n), log_probs.reshape(n)
            buf.dones[t] = step.dones
            if s.cost_aware:
                buf.step_costs[t], buf.costs[t] = step.costs.float(), costs
                buf.cost_values[t] = cost_values.reshape(n)  # type: ignore[union-attr]
            self.last_obs, self.last_starts = step.obs, step.dones
        return self._finish(nets, buf)

    def _policy_step(self, policy_nets: Callable[[th.Tensor], list[th.Tensor]], noise: th.Tensor) -> tuple[Any, ...]:
        """Actions (sampled per run from its own noise of this step, ``[K, E, 6]``), values,
        log-probs and cost values at the last observations."""
        outputs = policy_nets(self.last_obs.view(self.n_runs, self.n_envs, -1))
        policy = Policy.of(outputs[0])
        actions = (policy.p / noise.transpose(1, 2)).argmax(dim=1)
        cost_values = outputs[2][:, 0] if self.settings.cost_aware else None
        return actions, outputs[1][:, 0], policy.log_prob(actions), cost_values

    def _bootstrap(self, nets: FleetNetworks, step: FleetStep) -> tuple[th.Tensor, th.Tensor | None]:
        """The step's rewards (and float32 costs) with ``gamma * V(final obs)`` added where an episode
        was truncated, in the single learner's precision."""
        s = self.settings
        rewards, costs = step.rewards, (step.costs.float() if s.cost_aware else None)
        if step.final_obs is None or not (self.dense_bootstrap or bool(step.truncated.any())):
            return rewards, costs
        bootstrap = step.truncated
        with th.no_grad():
            final = step.final_obs.view(self.n_runs, self.n_envs, -1)
            v_end = nets("vf", final).reshape(-1)
            if not s.cost_aware:
                # rewards[i] += gamma * V (a float32 tensor): float32 throughout.
                return th.where(bootstrap, rewards + s.gamma * v_end, rewards), None
            vc_end = nets("cf", final).reshape(-1)
        # rewards[i] += gamma * V.item(): a float64 product added to a float32 (NEP 50).
        rewards = th.where(bootstrap, rewards + (s.gamma * v_end.double()).float(), rewards)
        costs = th.where(bootstrap, costs + (s.cost_gamma * vc_end.double()).float(), costs)  # type: ignore[operator]
        return rewards, costs

    def _finish(self, nets: FleetNetworks, buf: _Buffers) -> Rollout:
        """GAE (and the episode-cost record) on the host, then the rollout flattened per run."""
        s, k_runs = self.settings, self.n_runs
        with th.no_grad():
            last = self.last_obs.view(k_runs, self.n_envs, -1)
            last_v = nets("vf", last).reshape(-1).cpu().numpy()
            last_vc = nets("cf", last).reshape(-1).cpu().numpy() if s.cost_aware else None
        host = {name: getattr(buf, name).cpu().numpy() for name in ("rewards", "values", "starts")}
        last_dones = self.last_starts.cpu().numpy()
        adv, ret = gae(host["rewards"], host["values"], host["starts"], last_v, last_dones, s.gamma, s.gae_lambda)
        fields = {"values": host["values"], "advantages": adv, "returns": ret}
        raw = None
        if s.cost_aware:
            cost_values = buf.cost_values.cpu().numpy()
            cadv, cret = gae(buf.costs.cpu().numpy(), cost_values, host["starts"], last_vc, last_dones, s.cost_gamma, s.cost_gae_lambda)  # type: ignore[arg-type]
            fields.update(cost_values=cost_values, cost_advantages=cadv, cost_returns=cret)
            raw = {"advantages": adv, "cost_advantages": cadv}  # (T, K*E), for per-run normalisation
            self._record_episode_costs(buf.step_costs.cpu().numpy(), buf.dones.cpu().numpy())
        tensors = {name: th.from_numpy(flatten_runs(arr, k_runs)).to(self.device) for name, arr in fields.items()}
        on_device = {name: flatten_runs_tensor(getattr(buf, name), k_runs) for name in ("obs", "actions", "log_probs")}
        return Rollout(**on_device, **tensors, raw=raw)

    # ------------------------------------------------------------------ episode costs
    def _reset_runs_for_rollout(self) -> None:
        """``reset_envs_each_rollout`` per run: each run whose envs have not all just started an
        episode is reset, and its partial episode costs dropped (as the single learner)."""
        cut = ~self.last_starts.view(self.n_runs, self.n_envs).all(dim=1)
        if not bool(cut.any()):
            return
        copies = self.env.copies_of(cut)
        obs = self.env.reset(cut)
        self.last_obs = th.where(copies.unsqueeze(1), obs, self.last_obs)
        self.last_starts = self.last_starts | copies
        self.running_ep_cost[copies.cpu().numpy()] = 0.0

    def _record_episode_costs(self, step_costs: np.ndarray, dones: np.ndarray) -> None:
        """Replay the rollout's ``(T, N)`` float32 step costs and episode ends into each run's
        record, step by step, as the single learner adds them after each step (float64 sums)."""
        for costs, ended in zip(step_costs, dones):
            self.running_ep_cost += costs
            for i in np.flatnonzero(ended):
                self.ep_cost_buffers[i // self.n_envs].append(float(self.running_ep_cost[i]))
                self.running_ep_cost[i] = 0.0

    def mean_episode_costs(self) -> np.ndarray:
        """``J_c`` of every run (``CostOnPolicyAlgorithm.mean_episode_cost`` per run), ``[K]`` float64."""
        running = self.running_ep_cost.reshape(self.n_runs, self.n_envs)
        return np.array([float(np.mean(buf)) if buf else float(np.mean(running[k])) for k, buf in enumerate(self.ep_cost_buffers)])

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict[str, Any]:
        """The simulator and cost memory, the last observations and episode starts, and the
        episode-cost record (as CPU tensors and plain numbers)."""
        return {
            "env": _tensors(self.env.state_dict()),
            "last_obs": self.last_obs.cpu().clone(),
            "last_starts": self.last_starts.cpu().clone(),
            "running_ep_cost": th.from_numpy(self.running_ep_cost.copy()),
            "ep_cost_buffers": [[float(c) for c in buf] for buf in self.ep_cost_buffers],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.env.load_state_dict(state["env"])
        self.last_obs = _like(self.last_obs, state["last_obs"], "last observations")
        self.last_starts = _like(self.last_starts, state["last_starts"], "episode starts")
        running = state["running_ep_cost"].numpy()
        if running.shape != self.running_ep_cost.shape:
            raise ValueError(f"running episode costs: expected shape {self.running_ep_cost.shape}, got {running.shape}")
        self.running_ep_cost = running.astype(np.float64, copy=True)
        if len(state["ep_cost_buffers"]) != self.n_runs:
            raise ValueError(f"episode-cost records: expected {self.n_runs}, got {len(state['ep_cost_buffers'])}")
        window = self.settings.ep_cost_window
        self.ep_cost_buffers = [deque((float(c) for c in costs), maxlen=window) for costs in state["ep_cost_buffers"]]


def _like(current: th.Tensor, value: th.Tensor, what: str) -> th.Tensor:
    """``value`` on ``current``'s device with its dtype, refusing another shape."""
    if tuple(value.shape) != tuple(current.shape):
        raise ValueError(f"{what}: expected shape {tuple(current.shape)}, got {tuple(value.shape)}")
    return value.to(device=current.device, dtype=current.dtype).clone()


def _tensors(value: Any) -> Any:
    """``value`` with every numpy array as a tensor (unsigned 32-bit as int64: exact, and a type
    ``torch.save`` handles everywhere); readers cast back to their arrays' dtypes."""
    if isinstance(value, dict):
        return {k: _tensors(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_tensors(v) for v in value]
    if isinstance(value, np.ndarray):
        arr = value.astype(np.int64) if value.dtype == np.uint32 else value
        return th.from_numpy(np.ascontiguousarray(arr).copy())
    return value
