"""The compiled update engine (``update=compiled``, morality_gym/baselines/fleet/compiled.py).

What stands in for the GPU on the CPU: every learner's step compiles with ``fullgraph=True``
(a graph break, i.e. a host read such as ``.item()``, is an error, and so is a data-dependent shape:
``compiled.static_check``), and
over three updates and two fleets of different composition (sizes, scenarios, observation widths)
dynamo compiles each step function once and never again (``error_on_recompile``). The checks run
on ``static_check``, a backend that runs the traced graph as it is: it sees the very graph inductor would compile, without
paying inductor's code generation (tens of seconds per graph on this machine); the benchmark
(benchmarks/bench_fleet_compiled.py) runs inductor itself.

The compiled engine's arithmetic is the eager engine's up to float rounding (its Adam is written
out, and stopped PPO-Lag runs are computed then masked): a compiled fleet ends a few updates where
an eager one does, to float tolerance, with the same diagnostics.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import torch as th
import torch._dynamo

import morality_gym
from morality_gym.baselines.fleet import FleetRun, build_fleet, compiled, make_fleet
from morality_gym.baselines.fleet import ppo as fleet_ppo
from morality_gym.baselines.fleet.nets import ACTIVATIONS, backward_layers, trace_layers
from morality_gym.baselines.specs import SpecError, learner_spec, protocol_spec

SMALL = {
    "ppo": {"n_steps": 32, "n_epochs": 2},
    "ppo_shaped": {"n_steps": 32, "n_epochs": 2},
    "ppo_lag": {"n_steps": 32, "n_epochs": 3},
    "cpo": {"n_steps": 32, "n_critic_updates": 2},
}
CASES = [("ppo", "paper"), ("ppo_shaped", "paper"), ("ppo_lag", "paper"), ("ppo_lag", "corrected"), ("cpo", "paper"),
         ("cpo", "corrected")]
ROLLOUT = 32 * 8
#: The step function each learner compiles.
STEPS = {"ppo": "ppo_step", "ppo_shaped": "ppo_step", "ppo_lag": "lag_step", "cpo": "critic_step"}
#: Two fleets of different composition: sizes 2 and 3; one scenario, then three of widths 31, 63 and 22.
FLEET_A = [("DualProcess", "PushOrSwitch-Human-v1", 1), ("Utility", "PushOrSwitch-Animal-v1", 2)]
FLEET_B = [("DualProcess", "PushOrSwitch-Human-v1", 5), ("Utility", "Switch7-Human-v1", 6), ("DualProcess", "PushStandard-AnimalA-v1", 7)]


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tests/conftest.py


@pytest.fixture(autouse=True)
def _fresh_dynamo() -> Iterator[None]:
    """Every test starts with no compiled graph and zeroed counters, and fails on any recompile."""
    torch._dynamo.reset()
    compiled._compiled.cache_clear()
    torch._dynamo.utils.counters.clear()
    with torch._dynamo.config.patch(error_on_recompile=True):
        yield
    torch._dynamo.reset()
    compiled._compiled.cache_clear()


def _fleet(name: str, protocol: str, runs: list[tuple[str, str, int]], update: str = "compiled", in_graph: bool = True,
           **hparams: Any) -> Any:
    spec = learner_spec(name, {"hparams": {**SMALL[name], **hparams}})
    fleet = build_fleet(spec, [FleetRun(morality_gym.bind_chain(c, e), s) for c, e, s in runs], protocol, simulator="host",
                        update=update)
    fleet.compile_backend = compiled.static_check  # the graph inductor would get, checked, without code generation
    fleet.adam_in_graph = in_graph
    return fleet


@pytest.mark.parametrize("in_graph", [True, False], ids=["adam_in_graph", "adam_eager"])
@pytest.mark.parametrize(("name", "protocol"), CASES)
def test_every_step_compiles_whole_once_across_updates_and_fleets(name: str, protocol: str, in_graph: bool) -> None:
    """fullgraph: no graph break (a host sync or a data-dependent shape would raise); one graph for
    three updates of a fleet of two runs and three updates of a mixed fleet of three."""
    for runs in (FLEET_A, FLEET_B):
        fleet = _fleet(name, protocol, runs, in_graph=in_graph)
        assert fleet.learn(3 * ROLLOUT) == 3 * ROLLOUT
    counters = torch._dynamo.utils.counters
    assert dict(counters["graph_break"]) == {}
    assert counters["stats"]["unique_graphs"] == 1, dict(counters["stats"])


@pytest.mark.parametrize("in_graph", [True, False], ids=["adam_in_graph", "adam_eager"])
@pytest.mark.parametrize(("name", "protocol"), CASES)
def test_compiled_fleet_matches_the_eager_fleet(name: str, protocol: str, in_graph: bool) -> None:
    """Three updates on the compiled engine end at the eager engine's parameters, optimiser
    moments, step counts and diagnostics rows, to float tolerance."""
    eager, comp = (_fleet(name, protocol, FLEET_B, update=u, in_graph=in_graph) for u in ("eager", "compiled"))
    for fleet in (eager, comp):
        fleet.learn(3 * ROLLOUT)
    for a, b in zip(eager._trained_tensors(), comp._trained_tensors()):
        np.testing.assert_allclose(b.numpy(), a.numpy(), rtol=1e-4, atol=1e-5)
    for opt_a, opt_b in zip(eager._optimisers().values(), comp._optimisers().values()):
        np.testing.assert_array_equal(opt_b.steps, opt_a.steps)
    for rows_a, rows_b in zip(eager.update_logs, comp.update_logs):
        assert len(rows_a) == len(rows_b) == (0 if name.startswith("ppo") and name != "ppo_lag" else 3)  # PPO logs no rows
        for ra, rb in zip(rows_a, rows_b):
            assert ra.keys() == rb.keys()
            for key, value in ra.items():
                if isinstance(value, float):
                    np.testing.assert_allclose(rb[key], value, rtol=1e-3, atol=1e-5, err_msg=key)
                else:
                    assert rb[key] == value, key


@pytest.mark.parametrize("in_graph", [True, False], ids=["adam_in_graph", "adam_eager"])
def test_ppo_lag_early_stop_masks_stopped_runs(in_graph: bool) -> None:
    """A run whose KL stops its passes takes no further optimiser step (target_kl tiny: every run
    stops after its first pass)."""
    fleet = _fleet("ppo_lag", "corrected", FLEET_A, in_graph=in_graph, target_kl=1e-9)
    fleet.learn(ROLLOUT)
    assert [row["passes"] for rows in fleet.update_logs for row in rows] == [1, 1]
    minibatches = ROLLOUT // int(fleet.model.batch_size)
    np.testing.assert_array_equal(fleet.actor_optimizer.steps, [minibatches, minibatches])


def _graph_functions(name: str, protocol: str) -> list[str]:
    """The functions called in the graphs of a learner's compiled steps (two updates of a fleet of two runs)."""
    seen: list[str] = []

    def record(gm: th.fx.GraphModule, example_inputs: Any) -> Any:
        seen.extend(str(node.target) for node in gm.graph.nodes if node.op in ("call_function", "call_method"))
        return compiled.static_check(gm, example_inputs)

    fleet = _fleet(name, protocol, FLEET_A)
    fleet.compile_backend = record
    fleet.learn(2 * ROLLOUT)
    assert seen, "no graph was compiled"
    return seen


