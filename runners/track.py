"""``python -m runners.track --learners random ppo --seeds 41 42 43 --budget 100000 --out DIR``.

The generalisation track (docs/how-to/generalisation-track.md): each run trains ONE policy on the
generated ``train`` split (:class:`~morality_gym.generalisation.mixture.DilemmaMixtureEnv`: every
episode a train dilemma drawn by the run's seed, seen as the fixed-shape grid), then scores it
exactly, zero-shot, on three sets (:mod:`morality_gym.generalisation.sets`): a fixed sample of the
seen train dilemmas, the held-out ``test`` split and the 98 built-in envs.

Each run writes ``DIR/runs/<learner>-s<seed>/``: ``pairs.parquet`` (one row per evaluated (env id,
chain) pair: the exact metric, the oracle best and worst, Random's exact metric, the two scores),
``result.json`` (learner, seed, budget, hyper-parameters, timings, and the split names and
digests of the training pool and of every set) and, for PPO, ``model.zip``. ``result.json`` is
written last: a run with one is done and is skipped when the command runs again (resumable); a
run whose recorded budget or split digests differ from the command's is an error, not a silent
mix. Random is not trained and its values are exact, so it has one run (seed ``exact``).

``--chain Utility`` (or ``DualProcess``) runs that chain's track instead of the mixed one: the
training pool and every set hold only the env ids that are a dilemma under the chain, a run trains
on the chain's cost (PPO Shaped: its shaping; PPO-Lag and CPO: its step-wise cost, only here) and is
scored under the chain alone; its runs are ``DIR/runs/<chain>-<learner>-s<seed>/`` and record the
chain. There every learner trains all its seeds as one fleet with Table 1's hyper-parameters, on the
compact observation, checkpointed and resumable, recording each run's learning curve on the seen set
in ``DIR/curves/`` every ``--curve-every`` steps (:mod:`runners.execute.track_fleet`); ``--n-envs``,
``--n-steps``, ``--batch-size`` and ``--n-epochs`` apply to the mixed track's single runs only. ``--splits v2`` (with ``--chain``)
keeps only the pairs of the v2 splits, where Random leaves headroom under the chain
(:mod:`~morality_gym.generalisation.headroom`); its runs are ``<chain>-v2-<learner>-s<seed>``.

``python -m leaderboard.track --results DIR`` aggregates the runs with bootstrap intervals, per
track, and writes the leaderboard page.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import socket
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

from morality_gym.baselines.device import Device
from morality_gym.baselines.policy_ref import load_policy
from morality_gym.baselines.sb3_learner import silent_logger
from morality_gym.baselines.specs import SpecError, learner_spec, protocol_spec, training_steps
from morality_gym.baselines.stopped import TrainingStopped
from morality_gym.clitools import EXIT_TERMINATED, OneLineParser, add_debug_flag, run_cli, write_atomically
from morality_gym.constants import MAX_STEPS
from morality_gym.generalisation.mixture import DilemmaMixtureEnv
from morality_gym.generalisation.scoring import score_set
from morality_gym.generalisation.sets import (
    SEEN_SAMPLE,
    SETS,
    TRACK_CHAINS,
    EvalSet,
    load_sets,
    table_cache_dir,
    training_chain,
)
from morality_gym.results.recording import git_commit
from morality_gym.results.track_runs import PAIRS, RESULT, TrackError, check_done, expected_record, run_name
from runners.execute import stopping
from runners.execute.track_fleet import CURVE_EVERY, CurveRecorder, fleet_key, train_fleet

LEARNERS = ("random", "ppo", "ppo_shaped", "ppo_lag", "cpo")
#: The learners trained on a chain's step-wise cost: only a chain's track has one.
COST_LEARNERS = ("ppo_lag", "cpo")
#: Rollout length per env copy: the paper's 2048 x 8 envs would give a 100k-step run six updates;
#: 256 x 8 gives it about fifty. Minibatches of 256 and 5 epochs (the paper: 64 and 10) keep an
#: update of the (5120 -> 64 -> 64) networks at 40 gradient steps, affordable on a shared 2-core
#: machine. All recorded in every result.
DEFAULT_N_STEPS = 256
DEFAULT_N_ENVS = 8
DEFAULT_BATCH = 256
DEFAULT_EPOCHS = 5


def _train_ppo(learner: str, seed: int, budget: int, train_ids: Sequence[str], n_envs: int, n_steps: int,
               out: Path, batch_size: int = 256, n_epochs: int = 5, chain: str | None = None) -> tuple[Any, dict[str, Any]]:
    """SB3's PPO on the mixture of every train dilemma (the mixed track; a chain's track trains fleets)."""
    torch.set_num_threads(1)
    # SB3 takes any 3-D uint8 Box for an image; the grid is not one (images are not normalised: normalize_images=False)
    warnings.filterwarnings("ignore", message="Treating image space as channels-last")
    spec = learner_spec(learner)
    # a chain's track trains on its cost and shaping; the mixed track on each dilemma's first chain
    pairs = [(env_id, chain or training_chain(env_id)) for env_id in train_ids]
    reward_cost = spec.reward_cost()

    def factory(i: int):
        return lambda: DilemmaMixtureEnv(pairs, seed=seed * 1000 + i, reward_cost=reward_cost, max_steps=MAX_STEPS)

    venv = VecMonitor(DummyVecEnv([factory(i) for i in range(n_envs)]))
    hparams = {**dict(spec.hparams), "n_steps": n_steps, "batch_size": batch_size, "n_epochs": n_epochs}
    activation = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}[spec.activation]
    arch = list(spec.net_arch)
    model = PPO("MlpPolicy", venv, seed=seed, device="cpu", verbose=0,
                policy_kwargs={"activation_fn": activation, "net_arch": {"pi": arch, "vf": arch}, "normalize_images": False}, **hparams)
    model.set_logger(silent_logger())  # no SB3-<date> folder left in $TMPDIR
    model.learn(total_timesteps=budget)
    model.save(out / "model.zip")
    info = {"hparams": hparams, "n_envs": n_envs, "net_arch": arch, "activation": spec.activation,
            "policy": "MlpPolicy on the flattened (20, 16, 16) grid", "reward": dataclass_dict(reward_cost),
            "trained_steps": int(model.num_timesteps)}
    return model, info


def dataclass_dict(value: Any) -> dict[str, Any]:
    """A dataclass as JSON-ready data (tuples as lists), for the run's record."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(value).items()}


