"""The compiled engine's Adam step, piece by piece: where a PPO minibatch step's time goes and what each change gains.

Why a section of its own: the whole-training comparison (bench_fleet_compiled.py) says how much the
compiled engine gains, not why; a change to one piece of the step (here: where Adam's per-run rates
are computed) is measured alone, old and new compiled in the same process on the same tensors.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import sys
import tempfile
from collections.abc import Callable
from typing import Any

import torch

import morality_gym
from benchmarks import Context, Section, best_time, register
from morality_gym.baselines.fleet import FleetRun, build_fleet, compiled
from morality_gym.baselines.fleet.nets import backward_layers
from morality_gym.baselines.specs import learner_spec

#: Minibatch steps timed per figure (per repeat).
CALLS = 100


def _rates_in_graph(flat: Any, exp_avg: Any, exp_avg_sq: Any, steps: Any, grads: list[Any], lr: Any, consts: Any) -> None:
    """The engine before this change: Adam's per-run rates computed inside the compiled graph."""
    compiled.adam_(flat, exp_avg, exp_avg_sq, steps, grads, compiled.adam_rates(steps, lr, None, consts), None, consts)


def _engine(transposed_first_layer: bool, rates_in_graph: bool) -> Callable[..., Any]:
    """``compiled.ppo_step`` as the engine was before this change, in either or both of its two
    pieces: a fresh copy of the module (its own globals, so its graph is its own) whose first-layer
    gradient is the eager transposed product, and/or a step that computes Adam's rates in the graph
    from the learning rate (argument 9)."""
    spec = importlib.util.spec_from_file_location(f"{compiled.__name__}_{int(transposed_first_layer)}{int(rates_in_graph)}",
                                                  compiled.__file__)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dynamo looks the step's globals up by module name
    spec.loader.exec_module(module)
    if transposed_first_layer:
        module._backward = backward_layers  # type: ignore[attr-defined]
    if not rates_in_graph:
        return module.ppo_step  # type: ignore[no-any-return]

    def step(*args: Any) -> Any:
        rates = module.adam_rates(args[3], args[9], None, args[12])
        return module.ppo_step(*args[:9], rates, *args[10:])

    return step


#: The whole-step variants: (transposed first-layer gradient, rates in the graph).
STEPS = {
    "step before": (True, True),
    "step, rates outside only": (True, False),
    "step, direct first-layer product only": (False, True),
    "step now": (False, False),
}


@register("fleet_adam", "Fleet compiled update: Adam's per-run rates inside vs outside the graph", order=78)
def fleet_adam(ctx: Context) -> Section:
    torch.set_num_threads(1)
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = tempfile.mkdtemp(prefix="inductor-bench-")
    sizes = (2,) if ctx.quick else (12, 36)
    spec = learner_spec("ppo")
    ids = morality_gym.env_ids("PushOrSwitch")
    task = ctx.task("fleet_adam", len(sizes))
    compiled_fns: dict[str, Callable[..., Any]] = {
        "adam rates in graph": torch.compile(_rates_in_graph, fullgraph=True, dynamic=None),
        "adam rates outside": torch.compile(compiled.adam_, fullgraph=True, dynamic=None),
        **{name: torch.compile(_engine(*how), fullgraph=True, dynamic=None) for name, how in STEPS.items()},
    }
    rows, speedups = [], []
    load = os.getloadavg()[0]
    for k in sizes:
        params, ms = _measure(k, spec, ids, compiled_fns, ctx.repeats)
        speedups.append((k, ms))
        rows.append([f"K={k}", f"{params:,}", *(f"{v:.3f}" for v in ms.values()),
                     f"{ms['adam rates in graph'] / ms['adam rates outside']:.1f}x",
                     *(f"{ms['step before'] / ms[name]:.2f}x" for name in list(STEPS)[1:])])
        task.advance()
    task.done()
    return Section(
        intro="""
One PPO minibatch of a fleet of K runs on PushOrSwitch (paper hyper-parameters, 64 transitions per run, torch on one
thread), *CPU* milliseconds per call, best of the repeats of 100 calls, every variant compiled by inductor in this
one process on the same tensors (random minibatch values: the time does not depend on them). "adam": the Adam step
alone (`compiled.adam_`: per-run clipping, moments, parameters) on the PPO optimiser's `[K, P]` buffers, the
gradients laid out as the weights; "rates in graph" computes each run's step size `lr / (1 - beta1^t)` and
`sqrt(1 - beta2^t)` inside the compiled graph, "rates outside" beforehand as a `[K, 2]` tensor
(`compiled.adam_rates`, five small eager operations, timed with the call): inside, inductor fuses them into the loop
over every run's parameters and calls libm's `pow` again for each vector of 8 parameters. "adam fused eager" is
PyTorch's fused Adam kernel, which the eager engine calls (no clipping: a floor for the arithmetic). "step": the
whole minibatch step (`compiled.ppo_step`: forward, hand-written backward, Adam) as it was before this change
(rates in the graph, the first layer's weight gradient the eager transposed product, which inductor then reads
element by element), with each of the two changes alone, and now (both). Speed-ups are against "step before".
""",
        headers=["fleet", "parameters per run", "adam rates in graph ms", "adam rates outside ms", "adam fused eager ms",
                 *(f"{name} ms" for name in STEPS), "adam speed-up",
                 *(f"{name} speed-up" for name in list(STEPS)[1:])],
        rows=rows,
        notes=_notes(speedups, load, os.getloadavg()[0], os.cpu_count() or 1),
        compare=["adam rates outside ms", "step now ms"],
    )


