"""The fleet's networks: every run's MLPs with their parameters stacked along a run axis.

A network is a list of layers ``(W, b)`` with ``W: [K, out, in]`` and ``b: [K, out, 1]`` (each
run's slice in PyTorch's own layout of a ``Linear``), and a forward pass is one ``baddbmm`` per
layer for all ``K`` runs. Activations are kept *feature-major*, ``[K, features, B]``: a layer is
``W @ h + b``. Hand-batched matrix products were measured against ``torch.func.functional_call`` +
``vmap`` for the forward and backward pass of one [64, 64] MLP on minibatches of 64 (one thread):
about 2.2x faster at K = 12 and 2.4x at K = 36, so the fleet uses them. Feature-major because MKL's
batched products with a narrow output (the 6 logits, the single value) are slow the other way
round: ``[12, 64, 64] @ [12, 64, 6]`` took 40 us, ``[12, 6, 64] @ [12, 64, 64]`` 10 us, and the
value head 27 us against 4 us; the square hidden layers cost the same either way. (The same holds
the other way round for a rollout step's 8 states, where a hidden layer takes 35 us feature-major
and 12 us state-major: :meth:`FleetNetworks.trace` picks the orientation whose product has the
wider output.) Feature-major also puts a policy's actions on axis 1, where ``log_softmax`` is fast
(:mod:`.losses`).

Gradients are written out by hand (:meth:`FleetNetworks.backward`, and the forward-mode
:meth:`FleetNetworks.jvp` for CPO's Fisher-vector products) rather than taken by autograd: the
learners' losses are a few lines whose derivative with respect to the network's output is known in
closed form, and back-propagating that through a stack of affine layers is two matrix products per
layer, with no graph to record.

``tanh`` is computed as ``2 sigmoid(2z) - 1``: the same function, within 2.4e-7 of ``torch.tanh``
(both round float32 results), and 4.5x faster here: PyTorch's vectorised ``tanh`` is an accurate
but slow polynomial (95 us for a [12, 64, 64] tensor on this machine, 21 us the sigmoid way), and it
was the largest single item of a fleet's update. The fleet therefore matches its single runs to
float tolerance, as batched products already do.

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
from dataclasses import dataclass

import torch as th
from torch import nn

Layers = list[tuple[th.Tensor, th.Tensor]]
#: Which runs a call computes: all (None), a contiguous block (a slice: views, no copy) or a
#: list of run indices (a tensor: the weights are gathered).
Runs = slice | th.Tensor | None


def tanh_(z: th.Tensor) -> th.Tensor:
    """``tanh(z)`` in place on ``z`` (a fresh buffer), as ``2 sigmoid(2 z) - 1`` (see the module docstring)."""
    return z.mul_(2.0).sigmoid_().mul_(2.0).sub_(1.0)


def relu_(z: th.Tensor) -> th.Tensor:
    return z.clamp_(min=0.0)


def tanh_backward_(dh: th.Tensor, h: th.Tensor) -> th.Tensor:
    """``dh * tanh'`` in place on ``dh``, from the activation ``h = tanh(z)``: ``1 - h^2``."""
    return dh.mul_(th.addcmul(h.new_ones(()), h, h, value=-1.0))


def relu_backward_(dh: th.Tensor, h: th.Tensor) -> th.Tensor:
    return dh.mul_(h > 0)


#: name -> (in-place activation, in-place product of an upstream gradient with its derivative
#: given the activation's output)
ACTIVATIONS: dict[str, tuple[Callable[[th.Tensor], th.Tensor], Callable[[th.Tensor, th.Tensor], th.Tensor]]] = {
    "tanh": (tanh_, tanh_backward_),
    "relu": (relu_, relu_backward_),
}


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


@dataclass
class Trace:
    """What a forward pass keeps for the backward one: the layers it used (one row per computed
    run), each layer's input, feature-major (``[R, in, B]``: the observations, then the hidden
    activations), and the output of the last layer (``[R, out, B]``: logits or values)."""

    layers: Layers
    inputs: list[th.Tensor]
    out: th.Tensor