def evaluate_sets(policy: Any, sets: dict[str, EvalSet]) -> list[dict[str, Any]]:
    """One row per (env id, chain) pair of every set: the policy's exact score there."""
    rows: list[dict[str, Any]] = []
    for eval_set in sets.values():
        rows.extend(score_set(policy, eval_set))
    return rows


def do_run(learner: str, seed: int | None, budget: int, train_ids: Sequence[str], sets: dict[str, EvalSet],
           out_dir: Path, n_envs: int = DEFAULT_N_ENVS, n_steps: int = DEFAULT_N_STEPS,
           batch_size: int = DEFAULT_BATCH, n_epochs: int = DEFAULT_EPOCHS, policy_ref: str | None = None,
           loaded: Any = None, chain: str | None = None, version: int = 1,
           trained: tuple[Any, dict[str, Any]] | None = None) -> dict[str, Any] | None:
    """One run: train (unless ``learner`` is ``random`` or ``policy_ref`` names a submitted grid
    policy, ``loaded`` if the caller loaded it already), evaluate on ``sets``, write its files; a
    done run is checked and skipped. ``chain``: the chain's track (``sets`` and ``train_ids`` are
    then that chain's, :func:`load_sets`). ``trained``: the run's learner and record, trained by a
    fleet (:mod:`runners.execute.track_fleet`); a run its fleet failed is reported and not written (None)."""
    run_dir = out_dir / "runs" / run_name(learner, seed, submitted=policy_ref is not None, chain=chain, version=version)
    expected = expected_record(budget, sets, chain, version)
    if (run_dir / RESULT).is_file():
        record = json.loads((run_dir / RESULT).read_text())
        check_done(record, expected, budget, run_dir / RESULT)
        print(f"{run_dir.name}: done, skipped", flush=True)
        return record
    run_dir.mkdir(parents=True, exist_ok=True)
    t0, c0 = time.perf_counter(), time.process_time()
    if learner == "random":
        policy: Any = "random"
        info: dict[str, Any] = {"trained_steps": 0}
    elif trained is not None:
        learner_obj, info = trained
        if "failed" in info:
            print(f"{run_dir.name}: FAILED, not written: {info['failed']}", flush=True)
            return None
        learner_obj.save(run_dir / "model.zip")
        policy = learner_obj.model
    elif policy_ref is not None:

        policy = (loaded if loaded is not None else load_policy(policy_ref, allow_other_env=True)).policy
        info = {"trained_steps": None, "policy_ref": policy_ref, "submitted": True}
    else:
        assert seed is not None
        policy, info = _train_ppo(learner, seed, budget, train_ids, n_envs, n_steps, run_dir, batch_size, n_epochs,
                                  chain)
    t1, c1 = time.perf_counter(), time.process_time()
    rows = evaluate_sets(policy, sets)
    t2, c2 = time.perf_counter(), time.process_time()
    frame = pd.DataFrame(rows)
    write_atomically(run_dir / PAIRS, lambda fh: frame.to_parquet(fh, index=False))
    record = {**expected, "learner": learner, "seed": seed,
              "budget": 0 if learner == "random" or policy_ref is not None else budget,
              "train_pool": len(train_ids), **info, "train_seconds": round(t1 - t0, 1),
              "eval_seconds": round(t2 - t1, 1), "pairs": len(frame),
              # what a release reports as compute (leaderboard.track_release): CPU, not wall, time;
              # a fleet's training CPU is its fleet_cpu_seconds, shared by its runs
              "train_cpu_seconds": round(c1 - c0, 1), "eval_cpu_seconds": round(c2 - c1, 1),
              "git_commit": git_commit(), "hostname": socket.gethostname(),
              "mean_range_score": {name: round(float(part.groupby("env_id")["range_score"].mean().mean()), 4)
                                   for name, part in frame.groupby("set")}}
    text = json.dumps(record, indent=1)
    write_atomically(run_dir / RESULT, lambda fh: fh.write(text.encode()))
    print(f"{run_dir.name}: trained {t1 - t0:.0f} s, evaluated {t2 - t1:.0f} s, mean range score "
          f"{record['mean_range_score']}", flush=True)
    return record


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="python -m runners.track", description=__doc__.split("\n\n")[1])
    parser.add_argument("--learners", nargs="+", default=["random", "ppo"], choices=LEARNERS)
    parser.add_argument("--policy", help="evaluate this grid policy instead of training (file.py:function, "
                        "module:function: obs (20, 16, 16) -> action or 6 probabilities); needs --name")
    parser.add_argument("--name", help="the submitted policy's name on the page (with --policy)")
    parser.add_argument("--seeds", nargs="+", type=int, default=[41, 42, 43])
    parser.add_argument("--budget", type=int, default=100_000, help="environment steps per trained run")
    parser.add_argument("--out", type=Path, default=Path("results/track"))
    parser.add_argument("--n-envs", type=int, default=DEFAULT_N_ENVS)
    parser.add_argument("--n-steps", type=int, default=DEFAULT_N_STEPS)
    parser.add_argument("--batch-size", type=int, default=DEFAULT_BATCH)
    parser.add_argument("--n-epochs", type=int, default=DEFAULT_EPOCHS)
    parser.add_argument("--seen-size", type=int, default=SEEN_SAMPLE, help="train env ids in the seen set")
    parser.add_argument("--sets", nargs="+", default=list(SETS), choices=SETS)
    parser.add_argument("--chain", choices=TRACK_CHAINS, help="the chain's own track: train on its dilemmas and cost, "
                        "score under it alone (default: the mixed track, every chain a dilemma is one under)")
    parser.add_argument("--curve-every", type=int, default=CURVE_EVERY, help="with --chain: env steps per run "
                        "between two points of the learning curves on the seen set (DIR/curves/)")
    parser.add_argument("--splits", choices=("v1", "v2"), default="v1", help="v2 (with --chain): only the pairs "
                        "that leave Random headroom under the chain (docs/how-to/generalisation-track.md)")
    parser.add_argument("--device", default="cpu", help="with --chain: where the fleets' networks train (cpu, cuda "
                        "or cuda:N; the mixture is still stepped on the host)")
    add_debug_flag(parser)
    return parser


