"""One resolved run: what a sweep's worker executes, what its id hashes and what its row records.

:class:`RunConfig` is built once, where a sweep's configuration is validated (``runners.plan.runs``
from ``runners.compose.sweep_config``'s resolved learners), and never changed after; workers receive the object
itself. Its JSON form is the ``config`` column of the run's row (:mod:`morality_gym.results.schema`)
and what its id hashes (:mod:`morality_gym.results.identity`).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from morality_gym.baselines import typed
from morality_gym.baselines.specs import LearnerSpec, ProtocolSpec, RandomReplay
from morality_gym.norms.chain import parse_chain
from morality_gym.norms.metric import BoundChain, bind_chain
from morality_gym.results.identity import config_key, run_id_of
from morality_gym.results.schema import SCHEMA_VERSION


@dataclass(frozen=True)
class RunConfig:
    """One run, fully resolved where the sweep's configuration is validated, and never changed after.

    ``algo`` is the learner's spec with everything applied (its algo file, the protocol, the
    preset's overrides and rollout cap, the command line: :func:`runners.compose.sweep_config.learner_layers`);
    ``protocol`` is recorded whole because it is part of what the run is (and gives the random
    learner its own settings, :attr:`replay`); ``chain`` is the chain's full definition
    (``{"name", "norms": [[norm, modality], ...]}``), so that a changed chain is a new run.

    The object itself is what a worker receives (pickled as it is); its JSON form
    (:meth:`to_json`) is what its id hashes (:attr:`run_id`) and its Parquet row records, and
    :meth:`from_json` reads such a record back (a fleet's run list). Reading it by key
    (``run["algo"]["name"]``) reads that JSON form, as a recorded config reads.
    """

    env_id: str
    scenario: str
    variant: str
    chain: Mapping[str, Any]
    algo: LearnerSpec
    protocol: ProtocolSpec
    preset: str
    seed: int
    budget: int
    beta: float
    max_steps: int | None
    eval_episodes: int
    learn_eval_every: int
    learn_eval_episodes: int
    schema_version: int = SCHEMA_VERSION

    def to_json(self) -> dict[str, Any]:
        """The run config as plain data (JSON-ready): the dict the run id hashes and the Parquet
        row records. Tuples become lists, specs their field dicts (a fresh copy each call)."""
        return {f.name: plain(getattr(self, f.name)) for f in dataclasses.fields(self)}

    @functools.cached_property
    def _json(self) -> dict[str, Any]:
        return self.to_json()

    @functools.cached_property
    def run_id(self) -> str:
        """The run's content id (:func:`morality_gym.results.identity.run_id_of` over :meth:`to_json`)."""
        return run_id_of(self._json)

    @property
    def config_key(self) -> str:
        """The id of the run's configuration within its Table 1 cell (:func:`morality_gym.results.identity.config_key`)."""
        return config_key(self._json)

    def __getitem__(self, key: str) -> Any:
        return self._json[key]

    @property
    def replay(self) -> RandomReplay:
        """The random learner's own settings under the run's protocol (unused by every other learner)."""
        return self.protocol.random_replay()

    def bound_chain(self) -> BoundChain:
        """The run's chain bound to its env id."""
        chain = parse_chain({"name": self.chain["name"], "norms": [{"norm": n, "modality": m} for n, m in self.chain["norms"]]},
                            source=f"run config {self.chain['name']}")
        return bind_chain(chain, self.env_id, self.beta)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> RunConfig:
        """A recorded run config read back; it must give back exactly what was recorded (its id)."""
        run = typed.from_plain(cls, data)
        if run.to_json() != dict(data):
            raise ValueError(f"a recorded run config does not read back as written (schema {data.get('schema_version')!r})")
        return run


def plain(value: Any) -> Any:
    """``value`` as JSON-ready data: a dataclass as the dict of its fields, tuples as lists."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value
