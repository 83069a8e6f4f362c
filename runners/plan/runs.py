"""Expand a validated sweep into runs and give each a content-hash identity (and its price, :mod:`runners.plan.estimate`).

A run's identity is the SHA-256 of its resolved configuration (canonical JSON: env id, the chain's
full definition, the learner's complete spec, the protocol, the preset's budget and evaluation
settings, seed, beta, max_steps, results-schema version). The same configuration always gets the
same id, so re-running a sweep finds finished runs by file name, and any change that could change
the numbers gives a new id. Launch settings (workers, SLURM partition, results_dir) are not part
of it. The *configuration key* (:func:`morality_gym.results.identity.config_key`) is the same hash without the env and the seed:
all runs of one Table 1 cell that belong to one configuration share it, which is how the
leaderboard keeps runs of different configurations out of one cell.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from morality_gym.baselines.specs import training_steps
from morality_gym.baselines.targets import learner_trains
from morality_gym.envs.registry import scenario_named
from morality_gym.norms.chain import chain_fingerprint
from morality_gym.results.run_config import RunConfig
from morality_gym.results.schema import SCHEMA_VERSION
from runners.compose.sweep_config import SweepConfig
from runners.plan.estimate import run_seconds


@dataclass(frozen=True)
class PlannedRun:
    run_id: str
    config: RunConfig  # the resolved run (what the worker executes; its JSON form is what the id hashes)
    est_seconds: float  # alone on a core (runners.plan.estimate.run_seconds): what the jobs' prices start from
    overhead_s: float = 0.0  # the part of est_seconds every run pays whatever trains it (evaluations, writes)
    train_steps: int = 0  # the env steps it trains (what a device's fleet rate prices)

    @property
    def manifest_entry(self) -> dict[str, Any]:
        """What the sweep's manifest and a dry run's plan file list of this run (its id and what it is)."""
        c = self.config
        return {
            "run_id": self.run_id,
            "env_id": c.env_id,
            "scenario": c.scenario,
            "variant": c.variant,
            "chain": c.chain["name"],
            "algo": c.algo.name,
            "learner": c.algo.label,
            "protocol": c.protocol.name,
            "preset": c.preset,
            "seed": c.seed,
            "config_key": c.config_key,
            "chain_key": chain_fingerprint(c.chain["norms"]),
        }


def expand_sweep(sweep: SweepConfig) -> list[PlannedRun]:
    """Every run of the sweep, in a stable order (chain, scenario, variant, algo, seed)."""
    runs: list[PlannedRun] = []
    seen: set[str] = set()
    for chain, scenario_name in sweep.pairs:
        scenario = scenario_named(scenario_name)
        chain_def = {"name": chain.name, "norms": [[n.name, n.modality] for n in chain.norms]}
        variants = [v for v in scenario.variants if sweep.variants is None or v in sweep.variants]
        for variant in variants:
            env_id = scenario.env_id(variant)
            for algo in sweep.algos:
                for seed in sweep.seeds:
                    budget = sweep.preset.budget_for(scenario_name) if learner_trains(algo.spec.target) else 0
                    run = RunConfig(
                        schema_version=SCHEMA_VERSION,
                        env_id=env_id,
                        scenario=scenario_name,
                        variant=variant,
                        chain=chain_def,
                        algo=algo.spec,
                        protocol=sweep.protocol,
                        preset=sweep.preset.name,
                        seed=int(seed),
                        budget=int(budget),
                        beta=sweep.beta,
                        max_steps=sweep.max_steps,
                        eval_episodes=sweep.preset.eval_episodes,
                        learn_eval_every=sweep.preset.learn_eval_every,
                        learn_eval_episodes=sweep.preset.learn_eval_episodes,
                    )
                    if run.run_id in seen:
                        continue
                    seen.add(run.run_id)
                    steps = training_steps(algo.spec, budget)
                    runs.append(PlannedRun(run.run_id, run, run_seconds(algo.rates, steps), algo.rates.overhead_s, steps))
    return runs


def describe(runs: list[PlannedRun], done: set[str]) -> dict[str, Any]:
    """The plan's counts: runs in all, done and to do, and ``[runs, done]`` per learner.

    (The wall-time estimate is the jobs' (:func:`runners.plan.estimate.jobs_estimate`): a figure here
    from the runs alone, which an earlier version returned, was read by nothing.)"""
    by_algo: dict[str, list[int]] = {}
    for r in runs:
        entry = by_algo.setdefault(r.config.algo.label, [0, 0])
        entry[0] += 1
        entry[1] += r.run_id in done
    n_done = sum(r.run_id in done for r in runs)
    return {"total": len(runs), "done": n_done, "todo": len(runs) - n_done, "by_algo": by_algo}