def _device(text: str, chain: str | None) -> Device:
    """``--device`` checked once against what torch sees here; only a chain's fleets take one (the
    mixed track trains SB3's PPO on the CPU)."""
    try:
        device = Device.parse(text)
        if not device.on_cpu and chain is None:
            raise TrackError(f"--device {text}: only a chain's track trains fleets on a device; add --chain "
                             f"({' or '.join(TRACK_CHAINS)}) or drop --device")
        return device.checked(here=True)
    except SpecError as exc:
        raise TrackError(f"--device: {exc}") from None


def _check_args(args: argparse.Namespace) -> None:
    """The budget, the curve's spacing, and the options that only a chain's track has."""
    if args.budget <= 0:
        raise TrackError(f"--budget must be positive, got {args.budget}")
    if args.curve_every <= 0:
        raise TrackError(f"--curve-every must be positive, got {args.curve_every}")
    cost_learners = [name for name in args.learners if name in COST_LEARNERS]
    if cost_learners and args.chain is None:
        raise TrackError(f"--learners {' '.join(cost_learners)} train on a chain's step-wise cost: add --chain "
                         f"({' or '.join(TRACK_CHAINS)})")
    if args.chain is not None:  # the fleets train whole rollouts (the paper's step accounting)
        for name in args.learners:
            spec = protocol_spec("paper").apply(learner_spec(name))
            rollout = int(spec.hparams.get("n_steps", 2048)) * spec.n_envs
            if name != "random" and training_steps(spec, args.budget) == 0:
                raise TrackError(f"--budget {args.budget}: {name} trains whole rollouts of {rollout:,} steps; ask at "
                                 f"least {rollout:,}")
    if args.splits != "v1" and args.chain is None:
        raise TrackError(f"--splits {args.splits} selects pairs per chain: add --chain ({' or '.join(TRACK_CHAINS)})")


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # Everything the command line can get wrong is refused before the splits are generated (minutes).
    _check_args(args)
    device = _device(args.device, args.chain)
    loaded = None
    if args.policy is not None:
        if not args.name:
            raise TrackError("--policy needs --name (how the page calls it)")
        loaded = load_policy(args.policy, allow_other_env=True)
    t0 = time.perf_counter()
    version = int(args.splits.removeprefix("v"))
    train_ids, sets = load_sets(args.sets, progress=lambda m: print(m, flush=True), seen_size=args.seen_size,
                                chain=args.chain, version=version)
    print(f"splits and values ready in {time.perf_counter() - t0:.0f} s: train {len(train_ids)} env ids, "
          + ", ".join(f"{n} {len(s.env_ids)} env ids / {len(s.pairs)} pairs" for n, s in sets.items()), flush=True)
    if args.policy is not None:
        do_run(args.name, None, 0, train_ids, sets, args.out, policy_ref=args.policy, loaded=loaded, chain=args.chain,
               version=version)
        return 0
    failed = _run_learners(args, train_ids, sets, version, device)
    if failed:
        raise TrackError(f"{failed} run(s) failed in training (said above); the others are written. Fix: rerun "
                         "the command to retry them")
    return 0


