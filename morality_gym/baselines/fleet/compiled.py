"""The fleet's minibatch update steps as whole functions of tensors, compiled by ``torch.compile``.

Why: on the CPU a fleet's update is hundreds of minibatch steps per rollout, each a few dozen
small kernels over ``[K, 64, 64]``-sized tensors (forward, hand-written backward, clipping, Adam),
and half of its time is Python and dispatch rather than arithmetic; on a GPU the same steps are
launch-bound. Written as one function of tensors, with static shapes and no read of a value on the
host, each step compiles (``fullgraph=True``) into a few fused kernels, and on CUDA into a CUDA
graph (``mode="reduce-overhead"``).

What a step is, per learner:

* :func:`ppo_step`: PPO's and PPO-Shaped's minibatch (:meth:`.ppo.FleetPPO._train`'s loop body);
* :func:`lag_step`: PPO-Lag's minibatch (actor and both critics, :meth:`.ppo_lag.FleetPPOLag._one_pass`);
* :func:`critic_step`: the critics' regression minibatch of PPO-Lag and CPO (CPO's ten critic
  passes per rollout; its actor step, conjugate gradients and line search, stays eager).

The arithmetic is the eager path's (the same :mod:`.losses` and the same
:func:`~.nets.trace_layers`/:func:`~.nets.backward_layers`), with four differences that change
only float rounding: Adam is written out as tensor arithmetic inside the graph (:func:`adam_`; the
eager path calls PyTorch's fused kernel on row views, which a graph does not take whole; see
:func:`adam_in_graph`), its per-run rates handed in by the caller (:func:`adam_rates`), the first
layer's weight gradient is the direct product rather than the transposed one (:func:`_backward`),
each run's gradient norm is taken over its whole rows (padding columns of
a mixed fleet hold exact zeros), and runs masked out of a step
(PPO-Lag's KL early stop) are still computed and then left unchanged (``where``), so that every
step has the same shapes. The compiled engine therefore does not rerun a release bit for bit: the
eager engine (``update=eager``) does, and is the default (:data:`DEFAULT_UPDATE_ENGINE`: measured in
``BENCHMARKS.md``, "Fleet update engines on a whole Table 1 row", the compiled engine gains 0.9-1.2x
on the CPU at a sweep's fleet size, where the batched products dominate).

Shapes: the run axis, the observation width and the minibatch are marked dynamic, so one compiled
graph serves every fleet of a learner (any size, any scenario mix) and a sweep compiles once per
learner, not per fleet. Compiled code is cached on disk (:func:`compile_cache_dir`): a second
process reuses the first one's kernels.

Inductor's CPU backend writes C++ and needs a C++ compiler at run time (``g++``, installed by
``make system-deps``). Without one the compiled engine says so once on stderr and runs the eager
step functions instead (:func:`compiler_missing`).
"""

from __future__ import annotations

import functools
import os
import shutil
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import torch as th

from morality_gym.baselines.fleet.losses import Policy, mse
from morality_gym.baselines.fleet.nets import ACTIVATIONS, Layers, Trace, backward_layers, trace_layers
from morality_gym.baselines.specs import DEFAULT_UPDATE_ENGINE, UPDATE_ENGINES

Step = Callable[..., Any]
#: A ``torch.compile`` backend: None (inductor), a registered name, or a backend function.
Backend = str | Callable[..., Any] | None


class Net(NamedTuple):
    """A network's static shape: hidden widths, each head's output width (in the order of the
    optimiser's parameters) and the activation's name. A tuple of constants, so that two fleets of a
    learner hand the compiled step equal values (no recompile)."""

    hidden: tuple[int, ...]
    outputs: tuple[int, ...]
    activation: str


class AdamConsts(NamedTuple):
    """One optimiser's constants: betas, eps, the gradient clipping (``max_norm``; ``split``: how
    many of the gradient tensors form the first of two clipping groups, e.g. the reward critic's
    beside the cost critic's; 0: one group) and the critics' L2 factor."""

    beta1: float
    beta2: float
    eps: float
    max_norm: float
    split: int
    l2: float