def _notes(measured: list[tuple[int, dict[str, float]]], load_start: float, load_end: float, cpus: int) -> list[str]:
    """Which change was faster at every size measured, and the machine's load, so that a reader
    can tell a clear result from a noisy one (a previous run on a loaded machine was inconclusive)."""
    def verdict(name: str, base: str, what: str) -> str:
        ratios = [ms[base] / ms[name] for _, ms in measured]
        sizes = ", ".join(f"{r:.2f}x at K={k}" for (k, _), r in zip(measured, ratios))
        if all(r > 1.0 for r in ratios):
            word = "faster at every size"
        elif all(r < 1.0 for r in ratios):
            word = "slower at every size"
        else:
            word = "mixed"
        return f"{what}: {word} ({sizes})"

    return [
        "; ".join([
            verdict("adam rates outside", "adam rates in graph", "Adam's rates outside the graph, the Adam step alone"),
            verdict("step, rates outside only", "step before", "the same change alone on the whole step"),
            verdict("step, direct first-layer product only", "step before", "the direct first-layer product alone"),
            verdict("step now", "step before", "both (the engine now)"),
        ]) + ".",
        (f"Load average (1 min) {load_start:.2f} at the start and {load_end:.2f} at the end of this section, on {cpus} "
         "logical CPUs: the figures are this process's CPU time, which other jobs inflate less than wall time, though not entirely."
         + (" **Inconclusive**: the machine was loaded beyond its CPUs; rerun on a quiet machine before quoting."
            if max(load_start, load_end) > cpus else "")),
    ]


def _measure(k: int, spec: Any, ids: list[str], compiled_fns: dict[str, Callable[..., Any]], repeats: int
             ) -> tuple[int, dict[str, float]]:
    """CPU ms per call of every variant on a PPO fleet of ``k`` runs (its optimiser's buffers, a random minibatch)."""
    fleet = build_fleet(spec, [FleetRun(morality_gym.bind_chain("DualProcess", ids[i % len(ids)]), i) for i in range(k)],
                        "paper", update="compiled")
    opt = fleet.optimizer
    net = compiled.Net(tuple(spec.net_arch), (6, 1), spec.activation)
    consts = compiled.AdamConsts(opt.beta1, opt.beta2, opt.eps, float(fleet.model.max_grad_norm), 0, 0.0)
    batch = int(spec.hparams["batch_size"])
    gen = torch.Generator().manual_seed(0)
    obs = torch.rand(k, batch, fleet.nets.heads["pi"][0][0].shape[2], generator=gen)
    actions = torch.randint(0, 6, (k, batch), generator=gen)
    old_log_prob = torch.full((k, batch), -1.79)
    advantages, returns = torch.randn(k, batch, generator=gen), torch.randn(k, batch, generator=gen)
    lr = torch.full((k,), 3e-4)
    clip = torch.tensor(0.2)
    state = [opt.flat.clone(), opt.exp_avg.clone(), opt.exp_avg_sq.clone(), opt._step_counts.clone()]
    minibatch = (obs, actions, old_log_prob, advantages, returns)
    grads = compiled.ppo_step(*[t.clone() for t in state], *minibatch, lr, clip, net, None, 0.0, 0.5, True)
    assert grads is not None
    calls: dict[str, Callable[[list[Any]], Any]] = {
        "adam rates in graph": lambda s: compiled_fns["adam rates in graph"](*s, grads, lr, consts),
        "adam rates outside": lambda s: compiled_fns["adam rates outside"](
            *s, grads, compiled.adam_rates(s[3], lr, None, consts), None, consts),
        "adam fused eager": lambda s: _fused_eager(s, grads, consts),
    }
    for name, (_, rates_in_graph) in STEPS.items():
        calls[name] = functools.partial(_call_step, compiled_fns[name], minibatch, lr, clip, net, consts, rates_in_graph)
    ms: dict[str, float] = {}
    for name, call in calls.items():
        held = [t.clone() for t in state]
        call(held)  # untimed: compiles (or recompiles for this size)

        def work(call: Callable[[list[Any]], Any] = call, held: list[Any] = held) -> None:
            for _ in range(CALLS):
                call(held)

        ms[name] = 1e3 * best_time(work, repeats).cpu / CALLS
    return int(opt.flat.shape[1]), ms


def _call_step(step: Callable[..., Any], minibatch: tuple[Any, ...], lr: Any, clip: Any, net: Any, consts: Any,
               rates_in_graph: bool, state: list[Any]) -> Any:
    """One minibatch step; a step with its rates outside the graph gets them computed here (timed with it)."""
    rates = lr if rates_in_graph else compiled.adam_rates(state[3], lr, None, consts)
    return step(*state, *minibatch, rates, clip, net, consts, 0.0, 0.5, True)


def _fused_eager(state: list[Any], grads: list[Any], consts: Any) -> None:
    """PyTorch's fused Adam on every run's row (as :class:`~morality_gym.baselines.fleet.optim.BatchedAdam`
    calls it; no clipping)."""
    flat, exp_avg, exp_avg_sq, steps = state
    k = flat.shape[0]
    g = torch.cat([x.reshape(k, -1) for x in grads], dim=1)
    torch._fused_adam_(list(flat.unbind()), list(g.unbind()), list(exp_avg.unbind()), list(exp_avg_sq.unbind()), [],
                       list(steps.unbind()), lr=3e-4, beta1=consts.beta1, beta2=consts.beta2, weight_decay=0.0, eps=consts.eps,
                       amsgrad=False, maximize=False)
