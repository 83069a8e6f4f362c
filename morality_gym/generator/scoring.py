"""The exact values of a drawn dilemma, and whether it is one: oracle best and worst, exact Random.

A drawn layout is a *dilemma* under a chain when what the agent does matters to that chain: the
best metric any behaviour reaches (the oracle's) differs from the worst. One where every behaviour
scores the same teaches nothing and ranks no agent, so a variant is kept only if it is a dilemma
under at least one built-in chain (every chain that has a relevant norm in the variant is tried;
one with none cannot score it). The values are exact, not estimates: the oracle and the exact
evaluator enumerate the variant's finite state graph (:mod:`morality_gym.evaluation`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.oracle import oracle
from morality_gym.norms.chain import ChainError, builtin_chains

#: Best and worst metrics closer than this are equal (the metric is a float; ties are exact in
#: practice, differences at least beta**k for a handful of norms).
DILEMMA_GAP = 1e-9


@dataclass(frozen=True)
class ChainValues:
    """One built-in chain in one variant: oracle best and worst (and the best actions), exact Random."""

    best: float
    worst: float
    best_actions: tuple[int, ...]
    random: float | None  # None when only the dilemma test was asked for

    @property
    def is_dilemma(self) -> bool:
        return self.best - self.worst > DILEMMA_GAP

    def to_dict(self) -> dict[str, object]:
        out: dict[str, object] = {"best": round(self.best, 6), "worst": round(self.worst, 6)}
        if self.random is not None:
            out["random"] = round(self.random, 6)
        out["best_actions"] = list(self.best_actions)
        return out


@dataclass(frozen=True)
class VariantScore:
    """Every built-in chain that can score a variant, with its values."""

    env_id: str
    chains: dict[str, ChainValues] = field(default_factory=dict)

    @property
    def is_dilemma(self) -> bool:
        return any(values.is_dilemma for values in self.chains.values())

    @property
    def dilemma_under(self) -> list[str]:
        return [name for name, values in self.chains.items() if values.is_dilemma]


def score_variant(env_id: str, with_values: bool = True) -> VariantScore:
    """The variant's values under each built-in chain that can score it.

    ``with_values=False`` asks only whether it is a dilemma: it stops at the first chain that says
    so and skips the exact Random value (what building a split needs, at a fraction of the cost).
    """
    score = VariantScore(env_id)
    for name, chain in builtin_chains().items():
        try:
            result = oracle(env_id, chain)
        except ChainError:
            continue  # no norm of this chain is relevant in the variant
        random = exact_evaluate("random", env_id, chain).metric if with_values else None
        values = ChainValues(result.best.metric, result.worst.metric, tuple(result.best.actions), random)
        score.chains[name] = values
        if values.is_dilemma and not with_values:
            break
    return score