def compile_cache_dir() -> Path:
    """Where compiled kernels are kept between processes: ``$TORCHINDUCTOR_CACHE_DIR`` when set,
    else ``$XDG_CACHE_HOME/morality_gym/torch_compile`` (``~/.cache/...``)."""
    given = os.environ.get("TORCHINDUCTOR_CACHE_DIR")
    if given:
        return Path(given)
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "morality_gym" / "torch_compile"


def compiler_missing() -> str | None:
    """Why inductor cannot compile for the CPU here (no C++ compiler on ``PATH``), or None."""
    wanted = os.environ.get("CXX")
    names = [wanted] if wanted else ["g++", "clang++", "c++"]
    if any(shutil.which(n) for n in names):
        return None
    return (f"no C++ compiler ({' or '.join(names)}) on PATH, which torch.compile needs on the CPU; "
            "install g++ (make system-deps)")


@functools.cache
def _warn_eager(why: str) -> None:
    print(f"fleet update=compiled: {why}; running the eager update steps instead", file=sys.stderr)


@functools.cache
def _compiled(fn: Step, device_type: str, backend: Backend) -> Step:
    """``fn`` compiled once per process and device type: dynamo's cache is per function, so every
    fleet of the process shares the graphs."""
    os.environ.setdefault("TORCHINDUCTOR_CACHE_DIR", str(compile_cache_dir()))
    # torch waits: inductor's configuration loads only when something is compiled
    import torch._inductor.config as inductor_config

    inductor_config.fx_graph_cache = True
    options: dict[str, Any] = {"fullgraph": True, "dynamic": None}
    if backend is not None:
        options["backend"] = backend
    elif device_type == "cuda":
        options["mode"] = "reduce-overhead"
    step = th.compile(fn, **options)

    @functools.wraps(fn)
    def run(*args: Any) -> Any:
        # A value read on the host (``.item()``) or a shape known only from data (``nonzero``)
        # would wait for the device at every step (and keeps a GPU step out of a CUDA graph): with
        # these off, dynamo refuses both, and fullgraph=True makes the refusal an error.
        with th._dynamo.config.patch(capture_scalar_outputs=False, capture_dynamic_output_shape_ops=False):
            return step(*args)

    return run


def compiled_step(fn: Step, device: th.device, backend: Backend = None) -> Step:
    """``fn`` as the compiled engine runs it on ``device``: compiled (``backend`` None: inductor,
    CUDA graphs on a GPU; tests pass :func:`static_check`, which generates no code), or ``fn`` itself, with one
    line on stderr, when the CPU has no C++ compiler for inductor."""
    if backend is None and device.type == "cpu":
        why = compiler_missing()
        if why is not None:
            _warn_eager(why)
            return fn
    return _compiled(fn, device.type, backend)


class DataDependentShape(RuntimeError):
    """A compiled step holds a tensor whose shape (or a number) is known only from data (see :func:`static_check`)."""


def static_check(gm: th.fx.GraphModule, example_inputs: Sequence[Any]) -> Callable[..., Any]:
    """A ``torch.compile`` backend for tests: refuses a graph with any value whose shape depends on
    data (``nonzero``, a boolean mask, ``unique``: dynamo traces them with "unbacked" sizes, which on
    a GPU wait for the device and keep the step out of a CUDA graph), then runs the graph as traced.
    Host reads (``.item()``) already break the graph, which ``fullgraph=True`` makes an error."""
    # torch waits: the symbolic-shape helpers load only where a test checks a graph
    from torch.fx.experimental.symbolic_shapes import free_unbacked_symbols

    for node in gm.graph.nodes:
        value = node.meta.get("example_value")
        if value is not None and free_unbacked_symbols(value):
            raise DataDependentShape(f"data-dependent shape in a compiled update step: {node.format_node()}")
    return gm.forward


