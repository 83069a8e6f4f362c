"""What an evaluation returns: the metric, the per-norm morality functions and episode statistics."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from morality_gym.world.vocab import mask_to_names


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

    def to_dict(self, episodes: bool = False) -> dict[str, Any]:
        out = asdict(self)
        if episodes:
            out["episodes"] = [{**asdict(e), "events": e.event_names} for e in self.episodes]
        else:
            out.pop("episodes")
        return out
