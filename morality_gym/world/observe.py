"""Observation encoding: the flat vector of the reference (layout, order and values) and a dict view.

The flat layout is part of the benchmark: agents trained on it, and the conformance traces
compare it to 1e-6. It is therefore reproduced exactly, including raw group sizes in the
"normalised" vector, positions divided by H and W (not H-1 and W-1) and a per-character one-hot
order (docs/protocols.md#observation-values). Unlike the reference, the declared space is correct: the upper bound of each group
size is the largest size any variant of the scenario uses, so ``observation_space.contains(obs)`` always holds
and all variants of a scenario share one space (agents can be moved between them).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces

from morality_gym.world.rules import (
    AGENT_HARMED,
    AGENT_TERMINATED,
    CHARACTER_HARMED,
    TROLLEY_HARMED,
    TROLLEY_TERMINATED,
    State,
    World,
)


@dataclass(frozen=True)
class Field:
    """One component of one observed entity, and where it sits in the flat vector."""

    entity: str
    name: str
    offset: int
    width: int


def flat_key(field: Field) -> str:
    """The key of a component in the one-level dict observation: ``player/pos``."""
    return f"{field.entity}/{field.name}"


class ObservationCodec:
    """Turns kernel states into observations for one world.

    Entity order: player, levers, characters, trolleys (spec 6.1); components per entity in the
    reference's fixed order.
    """

    def __init__(self, world: World, normalise: bool = True) -> None:
        self.world = world
        self.normalise = normalise
        scn = world.scenario
        fields: list[Field] = []
        low: list[float] = []
        high: list[float] = []
        pos_high = [1.0, 1.0] if normalise else [float(scn.height - 1), float(scn.width - 1)]

        def add(entity: str, name: str, width: int, hi: list[float]) -> None:
            fields.append(Field(entity, name, len(low), width))
            low.extend([0.0] * width)
            high.extend(hi)

        add("player", "pos", 2, pos_high)
        add("player", "is_harmed", 1, [1.0])
        add("player", "is_terminated", 1, [1.0])
        for lever in scn.levers:
            add(lever.name, "curr_state", lever.n_states, [1.0] * lever.n_states)
        for k, spec in enumerate(scn.characters):
            largest = max(v.amounts[k] for v in scn.variants.values())
            add(spec.name, "pos", 2, pos_high)
            add(spec.name, "is_harmed", 1, [1.0])
            add(spec.name, "amount", 1, [float(largest)])
            add(spec.name, "character_type", 3, [1.0, 1.0, 1.0])
        for i in range(len(scn.trolley_starts)):
            add(f"trolley_{i}", "pos", 2, pos_high)
            add(f"trolley_{i}", "is_harmed", 1, [1.0])
            add(f"trolley_{i}", "is_actable", 1, [1.0])
        self.fields: tuple[Field, ...] = tuple(fields)
        self.size = len(low)
        self.low = np.array(low, dtype=np.float64)
        self.high = np.array(high, dtype=np.float64)
        self._type_onehots = tuple(
            tuple(1.0 if t == kind else 0.0 for t in spec.onehot)
            for spec, kind in zip(scn.characters, world.char_types)
        )

    # ------------------------------------------------------------------ spaces
    def flat_space(self, dtype: type = np.float64) -> spaces.Box:
        """The Box of the flat vector, with correct upper bounds (not the reference's Box(0, 1))."""
        return spaces.Box(self.low.astype(dtype), self.high.astype(dtype), dtype=dtype)

    def dict_space(self) -> spaces.Dict:
        """A Dict of Dicts mirroring :meth:`as_dict`, one Box per component.

        The mappings are ``OrderedDict``s because Gymnasium sorts the keys of a plain dict: the
        space would then list ``character_1`` before ``player``, and ``gymnasium.spaces.flatten``
        (used by ``FlattenObservation``) would give a vector in a different order from the flat
        observation.
        """
        entities: OrderedDict[str, OrderedDict[str, spaces.Box]] = OrderedDict()
        for f in self.fields:
            sl = slice(f.offset, f.offset + f.width)
            entities.setdefault(f.entity, OrderedDict())[f.name] = spaces.Box(self.low[sl], self.high[sl], dtype=np.float64)
        return spaces.Dict(OrderedDict((name, spaces.Dict(comp)) for name, comp in entities.items()))

    def flat_dict_space(self, dtype: type = np.float64) -> spaces.Dict:
        """One level of ``{"entity/component": Box}`` in the flat vector's order (:meth:`as_flat_dict`).

        Stable-Baselines3's ``MultiInputPolicy`` and Gymnasium's vector envs refuse nested Dict
        spaces, so the nested :meth:`dict_space` cannot be trained on; this one can. The separator
        is ``/`` because SB3 keeps one torch module per key and torch forbids ``.`` in module names.
        """
        return spaces.Dict(OrderedDict(
            (flat_key(f), spaces.Box(self.low[f.offset : f.offset + f.width].astype(dtype),
                                     self.high[f.offset : f.offset + f.width].astype(dtype), dtype=dtype))
            for f in self.fields))

    # ------------------------------------------------------------------ encoding
    def _pos(self, cell: int) -> tuple[float, float]:
        r, c = divmod(cell, self.world.width)
        if self.normalise:
            return r / self.world.height, c / self.world.width
        return float(r), float(c)

    def flat(self, state: State) -> list[float]:
        """The flat observation of ``state`` as a list of floats (same values as the reference)."""
        agent, aflags, levers, chars, trolleys = state
        out: list[float] = [*self._pos(agent), float(aflags & AGENT_HARMED), 1.0 if aflags & AGENT_TERMINATED else 0.0]
        for value, n in zip(levers, self.world.lever_states):
            out.extend(1.0 if k == value else 0.0 for k in range(n))
        for (cell, flags, _), amount, onehot in zip(chars, self.world.char_amounts, self._type_onehots):
            out.extend(self._pos(cell))
            out.append(float(flags & CHARACTER_HARMED))
            out.append(float(amount))
            out.extend(onehot)
        for cell, flags in trolleys:
            out.extend(self._pos(cell))
            out.append(float(flags & TROLLEY_HARMED))
            out.append(0.0 if flags & TROLLEY_TERMINATED else 1.0)
        return out

    def as_dict(self, state: State) -> dict[str, dict[str, np.ndarray]]:
        """``{entity: {component: array}}``; concatenating the arrays in order gives :meth:`flat`."""
        vec = np.asarray(self.flat(state), dtype=np.float64)
        out: dict[str, dict[str, np.ndarray]] = {}
        for f in self.fields:
            out.setdefault(f.entity, {})[f.name] = vec[f.offset : f.offset + f.width].copy()
        return out

    def as_flat_dict(self, vec: np.ndarray) -> dict[str, np.ndarray]:
        """``{"entity/component": array}`` cut from a flat observation ``vec`` (copies)."""
        return {flat_key(f): np.array(vec[f.offset : f.offset + f.width], dtype=np.float64) for f in self.fields}

    def layout(self) -> list[dict[str, object]]:
        """The flat layout as ``[{entity, field, offset, width}, ...]`` (as in the conformance INDEX)."""
        return [{"entity": f.entity, "field": f.name, "offset": f.offset, "width": f.width} for f in self.fields]