def adam_in_graph(device: th.device) -> bool:
    """Whether a compiled step takes its Adam step inside the graph (:func:`adam_`), or hands the
    gradients to the eager :class:`~.optim.BatchedAdam` (PyTorch's fused kernel). In the graph
    everywhere: on a GPU the whole step is then one CUDA graph, and on the CPU it was the faster
    (a PPO update at K = 12, one epoch, same process, two rounds: 0.76 and 0.87 s in the graph,
    0.93 and 0.88 s with the fused kernel, 1.08 and 1.02 s eager). The other way stays selectable
    (:attr:`~.base.FleetTrainer.adam_in_graph`) for measuring."""
    del device  # the same answer on every device today; the argument is where a device's own answer goes
    return True


def mark_dynamic(*tensors: th.Tensor, dims: Sequence[int] = (0,)) -> None:
    """Mark ``dims`` of ``tensors`` dynamic (run axis, observation width, minibatch): one graph for
    every fleet. ``maybe_``: a dimension of size 1 stays specialised instead of failing."""
    for t in tensors:
        for d in dims:
            th._dynamo.maybe_mark_dynamic(t, d)


def mark_static(*tensors: th.Tensor) -> None:
    """Mark the buffers a compiled step writes in place (an optimiser's parameters, Adam moments and
    step counts) as keeping their address from call to call.

    Why: a CUDA graph replays fixed addresses, and inductor's CUDA-graph trees refuse to capture a
    graph that writes into an input unless the input is static (an ``nn.Parameter``, or marked so).
    Unmarked, every compiled step ran outside a CUDA graph on an H200 ("skipping cudagraphs due to
    mutated inputs (4 instances)", ``benchmarks/gpu_compiled_check.sh``, 2026-11-28). ``guard=False``:
    no guard on the address, so another fleet's buffers reuse the compiled graph (the CUDA graph is
    recorded again for them) instead of recompiling it. The mark is an attribute of the tensor: it
    changes nothing on the CPU."""
    for t in tensors:
        th._dynamo.mark_static_address(t, guard=False)


# ---------------------------------------------------------------------------------------- pieces
def _backward(tr: Trace, dout: th.Tensor, act_backward: Callable[[th.Tensor, th.Tensor], th.Tensor]) -> list[th.Tensor]:
    """:func:`~.nets.backward_layers` with every weight gradient in its weights' layout.

    Why: eagerly the first layer's gradient is the transposed product (faster for the narrow
    observation input), a transposed view. In a graph, inductor fuses that view into Adam's loop
    and gathers it element by element (an index ``% width`` and ``// width`` per element, the
    observation width being a dynamic size): at K = 12, 1.39 ms for the Adam step with the first
    layers' gradients transposed against 0.72 ms with them contiguous (rates outside the graph,
    one probe, same process). On the whole PPO step the direct product was 1.08x (K = 12) and
    1.48x (K = 36) faster (BENCHMARKS.md, "Fleet compiled update: ...", a noisy run)."""
    return backward_layers(tr, dout, act_backward, narrow_transposed=False)


def unflatten(flat: th.Tensor, in_dim: int, net: Net) -> list[Layers]:
    """The heads' layers as views into an optimiser's ``[K, P]`` buffer (:class:`~.optim.BatchedAdam`'s
    layout: ``W0, b0, W1, b1, ...`` head after head, each ``W`` ``[out, in]`` row-major)."""
    k = flat.shape[0]
    heads: list[Layers] = []
    at = 0
    for out in net.outputs:
        sizes = [in_dim, *net.hidden, out]
        layers: Layers = []
        for i in range(len(sizes) - 1):
            n_in, n_out = sizes[i], sizes[i + 1]
            w = flat[:, at : at + n_out * n_in].view(k, n_out, n_in)
            at += n_out * n_in
            b = flat[:, at : at + n_out].view(k, n_out, 1)
            at += n_out
            layers.append((w, b))
        heads.append(layers)
    return heads


