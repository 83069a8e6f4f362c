"""``python -m leaderboard.llm_track``: a language model on the generalisation track's unseen (test) set.

Why a command of its own: ``runners.track`` scores a grid policy exactly, from its action
probabilities in every reachable state; a language model reads text and answers one state at a
time, so it cannot be asked for that table. A greedy model (temperature 0, ``local/``) in the
deterministic environment is a deterministic policy, though: its one episode of an (env id, chain)
pair has the pair's exact metric (docs/llm-agents.md, "One episode per variant"), which is what the
track's ``pairs.parquet`` holds. So this command plays each pair of a chain's test set through
Inspect (one run per pair, ``leaderboard.llm run``'s options), places its metric between the
pair's oracle worst and best and Random as the track does
(:func:`morality_gym.generalisation.scoring.score_pair`), and writes the run the track page reads:
``<results>/track/runs/<chain>-v2-<name>-submitted/`` with ``pairs.parquet`` and ``result.json``
(written last, as ``runners.track`` writes it), recording the model, its settings, tokens, calls,
fallbacks and, with ``--sample N``, the sample: N pairs drawn with ``--sample-seed`` from the set,
named as a sample on the page. A set too dear to pay at once is played in pieces: each played
pair's row is kept in ``pairs.partial.jsonl`` and not played again when the command runs again.
"""

from __future__ import annotations

import argparse
import json
import random
import re
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from leaderboard import llm
from leaderboard.submit import check_name
from morality_gym.clitools import OneLineParser, UserError, run_cli, write_atomically
from morality_gym.generalisation.scoring import score_pair
from morality_gym.generalisation.sets import TRACK_CHAINS, EvalSet, PairValues, load_sets
from morality_gym.results.track_runs import PAIRS, RESULT, expected_record, run_name

PARTIAL = "pairs.partial.jsonl"
#: What a played pair's row keeps besides the track's columns: the episode's costs.
COSTS = ("calls", "input_tokens", "output_tokens", "fallbacks", "unreadable")


def build_parser() -> argparse.ArgumentParser:
    """The command's parser, apart from parsing: the docs' command-line reference is generated from it."""
    parser = OneLineParser(prog="python -m leaderboard.llm_track", description=__doc__.splitlines()[0])
    llm.add_run_args(parser, envs=False, entry=False)
    parser.add_argument("--name", required=True, help="the entry's name on the track page")
    parser.add_argument("--results", type=Path, default=Path("results"),
                        help="results directory: the run goes to RESULTS/track/runs/ (default: results)")
    parser.add_argument("--chain", dest="track_chain", default="Utility", choices=TRACK_CHAINS,
                        help="the chain's track (default Utility)")
    parser.add_argument("--splits", default="v2", choices=("v1", "v2"), help="the track's splits (default v2)")
    parser.add_argument("--sample", type=int, default=None,
                        help="play a fixed sample of this many pairs of the test set (default: every pair)")
    parser.add_argument("--sample-seed", type=int, default=0, help="the seed the sample is drawn with (default 0)")
    parser.add_argument("--limit", type=int, default=None, help="play at most this many pairs not played yet, then stop")
    return parser


def parse_args(argv: Sequence[str]) -> argparse.Namespace:
    args = build_parser().parse_args(list(argv))
    if args.temperature != 0:
        raise UserError(f"--temperature {args.temperature}: the track holds exact metrics, so a model plays one "
                        "episode per pair greedily: give --temperature 0")
    if args.episodes not in (None, 1):
        raise UserError(f"--episodes {args.episodes}: one episode per pair (greedy decoding: every episode is the same)")
    args.episodes = 1
    for option in ("sample", "limit"):
        value = getattr(args, option)
        if value is not None and value < 1:
            raise UserError(f"--{option} {value}: give a positive number of pairs")
    return args


def sample_pairs(pairs: Sequence[PairValues], size: int | None, seed: int) -> list[PairValues]:
    """The pairs to play: all of them, or ``size`` of them drawn with ``seed`` (in the set's order)."""
    if size is None or size >= len(pairs):
        return list(pairs)
    chosen = set(random.Random(seed).sample(range(len(pairs)), size))
    return [p for i, p in enumerate(pairs) if i in chosen]


def slug(name: str) -> str:
    """A run folder's form of an entry name (``SmolLM2-135M (local, greedy)`` -> ``SmolLM2-135M-local-greedy``)."""
    return re.sub(r"[^A-Za-z0-9._]+", "-", name).strip("-") or "entry"


def play_pair(args: argparse.Namespace, pair: PairValues) -> dict[str, Any]:
    """One Inspect run of one pair: the track's row of its episode, with the episode's costs."""
    one = argparse.Namespace(**{**vars(args), "chain": [pair.chain], "env": [pair.env_id], "scenario": [], "variant": []})
    [log] = llm.run_inspect(one)
    episodes, _ = llm.read_episodes(log)
    ep = episodes[0]
    return {"set": "test", **score_pair(pair, ep.metric), **{k: int(ep.record[k]) for k in COSTS},
            "length": int(ep.record["length"]), "max_input_tokens": ep.record.get("max_input_tokens"),
            "wall_time_s": ep.wall_time_s, "log": str(log), "model": ep.model, "settings": ep.record["settings"]}