def trace_layers(layers: Layers, x: th.Tensor, act: Callable[[th.Tensor], th.Tensor]) -> Trace:
    """The forward pass of :meth:`FleetNetworks.trace` through given ``layers`` (one row per
    computed run) with the in-place activation ``act``: a plain function of tensors, so that the
    compiled update steps (:mod:`.compiled`) run the very arithmetic the eager ones do."""
    h = x.transpose(1, 2)
    inputs = [h]
    last = len(layers) - 1
    for i, (w, b) in enumerate(layers):
        if h.shape[2] >= w.shape[1]:
            h = th.baddbmm(b, w, h)
        else:  # fewer states than outputs (a rollout step's 8 envs): the state-major product is the fast one
            h = th.baddbmm(b.transpose(1, 2), h.transpose(1, 2), w.transpose(1, 2)).transpose(1, 2)
        if i < last:
            h = act(h)
            inputs.append(h)
    return Trace(layers, inputs, h)


def backward_layers(tr: Trace, dout: th.Tensor, act_backward: Callable[[th.Tensor, th.Tensor], th.Tensor],
                    narrow_transposed: bool = True) -> list[th.Tensor]:
    """:meth:`FleetNetworks.backward` as a plain function of tensors (see :func:`trace_layers`).

    ``narrow_transposed``: a layer with a narrow input (the observations) gets its weight gradient
    from the transposed product (the faster product eagerly), as a transposed view; False takes
    the direct product, whose result is laid out as the weights are (what a compiled step wants:
    :mod:`.compiled`)."""
    n = len(tr.layers)
    grads: list[th.Tensor] = [dout.new_empty(0)] * (2 * n)  # placeholders, each set below
    dz = dout
    for i in range(n - 1, -1, -1):
        w, _ = tr.layers[i]
        h = tr.inputs[i]
        if h.shape[1] >= dz.shape[1] or not narrow_transposed:
            grads[2 * i] = th.matmul(dz, h.transpose(1, 2))
        else:  # a narrow input (the observations): the transposed product has the wider output
            grads[2 * i] = th.matmul(h, dz.transpose(1, 2)).transpose(1, 2)
        grads[2 * i + 1] = dz.sum(dim=2, keepdim=True)
        if i > 0:
            dz = act_backward(th.matmul(w.transpose(1, 2), dz), h)
    return grads