def adam_rates(steps: th.Tensor, lr: th.Tensor, active: th.Tensor | None, c: AdamConsts) -> th.Tensor:
    """``[K, 2]``: each run's Adam step size ``lr / (1 - beta1^t)`` and ``sqrt(1 - beta2^t)`` for its
    next step ``t`` (the step count after this step: ``steps + 1``, or ``+ active``), as
    :func:`adam_` reads them. Computed *outside* the compiled step, by the caller, just before it.

    Why outside: inside a graph inductor fuses these per-run values into the loop over each run's
    parameters and evaluates the two ``pow`` (and the division and root) again for every vector of 8
    parameters (libm's ``pow`` may set ``errno``, so the C++ compiler cannot hoist it out of the
    loop; the generated code shows it). Measured gain: mixed so far, on a heavily shared machine
    (BENCHMARKS.md, "Fleet compiled update: Adam's per-run rates inside vs outside the graph": the
    Adam step alone 1.7x faster at K = 36, slower at K = 12; rerun 2026-11-28 at a load of 7-8 on 2 CPUs:
    the Adam step alone slower at both sizes, the whole step with this change alone 1.01x and 1.40x
    faster; still inconclusive, rerun on a quiet machine). Five small
    tensor operations on the device, no host read."""
    step = steps + (1.0 if active is None else active.to(steps.dtype))
    return th.stack([lr / (1.0 - th.pow(c.beta1, step)), th.sqrt(1.0 - th.pow(c.beta2, step))], dim=1)


def adam_(flat: th.Tensor, exp_avg: th.Tensor, exp_avg_sq: th.Tensor, steps: th.Tensor, grads: list[th.Tensor],
          rates: th.Tensor, active: th.Tensor | None, c: AdamConsts) -> None:
    """One step of :class:`~.optim.BatchedAdam` written as tensor arithmetic, in place: the L2
    term, per-run clipping (one or two groups of tensors), the step count, then Adam (the formula of
    PyTorch's fused kernel). ``rates``: :func:`adam_rates` (``[K, 2]``); ``active``: ``[K]`` bool,
    None for every run.

    Tensor by tensor, joined once at the end: a ``cat`` of the gradients first made inductor
    compute every element of the joined gradient by testing which of a dozen inputs it comes from,
    once per use (2.5 ms of a 3.4 ms step at K = 12, measured)."""
    k = flat.shape[0]
    g = [x.reshape(k, -1) for x in grads]  # laid out as the weights (:func:`_backward`)
    columns = [x.shape[1] for x in g]
    params = list(th.split(flat, columns, dim=1))
    if c.l2:
        g = [x + p * (2.0 * c.l2) for x, p in zip(g, params)]
    if c.max_norm > 0:
        groups = [range(len(g))] if c.split == 0 else [range(c.split), range(c.split, len(g))]
        for group in groups:
            norm = th.sqrt(sum((g[i] * g[i]).sum(dim=1, keepdim=True) for i in group))  # type: ignore[arg-type]
            coef = th.clamp(c.max_norm / (norm + 1e-6), max=1.0)
            for i in group:
                g[i] = g[i] * coef
    new_steps = steps + (1.0 if active is None else active.to(steps.dtype))
    step_size, bias2_sqrt = rates[:, :1], rates[:, 1:]  # [K, 1]: per run, not per element
    live = None if active is None else active.unsqueeze(1)
    out: tuple[list[th.Tensor], list[th.Tensor], list[th.Tensor]] = ([], [], [])
    for x, p, m, v in zip(g, params, th.split(exp_avg, columns, dim=1), th.split(exp_avg_sq, columns, dim=1)):
        m_new = m.lerp(x, 1.0 - c.beta1)
        v_new = v * c.beta2 + (1.0 - c.beta2) * x * x
        p_new = p - step_size * m_new / (v_new.sqrt() / bias2_sqrt + c.eps)
        if live is not None:
            m_new, v_new, p_new = th.where(live, m_new, m), th.where(live, v_new, v), th.where(live, p_new, p)
        for buf, value in zip(out, (p_new, m_new, v_new)):
            buf.append(value)
    steps.copy_(new_steps)
    flat.copy_(th.cat(out[0], dim=1))
    exp_avg.copy_(th.cat(out[1], dim=1))
    exp_avg_sq.copy_(th.cat(out[2], dim=1))