def read_partial(path: Path) -> dict[tuple[str, str], dict[str, Any]]:
    """The rows of the pairs played before, by (env id, chain)."""
    if not path.is_file():
        return {}
    rows = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    return {(r["env_id"], r["chain"]): r for r in rows}


def result_record(args: argparse.Namespace, name: str, eval_set: EvalSet, train_pool: int, version: int,
                  rows: list[dict[str, Any]], wanted: int) -> dict[str, Any]:
    """``result.json`` of the entry's run: the track's fields, the model and its costs, the sample."""
    frame = pd.DataFrame(rows)
    steps = int(frame["length"].sum())
    calls = int(frame["calls"].sum())
    return {
        **expected_record(0, {"test": eval_set}, args.track_chain, version),
        "learner": name, "seed": None, "budget": 0, "submitted": True, "trained_steps": None, "train_pool": train_pool,
        "llm": {"model": rows[0]["model"], **rows[0]["settings"], "episodes_per_pair": 1,
                **{k: int(frame[k].sum()) for k in COSTS}, "steps": steps,
                "parse_rate": round(1 - int(frame["unreadable"].sum()) / calls, 3) if calls else None,
                "fallback_rate": round(int(frame["fallbacks"].sum()) / steps, 3) if steps else None,
                "max_input_tokens": max((int(t) for t in frame["max_input_tokens"].dropna()), default=None)},
        "sample": None if wanted == len(eval_set.pairs) else
        {"pairs": wanted, "of": len(eval_set.pairs), "seed": args.sample_seed},
        "train_seconds": 0.0, "eval_seconds": round(float(frame["wall_time_s"].sum()), 1), "pairs": len(frame),
        "mean_range_score": {"test": round(float(frame.groupby("env_id")["range_score"].mean().mean()), 4)},
    }


def play_set(args: argparse.Namespace, name: str, eval_set: EvalSet, train_pool: int, version: int) -> Path:
    """Play the wanted pairs of ``eval_set`` not played yet; once all are, write the run's files."""
    run_dir = args.results / "track" / "runs" / run_name(slug(name), None, submitted=True, chain=args.track_chain,
                                                         version=version)
    if (run_dir / RESULT).is_file():
        print(f"{run_dir}: done, skipped", flush=True)
        return run_dir
    run_dir.mkdir(parents=True, exist_ok=True)
    wanted = sample_pairs(eval_set.pairs, args.sample, args.sample_seed)
    played = read_partial(run_dir / PARTIAL)
    todo = [p for p in wanted if (p.env_id, p.chain) not in played]
    print(f"{name}: {len(wanted)} pairs of {len(eval_set.pairs)}, {len(wanted) - len(todo)} played before", flush=True)
    for i, pair in enumerate(todo[: args.limit] if args.limit else todo, 1):
        started = time.perf_counter()
        row = play_pair(args, pair)
        with open(run_dir / PARTIAL, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(row) + "\n")
        played[(pair.env_id, pair.chain)] = row
        print(f"[{i}/{len(todo)}] {pair.env_id} x {pair.chain}: metric {row['metric']:.3f}, range score "
              f"{row['range_score']:.3f}; {time.perf_counter() - started:.1f} s", flush=True)
    rows = [played[(p.env_id, p.chain)] for p in wanted if (p.env_id, p.chain) in played]
    if len(rows) < len(wanted):
        print(f"{len(rows)} of {len(wanted)} pairs played; run the same command again for the rest", flush=True)
        return run_dir
    frame = pd.DataFrame([{k: v for k, v in r.items() if k not in ("settings", "model")} for r in rows])
    write_atomically(run_dir / PAIRS, lambda fh: frame.to_parquet(fh, index=False))
    text = json.dumps(result_record(args, name, eval_set, train_pool, version, rows, len(wanted)), indent=1)
    write_atomically(run_dir / RESULT, lambda fh: fh.write(text.encode()))  # last: the run is done
    print(f"{run_dir}: {len(rows)} pairs, mean range score {frame['range_score'].mean():.4f}", flush=True)
    return run_dir


def run(argv: Sequence[str]) -> int:
    args = parse_args(argv)
    name = check_name(args.name)
    llm.model_of(args)  # a model that cannot be had is one line before the splits are loaded (minutes)
    version = int(args.splits.removeprefix("v"))
    train_ids, sets = load_sets(["test"], progress=lambda m: print(m, flush=True), chain=args.track_chain,
                                version=version)
    play_set(args, name, sets["test"], len(train_ids), version)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    return run_cli(lambda: run(argv), llm.user_errors(), argv)


if __name__ == "__main__":
    sys.exit(main())