class FleetNetworks:
    """The stacked parameters of ``n_runs`` runs' heads (see the module docstring)."""

    def __init__(
        self, n_runs: int, obs_dim: int, hidden: Sequence[int], outputs: dict[str, int], activation: str,
        device: th.device | str = "cpu", in_dims: Sequence[int] | None = None,
    ) -> None:
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation {activation!r} is not one of {', '.join(ACTIVATIONS)}")
        self.n_runs = n_runs
        #: Each run's own observation width: a fleet that mixes scenarios pads observations to the
        #: widest (``obs_dim``), and run ``k``'s first layers keep zero weights beyond its
        #: ``in_dims[k]`` columns (its zero inputs there leave those weights' gradients at exactly 0).
        self.in_dims = [obs_dim] * n_runs if in_dims is None else [int(d) for d in in_dims]
        if len(self.in_dims) != n_runs or max(self.in_dims) > obs_dim:
            raise ValueError(f"in_dims {self.in_dims} do not fit {n_runs} runs of width at most {obs_dim}")
        self.activation_name = activation
        self._act, self._act_backward = ACTIVATIONS[activation]
        self.heads: dict[str, Layers] = {}
        for head, out in outputs.items():
            sizes = [obs_dim, *hidden, out]
            self.heads[head] = [
                (th.zeros(n_runs, o, i, device=device), th.zeros(n_runs, o, 1, device=device)) for i, o in itertools.pairwise(sizes)
            ]

    def params(self, *heads: str) -> list[th.Tensor]:
        """The stacked tensors of the given heads, ``W0, b0, W1, b1, ...`` head after head."""
        return [t for head in heads for layer in self.heads[head] for t in layer]

    def padded(self, *heads: str) -> dict[int, list[int]]:
        """For :meth:`params` ``(*heads)``: the index of every first-layer weight and each run's own
        width of it, when runs differ in width (``{}`` otherwise: nothing is padded)."""
        if len(set(self.in_dims)) < 2:
            return {}
        out, i = {}, 0
        for head in heads:
            out[i] = list(self.in_dims)
            i += 2 * len(self.heads[head])
        return out

    def layers(self, head: str, runs: Runs = None) -> Layers:
        """``head``'s layers for ``runs`` (views for ``None`` and slices, gathered copies for indices)."""
        layers = self.heads[head]
        if runs is None:
            return layers
        return [(w[runs], b[runs]) for w, b in layers]

    def trace(self, head: str, x: th.Tensor, runs: Runs = None) -> Trace:
        """``head`` of the given runs on observations ``x`` (``[R, B, in]``, state-major as the
        rollout stores them), keeping what :meth:`backward` needs."""
        return trace_layers(self.layers(head, runs), x, self._act)

    @th.no_grad()
    def __call__(self, head: str, x: th.Tensor, runs: Runs = None) -> th.Tensor:
        """``[R, out, B]``: ``head`` of every run on ``x`` (``[K, B, in]``), or of ``runs`` on ``[R, B, in]``."""
        return self.trace(head, x, runs).out

    def backward(self, tr: Trace, dout: th.Tensor) -> list[th.Tensor]:
        """The gradients ``[dW0, db0, dW1, db1, ...]`` of ``sum(dout * tr.out)``, i.e. of any loss
        whose gradient with respect to the head's output is ``dout`` (``[R', out, B]``; ``R'`` may
        exceed the trace's ``R = 1`` to back-propagate several cotangents through one run)."""
        return backward_layers(tr, dout, self._act_backward)

    def jvp(self, tr: Trace, tangents: Sequence[th.Tensor]) -> th.Tensor:
        """The directional derivative of ``tr.out`` along parameter tangents ``[dW0, db0, ...]``
        (each ``[R', out, in]`` / ``[R', out, 1]``): forward-mode through the traced layers."""
        dz: th.Tensor | None = None
        n = len(tr.layers)
        for i, (w, _) in enumerate(tr.layers):
            dw, db = tangents[2 * i], tangents[2 * i + 1]
            step = th.matmul(dw, tr.inputs[i]).add_(db)
            dz = step if dz is None else step.add_(th.matmul(w, dz))
            if i < n - 1:
                dz = self._act_backward(dz, tr.inputs[i + 1])
        assert dz is not None
        return dz

    def fused(self, heads: Sequence[str]) -> Callable[[th.Tensor], list[th.Tensor]]:
        """The given heads, at their current weights, as one network for inference
        (:class:`FusedHeads`; heads without a hidden layer are evaluated one by one)."""
        if len(self.heads[heads[0]]) < 2:
            return lambda x: [self(head, x) for head in heads]
        return FusedHeads(self, heads)

    def state_dict(self) -> dict[str, list[th.Tensor]]:
        """Every head's tensors (``W0, b0, W1, b1, ...``), as CPU copies, for a checkpoint."""
        return {head: [t.detach().cpu().clone() for layer in layers for t in layer] for head, layers in self.heads.items()}

    @th.no_grad()
    def load_state_dict(self, state: dict[str, list[th.Tensor]]) -> None:
        """Copy :meth:`state_dict`'s tensors *in place* (the parameters are views into their
        optimisers' flat buffers), refusing layers of another shape."""
        for head, layers in self.heads.items():
            saved = state[head]
            tensors = [t for layer in layers for t in layer]
            if len(saved) != len(tensors) or any(a.shape != b.shape for a, b in zip(saved, tensors)):
                raise ValueError(f"head {head!r}: the saved layers do not fit the network")
            for t, value in zip(tensors, saved):
                t.copy_(value)

    @th.no_grad()
    def load_run(self, k: int, policy: nn.Module) -> None:
        """Copy an SB3 policy's weights into run ``k``'s slices."""
        for head, layers in self.heads.items():
            linears = policy_linears(policy, head)
            if len(linears) != len(layers):
                raise ValueError(f"head {head!r}: the policy has {len(linears)} layers, the fleet {len(layers)}")
            for (w, b), lin in zip(layers, linears):
                w[k, :, : lin.weight.shape[1]] = lin.weight  # the first layer's padded columns stay 0
                b[k, :, 0] = lin.bias

    @th.no_grad()
    def export_run(self, k: int, policy: nn.Module) -> None:
        """Copy run ``k``'s weights into an SB3 policy of the same architecture."""
        for head, layers in self.heads.items():
            for (w, b), lin in zip(layers, policy_linears(policy, head)):
                lin.weight.copy_(w[k, :, : lin.weight.shape[1]])
                lin.bias.copy_(b[k, :, 0])