@pytest.mark.parametrize(("name", "protocol"), [("ppo", "paper"), ("ppo_lag", "corrected"), ("cpo", "paper")])
def test_adam_rates_are_computed_outside_the_graph(name: str, protocol: str) -> None:
    """No ``pow`` in a compiled step: inside the graph inductor recomputed each run's bias corrections
    for every 8 parameters (``compiled.adam_rates``'s docstring); the caller hands them in instead."""
    called = _graph_functions(name, protocol)
    assert not [f for f in called if "pow" in f], called


def test_compiled_weight_gradients_are_laid_out_as_the_weights() -> None:
    """The compiled steps' first-layer gradient (narrow observation input) is the direct product,
    contiguous like the weights, not the eager engine's transposed view, which inductor reads
    element by element in Adam's loop; the eager backward pass keeps its transposed product (its bits)."""
    gen = th.Generator().manual_seed(0)
    layers = [(th.randn(3, 64, 22, generator=gen), th.randn(3, 64, 1, generator=gen)),
              (th.randn(3, 6, 64, generator=gen), th.randn(3, 6, 1, generator=gen))]
    act, act_backward = ACTIVATIONS["tanh"]
    trace = trace_layers(layers, th.randn(3, 64, 22, generator=gen), act)
    dout = th.randn(3, 6, 64, generator=gen)
    direct = compiled._backward(trace, dout.clone(), act_backward)
    eager = backward_layers(trace, dout.clone(), act_backward)
    assert all(g.is_contiguous() for g in direct)
    assert not eager[0].is_contiguous()  # the eager engine's product, unchanged
    for a, b in zip(direct, eager):
        th.testing.assert_close(a, b, rtol=1e-5, atol=1e-5)