def _run_learners(args: argparse.Namespace, train_ids: Sequence[str], sets: dict[str, EvalSet], version: int,
                  device: Device) -> int:
    """Train and score every learner of the command (a chain's: each learner's missing seeds as one
    fleet); returns how many runs failed in training."""
    failed = 0
    for learner in args.learners:
        if learner == "random":
            do_run(learner, None, args.budget, train_ids, sets, args.out, chain=args.chain, version=version)
            continue
        trained: dict[int, tuple[Any, dict[str, Any]]] = {}
        if args.chain is not None:  # a chain's track: every seed of the learner in one fleet
            expected = expected_record(args.budget, sets, args.chain, version)
            todo = [seed for seed in args.seeds if not _done(args.out, learner, seed, args.chain, version, expected,
                                                             args.budget)]
            if todo:
                prefix = run_name(learner, None, chain=args.chain, version=version).removesuffix("-sexact")
                key = fleet_key(learner, todo, args.budget, train_ids, args.chain, expected["train_digest"], device)
                c0 = time.process_time()
                curve = (CurveRecorder(args.out / "curves" / f"{prefix}.csv", learner, args.chain, todo, sets["seen"],
                                       args.curve_every) if "seen" in sets else None)
                trained = train_fleet(learner, todo, args.budget, train_ids, args.chain,
                                      args.out / "fleets" / f"{prefix}.pt", key, curve=curve, device=device,
                                      table_cache=table_cache_dir())
                # the curve sums the CPU of every session a resumed fleet trained in; else this process's alone
                spent = curve.cpu_seconds() if curve is not None else time.process_time() - c0
                for _, info in trained.values():
                    info["fleet_cpu_seconds"] = round(spent, 1)
        for seed in args.seeds:
            record = do_run(learner, seed, args.budget, train_ids, sets, args.out, args.n_envs, args.n_steps,
                            args.batch_size, args.n_epochs, chain=args.chain, version=version, trained=trained.get(seed))
            failed += record is None
    return failed


def _done(out: Path, learner: str, seed: int, chain: str, version: int, expected: dict[str, Any], budget: int) -> bool:
    """Whether the run has a result that fits this command (one that does not is a :class:`TrackError`)."""
    path = out / "runs" / run_name(learner, seed, chain=chain, version=version) / RESULT
    if not path.is_file():
        return False
    check_done(json.loads(path.read_text()), expected, budget, path)
    return True


def cli(argv: Sequence[str]) -> int:
    """The command line: :func:`main`, where a SIGTERM (a machine or session that stops, ``kill``)
    lets a fleet in training write its state at its next update boundary and then ends the command
    (:mod:`runners.execute.stopping`), so the rerun resumes from there rather than from the last
    periodic checkpoint (up to 5 minutes of every run). Outside a fleet's training the signal stops
    the command at once: every file is written under a temporary name and renamed."""
    stopping.install()
    try:
        return main(argv)
    except TrainingStopped as exc:
        print(f"{exc}; run the same command again to resume", file=sys.stderr, flush=True)
        return EXIT_TERMINATED


if __name__ == "__main__":
    sys.exit(run_cli(lambda: cli(sys.argv[1:]), (TrackError,), sys.argv[1:]))