def _critics(flat: th.Tensor, obs: th.Tensor, returns: th.Tensor, cost_returns: th.Tensor, net: Net
             ) -> tuple[list[th.Tensor], th.Tensor, th.Tensor]:
    """Both critics' gradients and MSEs (:meth:`.cost_base.FleetCostTrainer._critic_grads`)."""
    act, act_backward = ACTIVATIONS[net.activation]
    reward_layers, cost_layers = unflatten(flat, obs.shape[2], net)
    reward, cost = trace_layers(reward_layers, obs, act), trace_layers(cost_layers, obs, act)
    value_loss, dvalues = mse(reward.out[:, 0], returns)
    cost_value_loss, dcost_values = mse(cost.out[:, 0], cost_returns)
    grads = _backward(reward, dvalues, act_backward) + _backward(cost, dcost_values, act_backward)
    return grads, value_loss, cost_value_loss


# ---------------------------------------------------------------------------------------- steps
def ppo_step(flat: th.Tensor, exp_avg: th.Tensor, exp_avg_sq: th.Tensor, steps: th.Tensor, obs: th.Tensor,
             actions: th.Tensor, old_log_prob: th.Tensor, advantages: th.Tensor, returns: th.Tensor, rates: th.Tensor,
             clip_range: th.Tensor, net: Net, adam: AdamConsts | None, ent_coef: float, vf_coef: float, normalize: bool
             ) -> list[th.Tensor] | None:
    """One PPO minibatch of every run (:meth:`.ppo.FleetPPO._train`'s loop body), its Adam step
    taken in place on the optimiser's buffers; with ``adam`` None, the gradients are returned for
    the eager optimiser instead (:func:`adam_in_graph`). ``rates``: :func:`adam_rates`; ``clip_range``: 0-d."""
    act, act_backward = ACTIVATIONS[net.activation]
    actor_layers, critic_layers = unflatten(flat, obs.shape[2], net)
    actor, critic = trace_layers(actor_layers, obs, act), trace_layers(critic_layers, obs, act)
    policy = Policy.of(actor.out)
    if normalize:
        advantages = (advantages - advantages.mean(dim=1, keepdim=True)) / (advantages.std(dim=1, keepdim=True) + 1e-8)
    ratio = th.exp(policy.log_prob(actions) - old_log_prob)
    _, dratio = clipped_surrogate_t(ratio, advantages, clip_range)
    dentropy = th.full_like(ratio, -ent_coef / ratio.shape[1]) if ent_coef else None
    dlogits = policy.dlogits(actions, dratio * ratio, dentropy)
    _, dvalues = mse(critic.out[:, 0], returns)
    grads = _backward(actor, dlogits, act_backward) + _backward(critic, dvalues.mul_(vf_coef), act_backward)
    if adam is None:
        return grads
    adam_(flat, exp_avg, exp_avg_sq, steps, grads, rates, None, adam)
    return None


