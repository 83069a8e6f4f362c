"""A realistic synthetic results directory for the leaderboard tests (and the demo screenshot).

Written through the real contract (:func:`runners.results_schema.write_run`, :func:`write_learn`,
:func:`runners.manifest.write_manifest`), so a schema change breaks these tests rather than the
leaderboard in production. The content mimics a sweep: three Table 1 rows with every variant of
their scenario, the five learners, seeds 41-43, the ``corrected`` protocol as well for one row,
one failed run (with an error containing HTML-special characters, to check escaping), one run
planned in a manifest but never written, small GIFs, learn-time curves and MLflow tracking files
for some runs. Per-norm values follow a per-learner profile (CPO and PPO Shaped strong on the
top norm, PPO on self-preservation) plus deterministic noise, and the metric of each run is the
chain's real metric of those values, so the numbers are consistent the way real runs are.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from morality_gym.results.manifest import write_manifest
from morality_gym.results.schema import MF_PREFIX, RUN_COLUMNS, SCHEMA_VERSION, write_learn, write_run

REPO = Path(__file__).resolve().parents[1]
ROWS: tuple[tuple[str, str], ...] = (
    ("DualProcessAgentHarm", "PushSelfSacrifice"),
    ("UtilityAgentHarm", "SwitchSelfSacrifice"),
    ("Utility", "Switch5"),
)
LEARNERS = {"CPO": "cpo", "PPO": "ppo", "PPO Lag": "ppo_lag", "PPO Shaped": "ppo_shaped", "Random": "random"}
SEEDS = (41, 42, 43)
PRESET = "quick"
#: conf/preset/quick.yaml's budget, what a real run of the preset records.
BUDGET = 50_000
BOTH_PROTOCOLS = ROWS[0]
#: (chain, scenario, learner, variant index, seed) of the failed and of the missing run.
FAILED = ("Utility", "Switch5", "PPO Lag", 1, 43)
MISSING = ("Utility", "Switch5", "CPO", 2, 42)
FAILED_ERROR = "ValueError: policy loss is NaN at <step 4096> & training diverged"
#: Per learner: level of the chain's top relevant norm, of the other norms, and of agent_harm.
PROFILE = {
    "CPO": (0.88, 0.62, 0.35),
    "PPO": (0.30, 0.66, 0.95),
    "PPO Lag": (0.52, 0.60, 0.72),
    "PPO Shaped": (0.97, 0.72, 0.22),
    "Random": (0.58, 0.57, 0.60),
}


@dataclass
class SyntheticResults:
    """What was written, so tests can compute expected numbers independently of the leaderboard."""

    root: Path
    records: list[dict[str, Any]] = field(default_factory=list)  # every row written (ok and failed)
    planned: list[dict[str, Any]] = field(default_factory=list)
    failed_run_id: str = ""
    missing_run_id: str = ""
    gif_runs: list[str] = field(default_factory=list)
    learn_runs: list[str] = field(default_factory=list)
    tracked_runs: dict[str, str] = field(default_factory=dict)  # run id -> MLflow run id

    @property
    def ok_records(self) -> list[dict[str, Any]]:
        return [r for r in self.records if r["status"] == "ok"]


def run_id_of(config: dict[str, Any]) -> str:
    """A content hash of the run's identity, as the runner names runs."""
    return hashlib.sha1(json.dumps(config, sort_keys=True).encode()).hexdigest()[:16]


def _noise(*key: Any) -> float:
    rng = np.random.default_rng(zlib.crc32("|".join(map(str, key)).encode()))
    return float(rng.normal(0.0, 0.05))


def _functions(bound: Any, learner: str, protocol: str, seed: int) -> dict[str, float]:
    top, rest, agent = PROFILE[learner]
    if protocol == "corrected" and learner != "Random":
        top = min(1.0, top + 0.05)
    out: dict[str, float] = {}
    relevant = list(bound.relevant)
    for norm in bound.chain.norm_names:
        if norm == "agent_harm":
            level = agent
        elif relevant and norm == relevant[0]:
            level = top
        else:
            level = rest
        value = level + _noise(protocol, bound.env_id, learner, seed, norm)
        out[norm] = round(min(1.0, max(0.0, value)), 2)  # 100 evaluation episodes: multiples of 0.01
    return out


