"""Execute one planned run: learn, evaluate, save artifacts, write its Parquet row last.

The run's Parquet file is written last and atomically, so its existence means "finished"; every
other artifact (model, GIF, learn-time evaluations) is written before it. A per-run lock
(:class:`~morality_gym.results.recording.RunLock`, released by the kernel even on ``kill -9``)
keeps two processes from executing the same run at once when a sweep is resumed while an orphan
is still busy. Any exception becomes a
``failed`` row with the error and traceback, so one bad run never stops the others, except a full
disk: that is no failure of the run, no row is written (it would not fit), and
:class:`~morality_gym.clitools.DiskFullError` stops the sweep with one line.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import traceback
from functools import lru_cache
from pathlib import Path
from typing import Any

import morality_gym
from morality_gym.baselines.learners import make_learner
from morality_gym.clitools import disk_full_error, is_disk_full
from morality_gym.results.recording import RunClock, finished_status, git_commit, utc_now, versions
from morality_gym.results.run_config import RunConfig
from morality_gym.results.schema import (
    MF_PREFIX,
    SCHEMA_VERSION,
    runs_dir,
    write_learn,
    write_run,
    write_updates,
)


@lru_cache(maxsize=1)
def training_code() -> str:
    """A fingerprint of the code and data a run trains with: a hash of every file of the
    ``morality_gym`` package (its Python modules and its YAML scenarios, chains and learner
    settings) and of the versions of the libraries whose arithmetic it uses.

    What a fleet checkpoint is keyed by (:mod:`runners.record.fleet_checkpoints`): a half-trained fleet
    must be finished by the code that began it, and the commit is too coarse for that (a commit
    of documentation or of the leaderboard would throw away every checkpoint) and too blind (an
    uncommitted edit keeps the commit). Asked once per process at the worker's start, as
    :func:`~morality_gym.results.recording.git_commit`, so that it describes the code the worker loaded."""
    return code_fingerprint(Path(morality_gym.__file__).resolve().parent, versions())


#: The files of a package that decide what a run computes (modules and the data they read).
CODE_SUFFIXES = (".py", ".yaml", ".yml", ".json")


def code_fingerprint(package: Path, versions_text: str) -> str:
    """A hash of ``package``'s :data:`CODE_SUFFIXES` files (paths and contents) and ``versions_text``."""
    digest = hashlib.sha256(versions_text.encode())
    for path in sorted(p for p in package.rglob("*") if p.suffix in CODE_SUFFIXES and p.is_file()):
        digest.update(str(path.relative_to(package)).encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


def limit_threads() -> None:
    """One compute thread per worker: the pool provides the parallelism (no oversubscription)."""
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = "1"
    try:
        import torch  # torch waits: importing runners.execute.run must not load it

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover - torch is a dependency
        pass


def _base_row(config: RunConfig, run_id: str, engine: str | None = "single") -> dict[str, Any]:
    return {
        "schema_version": SCHEMA_VERSION,
        "run_id": run_id,
        "env_id": config.env_id,
        "scenario": config.scenario,
        "variant": config.variant,
        "chain": config.chain["name"],
        "algo": config.algo.name,
        "learner": config.algo.label,
        "protocol": config.protocol.name,
        "preset": config.preset,
        "seed": int(config.seed),
        "budget": int(config.budget),
        "beta": float(config.beta),
        "max_steps": config.max_steps,
        "eval_episodes": int(config.eval_episodes),
        "hostname": socket.gethostname(),
        "git_commit": git_commit(),
        "versions": versions(),
        "config": json.dumps(config.to_json(), sort_keys=True),
        "engine": engine,
    }


def execute_locked(config: RunConfig, run_id: str, results_dir: Path, gif: bool) -> dict[str, Any]:
    """Train, evaluate and record one run whose lock the caller holds (the single engine's unit,
    and the fleet engine's fallback for what it does not reproduce). The run arrives resolved: its
    learner is built from its spec as it is (no protocol applied again)."""
    limit_threads()
    clock = RunClock.start()
    try:
        learner = make_learner(config.algo, config.bound_chain(), seed=config.seed, max_steps=config.max_steps,
                               replay=config.replay)
        learn_rows: list[dict[str, Any]] = []
        learner.learn(
            config.budget,
            eval_every=config.learn_eval_every,
            eval_episodes=config.learn_eval_episodes,
            on_eval=learn_rows.append,
        )
    except Exception as exc:  # noqa: BLE001 - every failure must be recorded, whatever it is
        return record_outcome(config, run_id, results_dir, gif, None, [], clock, error=exc)
    return record_outcome(config, run_id, results_dir, gif, learner, learn_rows, clock)


def record_outcome(
    config: RunConfig,
    run_id: str,
    results_dir: Path,
    gif: bool,
    learner: Any,
    learn_rows: list[dict[str, Any]],
    clock: RunClock,
    engine: str = "single",
    error: BaseException | None = None,
) -> dict[str, Any]:
    """Evaluate a trained ``learner`` and write every artifact of the run, its Parquet row last.

    Shared by the single and the fleet engine, so a run's files are the same whichever trained it.
    With ``error`` (training failed) only the failed row is written. Any exception here is recorded
    as the run's failure too. Returns the short summary the parent receives.
    """
    row = _base_row(config, run_id, engine)
    norms = [n for n, _ in config.chain["norms"]]
    try:
        if error is not None:
            raise error
        bound = learner.bound
        final = learner.final_evaluation(config.eval_episodes)
        exact = learner.exact_evaluation()
        artifacts = runs_dir(results_dir) / run_id
        artifacts.mkdir(parents=True, exist_ok=True)
        model_path = learner.save(artifacts / "model")
        gif_rel = None
        if gif:
            learner.record_gif(artifacts / "episode.gif")
            gif_rel = str((artifacts / "episode.gif").relative_to(results_dir))
        updates = learner.update_diagnostics()
        if updates:
            write_updates(results_dir, run_id, updates)
        if learn_rows:
            write_learn(
                results_dir,
                run_id,
                [
                    {
                        "schema_version": SCHEMA_VERSION,
                        "run_id": run_id,
                        "step": r["step"],
                        "metric": r["metric"],
                        "exact_metric": r["exact_metric"],
                        "mean_return": r["mean_return"],
                        "mean_cost": r["mean_cost"],
                        "mean_length": r["mean_length"],
                        "wall_time_s": r["wall_time_s"],
                        **{f"{MF_PREFIX}{n}": r["functions"].get(n) for n in norms},
                    }
                    for r in learn_rows
                ],
                norms,
            )
        row.update(
            status="ok",
            error=None,
            traceback=None,
            total_steps=int(learner.trained_steps),
            relevant_norms=list(bound.relevant),
            metric=final.metric,
            metric_stderr=final.metric_stderr,
            exact_metric=exact.metric,
            mean_return=final.mean_return,
            mean_cost=final.mean_cost,
            mean_length=final.mean_length,
            truncation_rate=final.truncation_rate,
            goal_rate=final.goal_rate,
            model_path=str(model_path.relative_to(results_dir)),
            gif_path=gif_rel,
            **{f"{MF_PREFIX}{n}": final.functions[n] for n in norms},
        )
    except Exception as exc:  # every failure must be recorded, whatever it is (a full disk aside)
        if is_disk_full(exc):  # not the run's failure: no row (it would not fit either); the sweep stops
            raise disk_full_error(runs_dir(results_dir) / run_id, exc) from exc
        row.update(
            status="failed",
            error=f"{type(exc).__name__}: {exc}",
            traceback="".join(traceback.format_exception(exc)),
            **_EMPTY_RESULT,
            **{f"{MF_PREFIX}{n}": None for n in norms},
        )
    wall, cpu = clock.elapsed()
    row.update(started_at=clock.started, finished_at=utc_now(), wall_time_s=wall, cpu_time_s=cpu)
    write_run(results_dir, row, norms)
    return {"run_id": run_id, "status": row["status"], "error": row["error"], "metric": row["metric"], "wall_time_s": row["wall_time_s"]}


#: The result columns of a run that produced no result.
_EMPTY_RESULT: dict[str, Any] = {
    "total_steps": 0, "relevant_norms": [], "metric": None, "metric_stderr": None, "exact_metric": None, "mean_return": None,
    "mean_cost": None, "mean_length": None, "truncation_rate": None, "goal_rate": None, "model_path": None, "gif_path": None,
}


def record_failure(config: RunConfig, run_id: str, results_dir: str | Path, error: str, trace: str = "", engine: str | None = None) -> None:
    """Record a run that died without recording itself (a killed worker, a lost SLURM job)."""
    results_dir = Path(results_dir)
    if finished_status(results_dir, run_id) is not None:
        return
    norms = [n for n, _ in config.chain["norms"]]
    row = _base_row(config, run_id, engine)
    now = utc_now()
    row.update(
        status="failed", error=error, traceback=trace or None, started_at=now, finished_at=now, wall_time_s=0.0,
        cpu_time_s=0.0,
        **_EMPTY_RESULT, **{f"{MF_PREFIX}{n}": None for n in norms},
    )
    write_run(results_dir, row, norms)
