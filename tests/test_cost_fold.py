"""The one step-wise cost (:class:`StackedCost`) against the spec's formula on the scalar env, and its sum's order.

The cost is written once, for numpy arrays and torch tensors. Its reference here is the formula of
evaluation spec section 5 evaluated term by term in plain Python floats on each step's
``info["norm_events"]`` of the scalar :class:`~morality_gym.TrolleyEnv`, in the order the cost has
always summed (event norms, then utility norms, each in the chain's order): every built-in chain on
every env id it binds to, all three modes and both reset policies, compared bit for bit with
:meth:`VectorCost.from_norm_events` (the single-env path) and with :class:`StackedCost` on numpy and on
torch (all copies in one pass). The second part pins :func:`~morality_gym.norms.cost.fold` to the
left-to-right sum on inputs where a reduction's pairing changes the last bit.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

import morality_gym
from morality_gym.envs.batched import utility_present
from morality_gym.norms.cost import StackedCost, VectorCost, fold
from morality_gym.norms.metric import BoundChain, compute_weights
from morality_gym.norms.reward_cost import RewardCostSpec
from morality_gym.world.vocab import EVENTS, UTILITIES, names_to_mask
from tests.helpers import bound_pairs

DEVICES = ["cpu", *(["cuda"] if th.cuda.is_available() else [])]
STEPS = 40


class _SpecCost:
    """Evaluation spec section 5, one env, plain Python: the reference the one cost must reproduce."""

    def __init__(self, bound: BoundChain, mode: str, scale: float, reset: str) -> None:
        chain = bound.chain
        norm_set = bound.relevant if mode == "full" else tuple(chain.norm_names)
        weights = {k: v for k, v in compute_weights(chain, norm_set, bound.beta).items() if k in norm_set}
        self.bounds = bound.global_bounds if mode == "minimal" else bound.bounds
        self.norms = [n for n in chain.norms if n.name in weights]
        assert all(n.prohibited for n in self.norms)  # no built-in chain has a prescribed norm
        self.weights, self.scale, self.reset = weights, scale, reset
        self.weight_sum = sum(weights.values())
        self.charged: set[str] = set()

    def step(self, norm_events: dict, ended: bool) -> float:
        happened = set(norm_events["action"]) | set(norm_events["outcome"]) | set(norm_events["causal"])
        total = 0.0
        for norm in self.norms:
            if norm.kind == "event" and norm.name in happened and norm.name not in self.charged:
                total += self.weights[norm.name]
                self.charged.add(norm.name)
        for norm in self.norms:
            if norm.kind == "utility" and norm.name in norm_events["utility"]:
                lo, hi = (float(v) for v in self.bounds[norm.name])
                x = 0.0 if hi == lo else (float(norm_events["utility"][norm.name]) - lo) / (hi - lo)
                total += self.weights[norm.name] * x
        if ended and self.reset == "per_episode":
            self.charged.clear()
        return self.scale * total / self.weight_sum


def _step(cost: StackedCost, where: str, events: np.ndarray, utility: np.ndarray, ended: np.ndarray) -> np.ndarray:
    """One step of ``cost`` on numpy arrays, or on tensors of the torch device ``where``, as a numpy array."""
    if where == "numpy":
        return cost(events, utility, ended)
    tensors = (th.from_numpy(a).to(where) for a in (events.astype(np.int64), utility, ended))
    return cost(*tensors).cpu().numpy()


@pytest.mark.parametrize(("mode", "reset"), [("minimal", "never"), ("full", "per_episode"), ("partial", "per_episode")])
def test_the_one_cost_is_the_spec_formula_on_the_scalar_env_bit_for_bit(mode: str, reset: str) -> None:
    bounds = bound_pairs()
    assert len({b.chain.name for b in bounds}) >= 4 and len(bounds) >= 98
    spec = RewardCostSpec(cost_mode=mode, cost_reset=reset, cost_scale=2.0)  # type: ignore[arg-type]
    envs = {env_id: morality_gym.TrolleyEnv(env_id, max_steps=15) for env_id in {b.env_id for b in bounds}}
    references = [_SpecCost(b, mode, 2.0, reset) for b in bounds]
    singles = [VectorCost(b, 1, mode=spec.cost_mode, scale=2.0, reset=spec.cost_reset) for b in bounds]
    stacked = {"numpy": StackedCost.for_copies(bounds, spec)} | {d: StackedCost.for_copies(bounds, spec, d) for d in DEVICES}
    rng = np.random.default_rng(5)
    paths = [[] for _ in bounds]  # each copy replays its own env's random episode
    for i, b in enumerate(bounds):
        env = envs[b.env_id]
        env.reset(seed=i)
        for _ in range(STEPS):
            _, _, term, trunc, info = env.step(int(rng.integers(0, 6)))
            paths[i].append((info["norm_events"], term or trunc))
            if term or trunc:
                env.reset()
    nonzero = 0
    for t in range(STEPS):
        want = np.array([ref.step(*paths[i][t]) for i, ref in enumerate(references)])
        single = np.array([c.from_norm_events(paths[i][t][0], ended=paths[i][t][1]) for i, c in enumerate(singles)])
        assert single.tobytes() == want.tobytes(), f"step {t}: the single-env cost differs from the spec's formula"
        events = np.array([names_to_mask(set().union(*(ne[k] for k in ("action", "outcome", "causal"))))
                           for ne, _ in (p[t] for p in paths)], dtype=np.uint32)
        utility = np.array([[float(p[t][0]["utility"].get(n, 0)) for n in UTILITIES] for p in paths])
        ended = np.array([p[t][1] for p in paths])
        for where, cost in stacked.items():
            got = _step(cost, where, events, utility, ended)
            assert got.tobytes() == want.tobytes(), f"step {t}: the stacked cost on {where} differs from the spec's formula"
        nonzero += int((want != 0).sum())
    assert nonzero > 100  # the episodes did cost something


@pytest.mark.parametrize("mode", ["minimal", "full", "partial"])
def test_the_one_cost_sums_many_terms_in_the_specs_order(mode: str) -> None:
    """Steps where many norms fire at once (random event masks and utilities, which the scenarios
    rarely give: there two nonzero terms commute), so that the order of the sum shows in the bits."""
    bounds = bound_pairs()
    spec = RewardCostSpec(cost_mode=mode, cost_reset="per_episode", cost_scale=3.0)  # type: ignore[arg-type]
    references = [_SpecCost(b, mode, 3.0, "per_episode") for b in bounds]
    stacked = {"numpy": StackedCost.for_copies(bounds, spec)} | {d: StackedCost.for_copies(bounds, spec, d) for d in DEVICES}
    rng = np.random.default_rng(11)
    for _ in range(30):
        events = rng.integers(0, 2 ** len(EVENTS), size=len(bounds), dtype=np.uint32)
        utility = rng.integers(0, 9, size=(len(bounds), len(UTILITIES))).astype(np.float64)
        ended = rng.random(len(bounds)) < 0.3
        type_present, living_present = utility_present(events)
        want = []
        for i, ref in enumerate(references):
            names = {n for bit, n in enumerate(EVENTS) if events[i] >> bit & 1}
            shown = {n: utility[i, k] for k, n in enumerate(UTILITIES)
                     if (living_present[i] if n == "n_harm" else type_present[i])}
            want.append(ref.step({"action": names, "outcome": (), "causal": (), "utility": shown}, bool(ended[i])))
        for where, cost in stacked.items():
            got = _step(cost, where, events, utility, ended)
            assert got.tobytes() == np.array(want).tobytes(), f"the stacked cost on {where} differs from the spec's formula"


def _left_fold(terms: np.ndarray) -> np.ndarray:
    total = np.zeros(terms.shape[1])
    for row in terms:
        total = total + row
    return total


@pytest.mark.parametrize("n_copies", [1, 3, 1000])
def test_fold_is_the_left_to_right_sum_where_a_reduction_is_not(n_copies: int) -> None:
    """Terms of very different sizes (what a chain's lexicographic weights give), 1 to 20 of them:
    ``fold`` on numpy and on torch equals ``((0 + t0) + t1) + ...`` bit for bit; ``sum`` over the
    term axis does not on some of them (numpy adds a lone copy's terms as ``t0 + (t1 + ...)``),
    which is why the cost folds instead of reducing."""
    rng = np.random.default_rng(n_copies)
    reduction_differs = False
    for n_terms in range(1, 21):
        terms = rng.standard_normal((n_terms, n_copies)) * 10.0 ** rng.integers(-8, 8, size=(n_terms, n_copies))
        want = _left_fold(terms)
        zero = np.zeros((1, n_copies))
        assert fold([zero, terms]).tobytes() == want.tobytes()
        for device in DEVICES:
            blocks = [th.from_numpy(zero).to(device), th.from_numpy(terms).to(device)]
            assert fold(blocks).cpu().numpy().tobytes() == want.tobytes()
        reduction_differs |= np.concatenate([zero, terms]).sum(0).tobytes() != want.tobytes()
    if n_copies == 1:
        assert reduction_differs  # the evidence that the order matters on these inputs


@pytest.mark.parametrize("mode", ["minimal", "full", "partial"])
def test_copies_that_share_their_terms_are_stepped_as_the_blocks_step_them(mode: str) -> None:
    """A :class:`VectorCost` (all copies one chain on one env id) steps its terms one column at a time
    with scalar parameters, which at 65,536 copies is 1.9x faster than the blocks; it must give the
    blocks' bits (the blocks are held to the spec's formula above), on steps where many norms fire."""
    rng = np.random.default_rng(23)
    for bound in bound_pairs():
        columns = VectorCost(bound, 64, mode=mode, scale=3.0, reset="per_episode")  # type: ignore[arg-type]
        blocks = VectorCost(bound, 64, mode=mode, scale=3.0, reset="per_episode")  # type: ignore[arg-type]
        assert columns._stack._uniform is not None
        blocks._stack._uniform = None
        for _ in range(6):
            events = rng.integers(0, 2 ** len(EVENTS), size=64, dtype=np.uint32)
            utility = rng.integers(0, 9, size=(64, len(UTILITIES))).astype(np.float64)
            ended = rng.random(64) < 0.3
            assert columns(events, utility, ended).tobytes() == blocks(events, utility, ended).tobytes(), bound