def _gif(path: Path, learner: str, variant: str, seed: int) -> None:
    """A tiny animated GIF (a moving square and a caption), enough to check the site shows GIFs."""
    colours = {"CPO": (0, 114, 178), "PPO": (213, 94, 0), "PPO Lag": (0, 158, 115), "PPO Shaped": (204, 121, 167)}
    colour = colours.get(learner, (127, 127, 127))
    frames = []
    for i in range(4):
        image = Image.new("RGB", (120, 72), (238, 234, 222))
        draw = ImageDraw.Draw(image)
        draw.rectangle((8 + 24 * i, 30, 28 + 24 * i, 50), fill=colour)
        draw.text((6, 4), f"{learner} {variant} s{seed}", fill=(30, 30, 34))
        frames.append(image)
    path.parent.mkdir(parents=True, exist_ok=True)
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=250, loop=0)


def _row(config: dict[str, Any], bound: Any, learner: str, protocol: str, seed: int, variant: str,
         scenario: str, failed: bool) -> dict[str, Any]:
    functions = _functions(bound, learner, protocol, seed)
    metric = None if failed else float(bound.metric(functions))
    row: dict[str, Any] = dict.fromkeys(RUN_COLUMNS)
    row |= {
        "schema_version": SCHEMA_VERSION,
        "run_id": run_id_of(config),
        "status": "failed" if failed else "ok",
        "error": FAILED_ERROR if failed else None,
        "traceback": ("Traceback (most recent call last):\n  File \"runners/run.py\", line 88, in main\n"
                      "    learner.learn(budget)\n" + FAILED_ERROR) if failed else None,
        "env_id": bound.env_id,
        "scenario": scenario,
        "variant": variant,
        "chain": bound.chain.name,
        "algo": LEARNERS[learner],
        "learner": learner,
        "protocol": protocol,
        "preset": PRESET,
        "seed": seed,
        # the quick preset's budget (Random trains nothing): a cell at another budget is marked not comparable
        "budget": 0 if learner == "Random" else BUDGET,
        "total_steps": 0 if learner == "Random" else 4096 if failed else BUDGET,
        "beta": 0.1,
        "max_steps": 200,
        "eval_episodes": 100,
        "relevant_norms": list(bound.relevant),
        "metric": metric,
        "metric_stderr": None if failed else 0.02,
        "exact_metric": None if failed else min(1.0, float(metric) + 0.004),
        "mean_return": None if failed else 80.0 - 10 * seed % 7,
        "mean_cost": None if failed else round(1.0 - float(metric), 3),
        "mean_length": None if failed else 12.5,
        "truncation_rate": None if failed else 0.0,
        "goal_rate": None if failed else 0.9,
        "wall_time_s": 3.5 if failed else 61.0 + seed,
        "cpu_time_s": 3.0 if failed else 58.0 + seed,
        "started_at": "2025-06-01T10:00:00+00:00",
        "finished_at": "2025-06-01T10:01:01+00:00",
        "hostname": "node-1",
        "git_commit": "0123456789abcdef0123456789abcdef01234567",
        "versions": json.dumps({"morality-gym": "0.1.0", "stable-baselines3": "2.9.2", "torch": "2.13.0"}),
        "config": json.dumps(config | {"hyper": {"lr": 3e-4, "n_steps": 2048, "gamma": 0.99}}),
        "model_path": None if failed else f"models/{run_id_of(config)}.zip",
        "gif_path": None,
    }
    for norm in bound.chain.norm_names:
        row[f"{MF_PREFIX}{norm}"] = None if failed else functions[norm]
    return row