def clipped_surrogate_t(ratio: th.Tensor, advantages: th.Tensor, clip_range: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """:func:`~.losses.clipped_surrogate` with the clip range a 0-d tensor (a schedule's value
    changes every update; a Python float would be a constant of the graph and recompile it)."""
    lo, hi = 1.0 - clip_range, 1.0 + clip_range
    unclipped = ratio * advantages
    clipped = th.clamp(ratio, lo, hi) * advantages
    loss = -th.min(unclipped, clipped).mean(dim=1)
    share = th.where(unclipped < clipped, 1.0, th.where(unclipped == clipped, 0.5, 0.0))
    inside = (ratio >= lo) & (ratio <= hi)
    weight = share + (1.0 - share) * inside
    return loss, advantages * weight * (-1.0 / ratio.shape[1])


def critic_step(flat: th.Tensor, exp_avg: th.Tensor, exp_avg_sq: th.Tensor, steps: th.Tensor, obs: th.Tensor,
                returns: th.Tensor, cost_returns: th.Tensor, rates: th.Tensor, net: Net, adam: AdamConsts | None
                ) -> tuple[th.Tensor, list[th.Tensor] | None]:
    """One minibatch of both critics' regression for every run (:meth:`.cost_base.FleetCostTrainer._train_critics`'s
    loop body); returns ``[2, K]``: the reward and cost critics' MSEs, and the gradients when
    ``adam`` is None (:func:`adam_in_graph`)."""
    grads, value_loss, cost_value_loss = _critics(flat, obs, returns, cost_returns, net)
    losses = th.stack([value_loss, cost_value_loss])
    if adam is None:
        return losses, grads
    adam_(flat, exp_avg, exp_avg_sq, steps, grads, rates, None, adam)
    return losses, None


def lag_step(actor_flat: th.Tensor, actor_avg: th.Tensor, actor_avg_sq: th.Tensor, actor_steps: th.Tensor,
             critic_flat: th.Tensor, critic_avg: th.Tensor, critic_avg_sq: th.Tensor, critic_steps: th.Tensor,
             obs: th.Tensor, actions: th.Tensor, old_log_prob: th.Tensor, adv: th.Tensor, cadv: th.Tensor,
             returns: th.Tensor, cost_returns: th.Tensor, lam32: th.Tensor, one_plus: th.Tensor, actor_rates: th.Tensor,
             critic_rates: th.Tensor, clip_range: th.Tensor, active: th.Tensor, actor_net: Net, critic_net: Net,
             actor_adam: AdamConsts | None, critic_adam: AdamConsts | None, ent_coef: float
             ) -> tuple[th.Tensor, list[th.Tensor] | None, list[th.Tensor] | None]:
    """One PPO-Lag minibatch of every run (:meth:`.ppo_lag.FleetPPOLag._one_pass`'s loop body),
    runs not ``active`` computed but left unchanged; returns ``[5, K]``: policy, value and cost
    value losses, mean entropy, clip fraction, and with the Adams None (:func:`adam_in_graph`)
    the actor's and the critics' gradients."""
    act, act_backward = ACTIVATIONS[actor_net.activation]
    (actor_layers,) = unflatten(actor_flat, obs.shape[2], actor_net)
    actor = trace_layers(actor_layers, obs, act)
    policy = Policy.of(actor.out)
    ent = policy.entropy()
    advantages = (adv - lam32 * cadv) / one_plus
    ratio = th.exp(policy.log_prob(actions) - old_log_prob)
    policy_loss, dratio = clipped_surrogate_t(ratio, advantages, clip_range)
    dentropy = th.full_like(ratio, -ent_coef / ratio.shape[1]) if ent_coef else None
    actor_grads = _backward(actor, policy.dlogits(actions, dratio * ratio, dentropy), act_backward)
    critic_grads, value_loss, cost_value_loss = _critics(critic_flat, obs, returns, cost_returns, critic_net)
    clip_fraction = ((ratio - 1.0).abs() > clip_range).float().mean(dim=1)
    stats = th.stack([policy_loss, value_loss, cost_value_loss, ent.mean(dim=1), clip_fraction])
    if actor_adam is None or critic_adam is None:
        return stats, actor_grads, critic_grads
    adam_(critic_flat, critic_avg, critic_avg_sq, critic_steps, critic_grads, critic_rates, active, critic_adam)
    adam_(actor_flat, actor_avg, actor_avg_sq, actor_steps, actor_grads, actor_rates, active, actor_adam)
    return stats, None, None


__all__ = [
    "DEFAULT_UPDATE_ENGINE", "UPDATE_ENGINES", "AdamConsts", "DataDependentShape", "Net", "adam_", "adam_in_graph", "adam_rates", "clipped_surrogate_t", "compile_cache_dir",
    "compiled_step", "compiler_missing", "critic_step", "lag_step", "mark_dynamic", "mark_static", "ppo_step", "static_check", "unflatten",
]
