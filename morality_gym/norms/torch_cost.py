"""The step-wise moral cost of copies on a torch device (evaluation spec section 5).

:class:`~morality_gym.norms.cost.StackedCost` computes every copy's cost with numpy on the host, each
copy by its own chain and env id; :class:`TorchCost` does the same arithmetic with tensors on the
device of a :class:`~morality_gym.envs.torch_sim.TorchTrolleySim`, so a training loop on a GPU never
brings a step's events to the host. It is built *from* a ``StackedCost`` (which is built from one
:class:`~morality_gym.norms.cost.VectorCost` per group), so the weights, bounds and terms are worked
out in one place, and it sums the same float64 terms in the same order: a copy's cost has the same
bits as on the host (tested on every built-in chain and its envs).

Prescribed norms (no built-in chain has one) need per-episode totals, which ``StackedCost`` does not
stack either; a chain with one is refused with its name.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch as th

from morality_gym.envs.torch_sim import utility_present
from morality_gym.norms.cost import StackedCost, VectorCost
from morality_gym.norms.metric import BoundChain
from morality_gym.norms.reward_cost import RewardCostSpec


class TorchCost:
    """Per-copy step-wise costs on ``device``; the cost memory (first violations) is per copy."""

    def __init__(self, stacked: StackedCost, device: str | th.device = "cpu") -> None:
        dev = th.device(device)
        self.device = dev

        def tensor(a: np.ndarray, dtype: th.dtype | None = None) -> th.Tensor:
            return th.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=dev)

        self.n_copies = stacked.n_copies
        self.event_mask = tensor(stacked.event_mask, th.int64)
        self.event_bits = tensor(stacked.event_bits, th.int64)
        self.event_weights = tensor(stacked.event_weights)
        self.utility_column = tensor(stacked.utility_column, th.int64)
        self.utility_weights = tensor(stacked.utility_weights)
        self.utility_lo = tensor(stacked.utility_lo)
        self.utility_span = tensor(stacked.utility_span)
        self.utility_degenerate = tensor(stacked.utility_degenerate)
        self.utility_living = tensor(stacked.utility_living)
        self.scale = tensor(stacked.scale)
        self.weight_sum = tensor(stacked.weight_sum)
        self.per_episode = tensor(stacked.per_episode)
        self.normalise = tensor(stacked.normalise)
        self.charged = tensor(stacked.charged, th.int64)

    @classmethod
    def for_copies(cls, bounds: Sequence[BoundChain], reward_cost: RewardCostSpec, device: str | th.device = "cpu") -> TorchCost:
        """The cost of copy ``i`` by ``bounds[i]`` (its chain bound to its env id), as the learner's
        ``reward_cost`` sees it (mode, scale, reset policy). Copies sharing (env id, chain, beta) share
        one :class:`VectorCost` definition, as the host fleet's groups do."""
        groups: dict[tuple[str, str, float], list[int]] = {}
        for i, b in enumerate(bounds):
            groups.setdefault((b.env_id, b.chain.name, float(b.beta)), []).append(i)
        costs = []
        for copies in groups.values():
            b = bounds[copies[0]]
            cost = VectorCost(b, len(copies), mode=reward_cost.cost_mode, scale=reward_cost.cost_scale, reset=reward_cost.cost_reset)
            costs.append((np.asarray(copies), cost))
        stacked = StackedCost.of_groups(costs, len(bounds))
        if stacked is None:
            named = sorted({n.name for _, c in costs for n in c.bound.chain.norms if not n.prohibited})
            raise ValueError(
                f"prescribed norm(s) {', '.join(named)}: the device cost handles prohibited norms only; "
                "use the host simulator and its cost (morality_gym.norms.wrappers.VecMoralityWrapper) for such a chain"
            )
        return cls(stacked, device)

    def reset(self, mask: th.Tensor | None = None) -> None:
        """Forget first violations (all copies, or where the bool tensor ``mask`` is true)."""
        self.charged = th.zeros_like(self.charged) if mask is None else th.where(mask, 0, self.charged)

    def __call__(self, events: th.Tensor, utility: th.Tensor, ended: th.Tensor) -> th.Tensor:
        """float64 costs of one step of every copy (``StackedCost.__call__``, term by term)."""
        type_present, living_present = utility_present(events)
        cost = th.zeros(self.n_copies, dtype=th.float64, device=self.device)
        new = events & self.event_mask & ~self.charged
        for bits, weights in zip(self.event_bits, self.event_weights):
            cost += weights * ((new >> bits) & 1)
        self.charged = self.charged | new
        for j in range(len(self.utility_weights)):
            x = utility.gather(1, self.utility_column[j].unsqueeze(1)).squeeze(1)
            x = th.where(self.normalise, (x - self.utility_lo[j]) / self.utility_span[j], x)
            x = th.where(self.utility_degenerate[j] & self.normalise, 0.0, x)
            shown = th.where(self.utility_living[j], living_present, type_present)
            cost += th.where(shown, self.utility_weights[j] * x, 0.0)
        self.charged = th.where(ended & self.per_episode, 0, self.charged)
        return self.scale * cost / self.weight_sum

    def state_dict(self) -> dict[str, th.Tensor]:
        """The cost memory (first violations charged per copy), as a CPU copy."""
        return {"charged": self.charged.cpu().clone()}

    def load_state_dict(self, state: dict[str, th.Tensor]) -> None:
        value = th.as_tensor(state["charged"])
        if value.shape != self.charged.shape:
            raise ValueError(f"cost memory charged: expected shape {tuple(self.charged.shape)}, got {tuple(value.shape)}")
        self.charged = value.to(device=self.device, dtype=th.int64).clone()