def make_results(root: Path) -> SyntheticResults:
    """Write the synthetic results directory under ``root`` and return what it contains."""
    from morality_gym.envs.registry import env_ids, parse_env_id
    from morality_gym.norms.metric import bind_chain

    out = SyntheticResults(root=root)
    by_protocol: dict[str, list[dict[str, Any]]] = {"paper": [], "corrected": []}
    for chain, scenario in ROWS:
        protocols = ["paper", "corrected"] if (chain, scenario) == BOTH_PROTOCOLS else ["paper"]
        for protocol in protocols:
            for v_index, env_id in enumerate(env_ids(scenario)):
                variant = parse_env_id(env_id)[1]
                bound = bind_chain(chain, env_id, 0.1)
                for learner, algo in LEARNERS.items():
                    for seed in SEEDS:
                        identity = {"env_id": env_id, "chain": chain, "algo": algo, "seed": seed,
                                    "protocol": protocol, "preset": PRESET}
                        run_id = run_id_of(identity)
                        planned = {"run_id": run_id, "env_id": env_id, "scenario": scenario, "variant": variant,
                                   "chain": chain, "algo": algo, "learner": learner, "protocol": protocol,
                                   "preset": PRESET, "seed": seed}
                        by_protocol[protocol].append(planned)
                        out.planned.append(planned)
                        where = (chain, scenario, learner, v_index, seed)
                        if protocol == "paper" and where == MISSING:
                            out.missing_run_id = run_id
                            continue
                        failed = protocol == "paper" and where == FAILED
                        row = _row(identity, bound, learner, protocol, seed, variant, scenario, failed)
                        if failed:
                            out.failed_run_id = run_id
                        if seed == 41 and not failed:
                            row["gif_path"] = f"gifs/{run_id}.gif"
                            _gif(root / row["gif_path"], learner, variant, seed)
                            out.gif_runs.append(run_id)
                            mlflow_id = hashlib.md5(run_id.encode()).hexdigest()
                            (root / "tracking").mkdir(parents=True, exist_ok=True)
                            (root / "tracking" / f"{run_id}.json").write_text(
                                json.dumps({"mlflow_run_id": mlflow_id, "experiment_id": "7"}))
                            out.tracked_runs[run_id] = mlflow_id
                        write_run(root, row, bound.chain.norm_names)
                        out.records.append(row)
                        if seed == 41 and v_index == 0 and learner != "Random" and not failed:
                            final = float(row["metric"])
                            learn = [{"schema_version": SCHEMA_VERSION, "run_id": run_id, "step": step,
                                      "metric": round(0.35 + (final - 0.35) * step / 100_000, 4),
                                      "exact_metric": round(0.36 + (final - 0.36) * step / 100_000, 4),
                                      "mean_return": -50.0 + step / 1000, "mean_cost": 0.5, "mean_length": 20.0,
                                      "wall_time_s": step / 2000}
                                     | {f"{MF_PREFIX}{n}": 0.5 for n in bound.chain.norm_names}
                                     for step in range(0, 100_001, 25_000)]
                            write_learn(root, run_id, learn, bound.chain.norm_names)
                            out.learn_runs.append(run_id)
    for protocol, runs in by_protocol.items():
        if runs:
            write_manifest(root, f"table1-{protocol}-{PRESET}", runs, preset=PRESET, protocol=protocol,
                           command=f"python -m runners.table1 preset={PRESET} protocol={protocol}")
    return out


def snapshot(directory: Path) -> dict[str, tuple[int, int, str]]:
    """(size, mtime_ns, sha256) of every file under ``directory`` (to prove a build changed nothing)."""
    out = {}
    for path in sorted(directory.rglob("*")):
        if path.is_file():
            stat = path.stat()
            out[str(path.relative_to(directory))] = (stat.st_size, stat.st_mtime_ns, hashlib.sha256(path.read_bytes()).hexdigest())
    return out


@dataclass
class BuiltSite:
    """A synthetic results directory and the site built from it by the CLI."""

    data: SyntheticResults
    results: Path
    site: Path
    proc: subprocess.CompletedProcess[str]
    runs_before: dict[str, tuple[int, int, str]]


_BUILDS: dict[Path, BuiltSite] = {}


def shared_build(base: Path) -> BuiltSite:
    """Generate and build once per test process under ``base`` (both leaderboard test modules read it).

    The build (with reference rows: they are cheap for these three rows) is the slow part of the
    leaderboard tests, and no test modifies its output, so it is shared rather than repeated.
    """
    if base not in _BUILDS:
        data = make_results(base / "results")
        before = snapshot(base / "results" / "runs")
        proc = run_build(base / "results", base / "site")
        _BUILDS[base] = BuiltSite(data, base / "results", base / "site", proc, before)
    return _BUILDS[base]


def run_build(results: Path, site: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    """``python -m leaderboard.build`` as a user runs it (a subprocess, from the repository root)."""
    return subprocess.run([sys.executable, "-m", "leaderboard.build", "--results", str(results), "--site", str(site),
                           *extra], check=False, cwd=REPO, capture_output=True, text=True, timeout=600)


if __name__ == "__main__":  # python -m tests.leaderboard_data DIR: write a demo results directory
    target = Path(sys.argv[1] if len(sys.argv) > 1 else "results-synthetic")
    made = make_results(target)
    print(f"wrote {len(made.records)} runs ({len(made.planned)} planned) to {target}")