def _with_host_read(*args: Any) -> None:
    compiled.ppo_step(*args)
    if args[0].abs().sum().item() < 0:  # a host read of a device value, as a careless edit would add
        raise AssertionError


def _with_data_dependent_shape(*args: Any) -> None:
    args = list(args)  # type: ignore[assignment]
    keep = th.nonzero(args[7] > 0)[:, 1]  # the states with a positive advantage: how many is known only at run time
    args[7] = args[7] + 0.0 * args[7][:, keep].sum()  # type: ignore[index]
    compiled.ppo_step(*args)


@pytest.mark.parametrize("bad_step", [_with_host_read, _with_data_dependent_shape])
def test_a_host_sync_or_data_dependent_shape_fails(monkeypatch: pytest.MonkeyPatch, bad_step: Any) -> None:
    """The check above is not vacuous: a step with ``.item()`` or a ``nonzero`` shape fails to compile whole."""
    monkeypatch.setattr(fleet_ppo, "ppo_step", bad_step)
    fleet = _fleet("ppo", "paper", FLEET_A)
    with pytest.raises(torch._dynamo.exc.TorchDynamoException, match="item|data-dependent shape"):
        fleet.learn(ROLLOUT)


def test_a_recompile_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    """A step whose shapes are left static (no ``mark_dynamic``) recompiles for a fleet of another
    size and observation width, and the check catches it."""
    monkeypatch.setattr(fleet_ppo, "mark_dynamic", lambda *tensors, dims=(0,): None)
    _fleet("ppo", "paper", FLEET_A).learn(ROLLOUT)
    with pytest.raises(torch._dynamo.exc.RecompileError):
        _fleet("ppo", "paper", FLEET_B).learn(ROLLOUT)


def test_unknown_engine_is_one_line() -> None:
    with pytest.raises(SpecError, match=r"update='compile': the fleet's update engines are eager and compiled"):
        _fleet("ppo", "paper", FLEET_A, update="compile")


