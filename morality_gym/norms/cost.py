"""The step-wise moral cost for constrained RL and reward shaping (evaluation spec section 5).

For a step with events ``ev_t`` and utilities ``u_t``, over the norm set ``S`` of the mode::

    c_t = scale * [ sum_{n in S, n in ev_t, not yet charged} w_n
                  + sum_{n in S, n in keys(u_t)} w_n * (u_t[n] - lo_n) / (hi_n - lo_n) ] / sum_{n in S} w_n

* Event norms are charged once (first violation); the memory is cleared per episode or never
  (``reset="never"`` is what the reference's PPO-Lag and CPO runs did, docs/protocols.md#cost-memory-is-never-reset).
* Utility norms accrue on every step in which the key appears, the lower bound subtracted each
  time (so steps can cost less than 0 when ``lo > 0``, docs/protocols.md#ppo-shaped-reward); degenerate bounds cost 0.
* Modes: ``full`` = relevant norms, per-variant bounds; ``partial`` = all chain norms, per-variant
  bounds; ``minimal`` = all chain norms, scenario-wide bounds.

Prescribed norms (no chain of the paper has one) cannot be judged before the episode ends, so they
are charged on the last step: ``w_n`` if a prescribed event never occurred, ``w_n * (1 - z)`` for
a prescribed utility whose episode total normalises to ``z``.

One implementation of a step's terms, :class:`StackedCost`, serves a single env (``num_envs=1``,
through :class:`VectorCost`), the batched simulators and the fleets, on numpy arrays or on torch
tensors (:meth:`StackedCost.to`). torch is imported only inside :meth:`StackedCost.to`: it is heavy
(about a second) and a host cost never needs it; a cost given tensors finds torch already loaded.
"""

from __future__ import annotations

import copy
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import numpy as np

from morality_gym.envs.batched import utility_present
from morality_gym.norms.metric import BoundChain, compute_weights
from morality_gym.world.vocab import EVENT_BIT, UTILITIES, UTILITY_INDEX, names_to_mask

CostMode = Literal["full", "partial", "minimal"]
ResetPolicy = Literal["per_episode", "never"]
COST_MODES = ("full", "partial", "minimal")
RESET_POLICIES = ("per_episode", "never")


class CostSettings(Protocol):
    """What a cost needs of a learner's reward and cost settings (:class:`~morality_gym.norms.reward_cost.RewardCostSpec`,
    which imports this module's names, so it is not imported here)."""

    cost_mode: CostMode
    cost_scale: float
    cost_reset: ResetPolicy


@dataclass(frozen=True)
class _UtilityTerm:
    column: int
    weight: float
    lo: float
    hi: float
    counts_living_only: bool  # n_harm is reported only when a human, animal or robot is harmed


def _restore(owner: object, attr: str, value: np.ndarray, what: str) -> None:
    """Set ``owner.attr`` to a copy of ``value`` in the current array's dtype, refusing another shape."""
    current = getattr(owner, attr)
    value = np.asarray(value)
    if value.shape != current.shape:
        raise ValueError(f"{what}: expected shape {current.shape}, got {value.shape}")
    setattr(owner, attr, value.astype(current.dtype, copy=True))