class FusedHeads:
    """Several heads of every run evaluated on the same observations as one network, for a
    rollout's steps (the weights do not change during a rollout, so they are arranged once).

    A rollout step evaluates the actor and one or two critics on ``K x 8`` observations: tiny
    products, each paying a fixed overhead. Here the heads' first layers are one product (their
    weights side by side), every further layer one product over ``heads x K`` stacked networks
    (outputs zero-padded to the widest head), so a step costs the operations of one head. The
    numbers are the same products as :meth:`FleetNetworks.trace`'s, batched differently (float
    rounding only). State-major throughout (few states, wide layers).
    """

    def __init__(self, nets: FleetNetworks, heads: Sequence[str]) -> None:
        self.heads = list(heads)
        self.n_runs = nets.n_runs
        self._act = nets._act
        stacks = [nets.heads[h] for h in self.heads]
        depth = len(stacks[0])
        if depth < 2 or any(len(layers) != depth for layers in stacks):
            raise ValueError("fused heads need the same hidden layers (at least one)")
        self.outputs = [layers[-1][0].shape[1] for layers in stacks]
        self.hidden = stacks[0][0][0].shape[1]
        with th.no_grad():
            # layer 0 side by side: [K, in, H * hidden]
            self.w0 = th.cat([layers[0][0] for layers in stacks], dim=1).transpose(1, 2).contiguous()
            self.b0 = th.cat([layers[0][1] for layers in stacks], dim=1).transpose(1, 2).contiguous()
            # further layers stacked head-major: [H * K, in, out] (the last zero-padded to the widest head)
            width = max(self.outputs)
            self.stacked: Layers = []
            for i in range(1, depth):
                ws, bs = [], []
                for layers in stacks:
                    w, b = layers[i][0].transpose(1, 2), layers[i][1].transpose(1, 2)
                    pad = width - w.shape[2] if i == depth - 1 else 0
                    ws.append(th.nn.functional.pad(w, (0, pad)))
                    bs.append(th.nn.functional.pad(b, (0, pad)))
                self.stacked.append((th.cat(ws).contiguous(), th.cat(bs).contiguous()))

    @th.no_grad()
    def __call__(self, x: th.Tensor) -> list[th.Tensor]:
        """Each head's output on ``x`` (``[K, B, in]``), feature-major as :meth:`FleetNetworks.__call__`'s
        (``[K, out, B]``, views)."""
        k, n_heads = self.n_runs, len(self.heads)
        batch = x.shape[1]
        h = self._act(th.baddbmm(self.b0, x, self.w0))  # [K, B, H * hidden]
        h = h.view(k, batch, n_heads, self.hidden).permute(2, 0, 1, 3).reshape(n_heads * k, batch, self.hidden)
        last = len(self.stacked) - 1
        for i, (w, b) in enumerate(self.stacked):
            h = th.baddbmm(b, h, w)
            if i < last:
                h = self._act(h)
        return [h[j * k : (j + 1) * k, :, :out].transpose(1, 2) for j, out in enumerate(self.outputs)]