def test_no_compiler_falls_back_to_eager_with_a_message(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """Without a C++ compiler inductor cannot build CPU kernels: one line on stderr, and the fleet trains eagerly."""
    monkeypatch.delenv("CXX", raising=False)
    monkeypatch.setattr(compiled.shutil, "which", lambda name: None)
    compiled._warn_eager.cache_clear()
    fleet = _fleet("ppo", "paper", FLEET_A)
    fleet.compile_backend = None
    fleet.learn(ROLLOUT)
    err = capsys.readouterr().err
    assert err.count("no C++ compiler") == 1 and "running the eager update steps instead" in err
    assert torch._dynamo.utils.counters["stats"]["unique_graphs"] == 0


def test_compiled_checkpoints_name_their_engine() -> None:
    """A checkpoint of a compiled fleet does not resume an eager one (their floats differ); an
    eager fleet's identity is what it was before the setting existed."""
    assert "update" not in _fleet("ppo", "paper", FLEET_A, update="eager").checkpoint_key()
    assert _fleet("ppo", "paper", FLEET_A).checkpoint_key()["update"] == "compiled"


@pytest.mark.parametrize(("name", "protocol"), [("ppo", "paper"), ("ppo_lag", "corrected"), ("cpo", "paper")])
def test_buffers_a_step_writes_are_static_for_cuda_graphs(name: str, protocol: str) -> None:
    """Every input a compiled step writes in place (parameters, Adam moments, step counts) is
    marked static without a guard: inductor's CUDA-graph trees skip capturing a graph that writes
    into any other input, which they did for every step on the H200 before the mark, and a guard
    would recompile for every fleet."""
    written_marks: list[Any] = []

    def backend(gm: th.fx.GraphModule, example_inputs: list[Any]) -> Any:
        placeholders = [n for n in gm.graph.nodes if n.op == "placeholder"]
        written = {n.args[0] for n in gm.graph.nodes if n.op == "call_method" and n.target == "copy_"}
        written_marks.extend(getattr(value, "_dynamo_static_input_type", None)
                             for node, value in zip(placeholders, example_inputs) if node in written)
        return compiled.static_check(gm, example_inputs)

    fleet = _fleet(name, protocol, FLEET_A)
    fleet.compile_backend = backend
    fleet.learn(ROLLOUT)
    assert len(written_marks) == (8 if name == "ppo_lag" else 4)
    assert set(written_marks) == {"unguarded"}


@pytest.mark.parametrize("name", ["ppo", "cpo"])
def test_eager_stays_the_default_engine(name: str) -> None:
    """Only the eager engine reruns a release bit for bit (docs/engines.md), and the sweep builds
    its fleets with ``fleet_update``, whose default is this one: so a fleet built without ``update=``, by
    either entry point, is eager and trains without compiling anything."""
    assert compiled.DEFAULT_UPDATE_ENGINE == "eager"
    spec = learner_spec(name, {"hparams": SMALL[name]})
    runs = [FleetRun(morality_gym.bind_chain(c, e), s) for c, e, s in FLEET_A]
    protocol = protocol_spec("paper")
    for fleet in (build_fleet(spec, runs, "paper"), make_fleet(protocol.apply(spec), runs, protocol)):
        assert fleet.update_engine == "eager" and not fleet.compiled
        fleet.learn(ROLLOUT)
        assert "update" not in fleet.checkpoint_key()  # its checkpoints are those of the releases' engine
    assert torch._dynamo.utils.counters["stats"]["unique_graphs"] == 0


@pytest.mark.skipif(not th.cuda.is_available(), reason="needs a GPU (benchmarks/gpu_compiled_check.sh runs it)")
@pytest.mark.parametrize(("name", "protocol"), [("ppo", "paper"), ("ppo_lag", "corrected"), ("cpo", "paper")])
def test_compiled_fleet_on_the_gpu_matches_eager(name: str, protocol: str) -> None:
    """On CUDA the compiled engine (inductor, CUDA graphs) ends where the eager engine does, and compiles each step once."""
    spec = learner_spec(name, {"hparams": SMALL[name]})
    runs = [FleetRun(morality_gym.bind_chain(c, e), s) for c, e, s in FLEET_B]
    eager, comp = (build_fleet(spec, runs, protocol, device="cuda", update=u) for u in ("eager", "compiled"))
    for fleet in (eager, comp):
        fleet.learn(3 * ROLLOUT)
    for a, b in zip(eager._trained_tensors(), comp._trained_tensors()):
        np.testing.assert_allclose(b.cpu().numpy(), a.cpu().numpy(), rtol=1e-4, atol=1e-4)
    assert torch._dynamo.utils.counters["stats"]["unique_graphs"] == 1
