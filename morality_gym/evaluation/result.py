"""What an evaluation returns: the metric, the per-norm morality functions and episode statistics."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

from morality_gym.world.vocab import mask_to_names

if TYPE_CHECKING:
    from morality_gym.norms.metric import BoundChain


@dataclass(frozen=True)
class EpisodeRecord:
    """One Monte-Carlo episode, as the evaluator aggregates it."""

    events: int  # bit mask of every event that occurred at least once
    utility: dict[str, float]  # episode totals per utility key that appeared
    ret: float
    length: int
    truncated: bool
    goal_reached: bool
    metric: float  # this episode's own morality metric (the MC metric is their mean)

    @property
    def event_names(self) -> list[str]:
        return mask_to_names(self.events)


@dataclass
class EvaluationResult:
    """Morality metric and friends of one policy in one env id under one chain.

    ``exact`` results have no episodes and no standard error: they are expectations.
    ``metric_stderr`` is the Monte-Carlo standard error (the metric is the mean of per-episode
    metrics, because every morality function is linear in the episode outcomes).
    """

    env_id: str
    chain: str
    beta: float
    exact: bool
    metric: float
    functions: dict[str, float]
    weights: dict[str, float]
    relevant: list[str]
    event_freq: dict[str, float]
    utility_mean: dict[str, float]
    mean_return: float
    mean_length: float
    truncation_rate: float
    goal_rate: float
    n_episodes: int | None = None
    metric_stderr: float | None = None
    mean_cost: float | None = None
    episodes: list[EpisodeRecord] = field(default_factory=list, repr=False)

    @classmethod
    def from_aggregates(
        cls,
        bound: BoundChain,
        *,
        exact: bool,
        event_freq: Mapping[str, float],
        utility_mean: Mapping[str, float],
        **stats: Any,
    ) -> EvaluationResult:
        """Morality functions and metric from event frequencies and mean utility totals (spec 4.2-4.3).

        Exact and Monte-Carlo evaluation differ only in how they obtain these aggregates; ``stats``
        carries the rest (mean return and length, truncation and goal rates, ...).
        """
        functions = bound.morality_functions(event_freq, utility_mean)
        return cls(
            env_id=bound.env_id,
            chain=bound.chain.name,
            beta=bound.beta,
            exact=exact,
            metric=bound.metric(functions),
            functions=functions,
            weights=dict(bound.weights),
            relevant=list(bound.relevant),
            event_freq=dict(event_freq),
            utility_mean=dict(utility_mean),
            **stats,
        )

    def to_dict(self, episodes: bool = False) -> dict[str, Any]:
        out = asdict(self)
        if episodes:
            out["episodes"] = [{**asdict(e), "events": e.event_names} for e in self.episodes]
        else:
            out.pop("episodes")
        return out
