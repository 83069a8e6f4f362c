"""The fleet's networks: every run's MLPs with their parameters stacked along a run axis.

A network is a list of layers ``(W, b)`` with ``W: [K, in, out]`` and ``b: [K, 1, out]``, and a
forward pass over inputs ``[K, B, in]`` is one ``baddbmm`` per layer for all ``K`` runs. Hand-batched
matrix products were measured against ``torch.func.functional_call`` + ``vmap`` for the forward and
backward pass of one [64, 64] MLP on minibatches of 64 (one thread): about 2.2x faster at K = 12
and 2.4x at K = 36 (1.7 vs 3.9 ms and 7.6 vs 18.5 ms per call), so the fleet uses them.

Heads (the names are the SB3 policy's ``net_arch`` keys): ``pi`` is the actor (its hidden layers
and the action head), ``vf`` the reward critic (hidden layers and value head), ``cf`` the cost
critic of PPO-Lag and CPO. :meth:`FleetNetworks.load_run` and :meth:`FleetNetworks.export_run`
copy one run's weights from and to an SB3 policy, so a fleet starts from exactly the weights its
single-run learners would start from and hands back policies that evaluate, save and render as
any other.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence

import torch as th
from torch import nn

Layers = list[tuple[th.Tensor, th.Tensor]]
ACTIVATIONS: dict[str, Callable[[th.Tensor], th.Tensor]] = {"tanh": th.tanh, "relu": th.relu}


def policy_linears(policy: nn.Module, head: str) -> list[nn.Linear]:
    """The linear layers of one head of an SB3 (cost) actor-critic policy, input to output."""
    if head == "pi":
        modules: list[nn.Module] = [policy.mlp_extractor.policy_net, policy.action_net]  # type: ignore[attr-defined]
    elif head == "vf":
        modules = [policy.mlp_extractor.value_net, policy.value_net]  # type: ignore[attr-defined]
    elif head == "cf":
        modules = [policy.cost_net]  # type: ignore[attr-defined]
    else:
        raise ValueError(f"unknown head {head!r}; heads: pi, vf, cf")
    return [m for module in modules for m in module.modules() if isinstance(m, nn.Linear)]


def forward(layers: Layers, x: th.Tensor, activation: Callable[[th.Tensor], th.Tensor]) -> th.Tensor:
    """``[K, B, in] -> [K, B, out]``: each run's MLP on its own inputs."""
    h = x
    last = len(layers) - 1
    for i, (w, b) in enumerate(layers):
        h = th.baddbmm(b, h, w)
        if i < last:
            h = activation(h)
    return h


class FleetNetworks:
    """The stacked parameters of ``n_runs`` runs' heads (see the module docstring)."""

    def __init__(self, n_runs: int, obs_dim: int, hidden: Sequence[int], outputs: dict[str, int], activation: str) -> None:
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation {activation!r} is not one of {', '.join(ACTIVATIONS)}")
        self.n_runs = n_runs
        self.activation = ACTIVATIONS[activation]
        self.heads: dict[str, Layers] = {}
        for head, out in outputs.items():
            sizes = [obs_dim, *hidden, out]
            self.heads[head] = [
                (th.zeros(n_runs, i, o, requires_grad=True), th.zeros(n_runs, 1, o, requires_grad=True))
                for i, o in itertools.pairwise(sizes)
            ]

    def params(self, *heads: str) -> list[th.Tensor]:
        """The stacked tensors of the given heads, ``W0, b0, W1, b1, ...`` head after head."""
        return [t for head in heads for layer in self.heads[head] for t in layer]

    def __call__(self, head: str, x: th.Tensor, runs: th.Tensor | None = None) -> th.Tensor:
        """``head`` of every run on ``x`` (``[K, B, in]``), or of the runs ``runs`` (indices) on
        ``x`` of shape ``[len(runs), B, in]`` (gradients still reach the full stacked tensors)."""
        layers = self.heads[head]
        if runs is not None:
            layers = [(w[runs], b[runs]) for w, b in layers]
        return forward(layers, x, self.activation)

    @th.no_grad()
    def load_run(self, k: int, policy: nn.Module) -> None:
        """Copy an SB3 policy's weights into run ``k``'s slices."""
        for head, layers in self.heads.items():
            linears = policy_linears(policy, head)
            if len(linears) != len(layers):
                raise ValueError(f"head {head!r}: the policy has {len(linears)} layers, the fleet {len(layers)}")
            for (w, b), lin in zip(layers, linears):
                w[k] = lin.weight.T
                b[k, 0] = lin.bias

    @th.no_grad()
    def export_run(self, k: int, policy: nn.Module) -> None:
        """Copy run ``k``'s weights into an SB3 policy of the same architecture."""
        for head, layers in self.heads.items():
            for (w, b), lin in zip(layers, policy_linears(policy, head)):
                lin.weight.copy_(w[k].T)
                lin.bias.copy_(b[k, 0])