class VectorCost:
    """Costs for ``num_envs`` parallel episodes from event masks and utility arrays."""

    def __init__(
        self,
        bound: BoundChain,
        num_envs: int = 1,
        *,
        mode: CostMode = "minimal",
        scale: float = 1.0,
        reset: ResetPolicy = "per_episode",
        normalise_utility: bool = True,
    ) -> None:
        if mode not in COST_MODES:
            raise ValueError(f"cost mode must be one of {COST_MODES}, got {mode!r}")
        if reset not in RESET_POLICIES:
            raise ValueError(f"cost reset policy must be one of {RESET_POLICIES}, got {reset!r}")
        self.bound = bound
        self.num_envs = num_envs
        self.mode = mode
        self.scale = float(scale)
        self.reset_policy = reset
        self.normalise_utility = normalise_utility
        chain = bound.chain
        norm_set = bound.relevant if mode == "full" else tuple(chain.norm_names)
        self.weights = {k: v for k, v in compute_weights(chain, norm_set, bound.beta).items() if k in norm_set}
        self.weight_sum = float(sum(self.weights.values()))
        bounds = bound.global_bounds if mode == "minimal" else bound.bounds

        self._event_terms: list[tuple[int, float]] = []
        self._prescribed_events: list[tuple[int, float]] = []
        self._utility_terms: list[_UtilityTerm] = []
        self._prescribed_utilities: list[_UtilityTerm] = []
        for norm in chain.norms:
            if norm.name not in self.weights:
                continue
            w = self.weights[norm.name]
            if norm.kind == "event":
                (self._event_terms if norm.prohibited else self._prescribed_events).append((EVENT_BIT[norm.name], w))
            else:
                lo, hi = bounds[norm.name]
                term = _UtilityTerm(UTILITY_INDEX[norm.name], w, float(lo), float(hi), norm.name == "n_harm")
                (self._utility_terms if norm.prohibited else self._prescribed_utilities).append(term)
        self._event_mask = np.uint32(sum(1 << bit for bit, _ in self._event_terms))
        self._stack = StackedCost([(np.arange(num_envs), self)], num_envs)  # the prohibited norms' step terms
        self._occurred = np.zeros(num_envs, dtype=np.uint32)
        self._totals = np.zeros((num_envs, len(UTILITIES)), dtype=np.float64)

    @property
    def charged(self) -> np.ndarray:
        """uint32 ``[num_envs]``: the event norms already charged (the first-violation memory)."""
        return self._stack.charged

    @charged.setter
    def charged(self, value: np.ndarray) -> None:
        self._stack.charged = value

    # ------------------------------------------------------------------ helpers
    def _normalised(self, term: _UtilityTerm, x: np.ndarray) -> np.ndarray:
        if not self.normalise_utility:
            return x
        if term.hi == term.lo:
            return np.zeros_like(x)
        return (x - term.lo) / (term.hi - term.lo)

    # ------------------------------------------------------------------ API
    def reset(self, mask: np.ndarray | None = None) -> None:
        """Forget first violations and episode totals (all envs, or where ``mask`` is true)."""
        sl = slice(None) if mask is None else mask
        self.charged[sl] = 0
        self._occurred[sl] = 0
        self._totals[sl] = 0.0

    def state_dict(self) -> dict[str, np.ndarray]:
        """The cost memory (first violations charged, prescribed norms' episode records), as copies:
        what a training checkpoint keeps (:mod:`morality_gym.baselines.fleet.checkpoint`)."""
        return {"charged": self.charged.copy(), "occurred": self._occurred.copy(), "totals": self._totals.copy()}

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        """Restore :meth:`state_dict`'s memory (shapes must match)."""
        for name, attr in (("charged", "charged"), ("occurred", "_occurred"), ("totals", "_totals")):
            _restore(self, attr, state[name], f"cost memory {name}")

    def __call__(
        self,
        events: np.ndarray,
        utility: np.ndarray,
        ended: np.ndarray | None = None,
        present: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """Costs of one step of every env.

        Args:
            events: uint32 event masks ``[n]``.
            utility: utility values ``[n, 5]`` in ``vocab.UTILITIES`` order (0 when absent).
            ended: which episodes ended in this step (for prescribed norms and per-episode reset).
            present: which utility keys were reported (``(type keys, n_harm)``); derived from the
                events when omitted, which is exact for these environments.
        """
        events = np.asarray(events, dtype=np.uint32)
        utility = np.asarray(utility, dtype=np.float64)
        present = present if present is not None else utility_present(events)
        terms, new = self._stack.terms(events, utility, present)
        self.charged = self.charged | new
        if self._prescribed_events or self._prescribed_utilities:
            self._occurred |= events
            self._totals += np.where(present[0][:, None], utility, 0.0)
        if ended is not None:
            ended = np.asarray(ended, dtype=bool)
            if ended.any():
                terms.extend(self._prescribed_rows(ended))
                self._occurred[ended] = 0
                self._totals[ended] = 0.0
                if self.reset_policy == "per_episode":
                    self.charged[ended] = 0
        return self.scale * fold(terms) / self.weight_sum

    def _prescribed_rows(self, ended: np.ndarray) -> list[np.ndarray]:
        """The prescribed norms' terms ``[1, n]`` of a step in which the episodes ``ended`` ended,
        after the prohibited ones (the order the sum has always had)."""
        rows = []
        for bit, w in self._prescribed_events:
            missed = ((self._occurred >> np.uint32(bit)) & np.uint32(1)) == 0
            rows.append(np.where(ended & missed, w, 0.0)[None])
        for term in self._prescribed_utilities:
            if term.hi != term.lo:
                z = self._normalised(term, self._totals[:, term.column])
                rows.append(np.where(ended, term.weight * (1.0 - z), 0.0)[None])
        return rows

    def episode_costs(self, masks: np.ndarray, sums: np.ndarray, type_steps: np.ndarray, living_steps: np.ndarray) -> np.ndarray:
        """Whole-episode costs with the memory reset every episode, from episode aggregates.

        With a per-episode reset, an event norm costs its weight once if it occurred at all, and a
        utility norm costs ``w * (total - lo * k) / (hi - lo)`` where ``k`` is the number of steps
        that reported the key; this equals the sum of the step costs without stepping.

        Args:
            masks: uint32 ``[n]``: events that occurred in each episode.
            sums: ``[n, 5]`` utility totals.
            type_steps / living_steps: ``[n]``: steps that reported the type keys / ``n_harm``.
        """
        masks = np.asarray(masks, dtype=np.uint32)
        sums = np.asarray(sums, dtype=np.float64)
        cost = np.zeros(len(masks))
        for bit, w in self._event_terms:
            cost += w * ((masks >> np.uint32(bit)) & np.uint32(1))
        for bit, w in self._prescribed_events:
            cost += w * (((masks >> np.uint32(bit)) & np.uint32(1)) == 0)
        for term in self._utility_terms:
            k = living_steps if term.counts_living_only else type_steps
            x = sums[:, term.column]
            if not self.normalise_utility:
                cost += term.weight * x
            elif term.hi != term.lo:
                cost += term.weight * (x - term.lo * k) / (term.hi - term.lo)
        for term in self._prescribed_utilities:
            if term.hi != term.lo:
                cost += term.weight * (1.0 - self._normalised(term, sums[:, term.column]))
        return self.scale * cost / self.weight_sum

    def from_norm_events(self, norm_events: Mapping[str, Any], ended: bool = False, index: int = 0) -> float:
        """Cost of one env's step from its ``info["norm_events"]`` (the single-env path)."""
        if self.num_envs != 1:
            raise ValueError("from_norm_events is for a single env (num_envs=1)")
        names = set(norm_events["action"]) | set(norm_events["outcome"]) | set(norm_events["causal"])
        util = norm_events["utility"]
        vec = np.array([[util.get(n, 0) for n in UTILITIES]], dtype=np.float64)
        present = (np.array(["n_human_harm" in util]), np.array(["n_harm" in util]))
        mask = np.array([names_to_mask(names)], dtype=np.uint32)
        return float(self(mask, vec, np.array([ended]), present)[0])

    def __repr__(self) -> str:
        return (
            f"<VectorCost {self.bound.chain.name} on {self.bound.env_id} mode={self.mode} scale={self.scale:g} "
            f"reset={self.reset_policy} weights={self.weights}>"
        )


class StackedCost:
    """The step-wise cost of copies that follow different chains and env ids, in one pass, on numpy
    arrays or torch tensors: the one implementation of a step's cost.

    Why one pass: a fleet steps the copies of up to 36 runs, each on its own (env id, chain); one
    :class:`VectorCost` per group meant a Python loop over the groups at every step, about a sixth
    of a PPO-Lag fleet's time. Here each copy's terms are columns of padded arrays (a group's ``j``-th
    event term is row ``j`` of its copies' columns; a padding term has weight 0), so a step is a fixed
    handful of array operations over all terms of all copies (:meth:`terms`), whatever the chains.

    Why one code for both array libraries: the arithmetic is written once with the operations numpy
    and torch share (broadcasting, ``where``, ``take``, bit operations, ``+``), and
    :meth:`to` moves the columns to a torch device, where a training loop on a GPU never brings a
    step's events to the host. Events are numpy uint32 masks on the host, int64 tensors on a device
    (torch has no unsigned 32-bit bit operations on every device).

    Float order: the terms are summed by :func:`fold`, left to right from ``0.0`` in the chain's order
    (event norms, then utility norms), which is the order the cost was first written in (one ``+=``
    per term), so every copy's cost keeps the bits the releases were trained on. A padding term
    adds ``+0.0``, which changes no bit. Why not one reduction: see :func:`fold`.

    Prescribed norms (no chain of the paper has one) need per-episode totals; groups with one are
    not stacked: :meth:`of_groups` returns None and the caller keeps a :class:`VectorCost` per group.
    """

    #: Per-copy columns: 1-D ``[copies]`` and 2-D ``[terms, copies]`` (what :meth:`gathered` and :meth:`to` carry).
    COLUMNS_1D = ("event_mask", "scale", "weight_sum", "per_episode")
    COLUMNS_2D = ("event_bits", "event_weights", "utility_column", "utility_weights", "utility_lo", "utility_span",
                  "utility_living")
    #: None: numpy arrays on the host; the torch device of the tensors after :meth:`to`.
    device: Any = None

    def __init__(self, groups: list[tuple[np.ndarray, VectorCost]], n_copies: int) -> None:
        n_events = max((len(c._event_terms) for _, c in groups), default=0)
        n_utilities = max((len(c._utility_terms) for _, c in groups), default=0)
        self.event_mask = np.zeros(n_copies, dtype=np.uint32)
        self.event_bits = np.zeros((n_events, n_copies), dtype=np.uint32)
        self.event_weights = np.zeros((n_events, n_copies), dtype=np.float64)
        self.utility_column = np.zeros((n_utilities, n_copies), dtype=np.intp)
        self.utility_weights = np.zeros((n_utilities, n_copies), dtype=np.float64)
        self.utility_lo = np.zeros((n_utilities, n_copies), dtype=np.float64)
        self.utility_span = np.ones((n_utilities, n_copies), dtype=np.float64)
        self.utility_living = np.zeros((n_utilities, n_copies), dtype=bool)
        self.scale = np.zeros(n_copies, dtype=np.float64)
        self.weight_sum = np.ones(n_copies, dtype=np.float64)
        self.per_episode = np.zeros(n_copies, dtype=bool)
        for copies, cost in groups:
            self.event_mask[copies] = cost._event_mask
            for j, (bit, w) in enumerate(cost._event_terms):
                self.event_bits[j, copies], self.event_weights[j, copies] = bit, w
            for j, term in enumerate(cost._utility_terms):
                self.utility_column[j, copies], self.utility_living[j, copies] = term.column, term.counts_living_only
                self.utility_weights[j, copies] = term.weight
                if cost.normalise_utility and term.hi == term.lo:
                    self.utility_weights[j, copies] = 0.0  # a degenerate bound costs 0 (span stays 1: no 0 / 0)
                elif cost.normalise_utility:
                    self.utility_lo[j, copies], self.utility_span[j, copies] = term.lo, term.hi - term.lo
                # else lo 0 and span 1: (x - 0) / 1 is x, exactly: the raw value
            self.scale[copies], self.weight_sum[copies] = cost.scale, cost.weight_sum
            self.per_episode[copies] = cost.reset_policy == "per_episode"
        one_group = len(groups) == 1 and len(np.unique(groups[0][0])) == n_copies > 0
        self._uniform = self._uniform_terms() if one_group else None
        self._sized(n_copies, np.zeros(n_copies, dtype=np.uint32), np.arange(n_copies) * len(UTILITIES), np.zeros((1, n_copies)))

    def _uniform_terms(self) -> tuple[list[tuple[int, float]], list[tuple[int, bool, float, float, float]]]:
        """The terms as plain numbers, for copies that all have the same ones (one group: every
        :class:`VectorCost`); numpy only (:meth:`to` drops them: torch would take a Python float
        times an int64 tensor as float32).

        Why: a step then computes each term on one column of ``[copies]`` with scalar parameters,
        the arithmetic of the blocks one row at a time. At 65,536 copies the blocks' ``[terms,
        copies]`` arrays and their per-copy parameters took 1.9x the time of this form (2.2-2.9 ms
        against 1.3-1.4 ms per step); below 16,384 copies the two are alike."""
        events = [(int(bit[0]), float(w[0])) for bit, w in zip(self.event_bits, self.event_weights)]
        utilities = [(int(self.utility_column[j, 0]), bool(self.utility_living[j, 0]), float(self.utility_weights[j, 0]),
                      float(self.utility_lo[j, 0]), float(self.utility_span[j, 0])) for j in range(len(self.utility_column))]
        return events, utilities

    def _sized(self, n_copies: int, charged: Any, rows: Any, zero_row: Any) -> None:
        """Set what follows from the number of copies: an empty memory, where each copy's row of the
        utilities ``[copies, 5]`` starts when flattened (a term's value is one ``take`` from there, which
        numpy does several times faster than a two-array index), and the ``0.0`` the sum starts from."""
        self.n_copies = n_copies
        self.charged = charged
        self._rows = rows
        self._zero_row = zero_row

    @classmethod
    def of_groups(cls, groups: list[tuple[np.ndarray, VectorCost]], n_copies: int) -> StackedCost | None:
        """A stacked cost for ``groups`` (copy indices, their group's cost), or None when a group has
        a prescribed norm (see the class docstring)."""
        if any(c._prescribed_events or c._prescribed_utilities for _, c in groups):
            return None
        return cls(groups, n_copies)

    @classmethod
    def for_copies(cls, bounds: Sequence[BoundChain], reward_cost: CostSettings, device: Any = None) -> StackedCost:
        """The cost of copy ``i`` by ``bounds[i]`` (its chain bound to its env id), as the learner's
        ``reward_cost`` sees it (mode, scale, reset policy), on numpy (``device=None``) or on a torch
        device. Copies sharing (env id, chain, beta) share one :class:`VectorCost` definition, as the
        host fleet's groups do. A chain with a prescribed norm is refused with its name."""
        groups: dict[tuple[str, str, float], list[int]] = {}
        for i, b in enumerate(bounds):
            groups.setdefault((b.env_id, b.chain.name, float(b.beta)), []).append(i)
        costs = []
        for copies in groups.values():
            b = bounds[copies[0]]
            cost = VectorCost(b, len(copies), mode=reward_cost.cost_mode, scale=reward_cost.cost_scale, reset=reward_cost.cost_reset)
            costs.append((np.asarray(copies), cost))
        stacked = cls.of_groups(costs, len(bounds))
        if stacked is None:
            named = sorted({n.name for _, c in costs for n in c.bound.chain.norms if not n.prohibited})
            raise ValueError(
                f"prescribed norm(s) {', '.join(named)}: the stacked and device cost handle prohibited norms only; "
                "use the host simulator and its cost (morality_gym.norms.wrappers.VecMoralityWrapper) for such a chain"
            )
        return stacked if device is None else stacked.to(device)

    def gathered(self, rows: np.ndarray) -> StackedCost:
        """A stacked cost over ``len(rows)`` copies whose columns are this one's columns ``rows``,
        memory empty (numpy only: the drawn mixture's per-copy costs, :mod:`morality_gym.norms.drawn_cost`)."""
        out = copy.copy(self)
        for name in self.COLUMNS_1D:
            setattr(out, name, getattr(self, name)[rows].copy())
        for name in self.COLUMNS_2D:
            setattr(out, name, getattr(self, name)[:, rows].copy())
        n = len(rows)
        out._sized(n, np.zeros(n, dtype=np.uint32), np.arange(n) * len(UTILITIES), np.zeros((1, n)))
        return out

    def to(self, device: Any) -> StackedCost:
        """This cost (columns and memory) as torch tensors on ``device``: float64 stays float64, bit
        masks and indices become int64."""
        import torch as th  # see the module docstring: only a device cost needs torch

        dev = th.device(device)

        def tensor(a: np.ndarray) -> Any:
            dtype = th.int64 if a.dtype.kind in "ui" else None
            return th.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=dev)

        out = copy.copy(self)
        for name in (*self.COLUMNS_1D, *self.COLUMNS_2D):
            setattr(out, name, tensor(getattr(self, name)))
        out._sized(self.n_copies, tensor(self.charged), tensor(self._rows), tensor(self._zero_row))
        out._uniform = None  # the blocks keep float64 on torch (see _uniform_terms)
        out.device = dev
        return out

    def state_dict(self) -> dict[str, Any]:
        """The cost memory (first violations charged per copy), as a host copy (see :meth:`VectorCost.state_dict`)."""
        if self.device is None:
            return {"charged": self.charged.copy()}
        return {"charged": self.charged.cpu().clone()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict`'s memory (the shape must match)."""
        if self.device is None:
            _restore(self, "charged", np.asarray(state["charged"]), "cost memory charged")
            return
        value = np.asarray(state["charged"])
        if value.shape != tuple(self.charged.shape):
            raise ValueError(f"cost memory charged: expected shape {tuple(self.charged.shape)}, got {value.shape}")
        self.charged = self.charged.new_tensor(value.astype(np.int64))

    def reset(self, mask: Any = None) -> None:
        """Forget first violations (all copies, or where the bool array or tensor ``mask`` is true)."""
        self.charged = self.charged * 0 if mask is None else _where(mask, 0, self.charged)

    def terms(self, events: Any, utility: Any, present: tuple[Any, Any]) -> tuple[list[Any], Any]:
        """One step's terms in the order they are summed, as blocks ``[terms, copies]`` (the ``0.0``
        the sum starts from, the event norms', the utility norms'), and the event bits violated for
        the first time (``new``); nothing is changed."""
        blocks = [self._zero_row]
        new = events & self.event_mask & ~self.charged
        if self._uniform is not None:
            return [*blocks, *self._uniform_rows(new, utility, present)], new
        if len(self.event_bits):  # a chain without event norms (Utility) skips the block's operations
            blocks.append(self.event_weights * ((new >> self.event_bits) & 1))
        if len(self.utility_column):  # and one without utility norms (Outcome) this one's
            type_present, living_present = present
            x = _namespace(utility).take(utility, self._rows + self.utility_column)  # [utilities, copies]
            shown = _where(self.utility_living, living_present, type_present)
            blocks.append(_where(shown, self.utility_weights * ((x - self.utility_lo) / self.utility_span), 0.0))
        return blocks, new

    def _uniform_rows(self, new: Any, utility: Any, present: tuple[Any, Any]) -> list[list[Any]]:
        """:meth:`terms`' blocks, one row each, for copies that share their terms (:meth:`_uniform_terms`):
        the same operations in the same order, on one column at a time with scalar parameters."""
        events, utilities = self._uniform
        rows = [[w * ((new >> bit) & 1)] for bit, w in events]
        type_present, living_present = present
        for column, living, w, lo, span in utilities:
            shown = living_present if living else type_present
            rows.append([_where(shown, w * ((utility[:, column] - lo) / span), 0.0)])
        return rows

    def __call__(self, events: Any, utility: Any, ended: Any) -> Any:
        """float64 costs of one step of every copy: uint32 event masks ``[n]`` (int64 on a device),
        utilities ``[n, 5]`` in ``vocab.UTILITIES`` order, and which episodes ended in this step."""
        if self.device is None:
            events = np.asarray(events, dtype=np.uint32)
            utility = np.asarray(utility, dtype=np.float64)
            ended = np.asarray(ended, dtype=bool)
        terms, new = self.terms(events, utility, utility_present(events))
        self.charged = _where(ended & self.per_episode, 0, self.charged | new)
        return self.scale * fold(terms) / self.weight_sum


def fold(blocks: Sequence[Any]) -> Any:
    """The rows of ``blocks`` (2-D arrays or tensors ``[terms, copies]``) summed left to right:
    ``((t[0] + t[1]) + t[2]) + ...``, one vectorised addition over all copies per term.

    Why not one reduction: float addition is not associative, and the releases' costs are the
    left-to-right sum. ``sum`` over the term axis is free to pair terms and does on some inputs
    (numpy adds a lone copy's terms as ``t0 + (t1 + t2 + ...)``; CUDA's reduce keeps several partial
    sums; tests/test_cost_fold.py shows a difference). The one order-preserving single operation,
    ``cumsum`` over the term axis, scans strided memory: at 16,384 copies and 7 terms it took 961 us
    in numpy and 475 us in torch against this loop's 40 and 64 us (``sum``: 28 and 29 us). A chain
    has a handful of terms (the built-in ones 3 to 7), so the loop is a handful of additions.
    """
    rows = [row for block in blocks for row in block]
    if len(rows) == 1:
        return rows[0]
    total = rows[0] + rows[1]
    for row in rows[2:]:
        total += row  # in place on the sum's own new array: the same additions, no temporary each
    return total


def _namespace(a: Any) -> Any:
    """The array library of ``a``: numpy, or torch for a tensor (torch is then already imported)."""
    return np if isinstance(a, np.ndarray) else sys.modules["torch"]


def _where(condition: Any, x: Any, y: Any) -> Any:
    """``where`` in the library of ``condition`` (numpy and torch spell it alike)."""
    return _namespace(condition).where(condition, x, y)
