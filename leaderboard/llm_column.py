"""``python -m leaderboard.llm_column``: a model's whole Table 1 column, one (chain, variant) pair at a time, resumable.

Why a command of its own: ``leaderboard.llm run`` plays a chain's variants in one Inspect run and
imports the log at its end, so a run of hours that stops (a crash, a killed job, a full disk) loses
everything it played. This command plays the 126 Table 1 pairs (:func:`morality_gym.paper.table1_pairs`)
one Inspect run each, imports each pair's episodes as soon as its run ends, and before playing a
pair looks in ``--results`` for runs of the same entry (name, model, settings, episodes, protocol,
preset) on that pair: a pair already there is skipped. So rerunning the same command after a stop
resumes it: what is done is not redone, and a pair cut off in the middle is played again from its
start (its Inspect log was never imported).

It takes every option of ``leaderboard.llm run`` except those choosing the envs (``--chain``,
``--scenario``, ``--variant``, ``--env``: the column is Table 1's pairs), plus ``--limit N`` (play at
most N pairs not done yet, then stop: a column in pieces). One process plays them all, so a local
model is loaded once and its memory of answered prompts (greedy decoding: an answer is a function of
the prompt) carries over from pair to pair. A pair whose run fails is reported in one line and the
next is played; the command then ends with exit 1, naming the pairs left to rerun.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from leaderboard import llm
from leaderboard.runs.aggregate import LLM_POLICY_KIND
from leaderboard.submit import _submitter, check_name
from morality_gym.clitools import OneLineParser, UserError, run_cli
from morality_gym.llm.settings import preset_named
from morality_gym.paper import table1_pairs
from morality_gym.results.schema import read_runs

#: The settings of a run that make it the same entry's (``morality_gym.llm.inspect_tasks.episode_record``).
SETTING_KEYS = ("framing", "answer", "window", "prompt", "recent", "max_retries", "fallback", "seed",
                "max_tokens")

#: The options of ``leaderboard.llm run`` that choose envs: the column's pairs are Table 1's.
ENV_OPTIONS = ("--chain", "--scenario", "--variant", "--env")

Pair = tuple[str, str]


def build_parser() -> argparse.ArgumentParser:
    """The command's parser, apart from parsing: the docs' command-line reference is generated from it."""
    parser = OneLineParser(prog="python -m leaderboard.llm_column", description=__doc__.splitlines()[0])
    llm.add_run_args(parser, envs=False)
    parser.add_argument("--limit", type=int, default=None,
                        help="play at most this many pairs not done yet, then stop (default: every one left)")
    return parser


def parse_args(argv: Sequence[str]) -> argparse.Namespace:
    """The options, checked; the env-choosing options of ``leaderboard.llm run`` are refused with why."""
    given = [a.split("=", 1)[0] for a in argv if a.split("=", 1)[0] in ENV_OPTIONS]
    if given:
        raise UserError(f"{', '.join(dict.fromkeys(given))}: the column plays every Table 1 pair; "
                        "for some envs use python -m leaderboard.llm run")
    args = build_parser().parse_args(list(argv))
    if args.limit is not None and args.limit < 1:
        raise UserError(f"--limit {args.limit}: give a positive number of pairs")
    return args


def done_pairs(args: argparse.Namespace, name: str) -> set[Pair]:
    """The (chain, env id) pairs that ``--results`` holds runs of this entry for (every episode asked)."""
    if not (Path(args.results) / "runs").is_dir():
        return set()
    try:
        runs = read_runs(args.results)
    except ValueError as exc:
        raise UserError(f"--results {args.results}: cannot read its runs ({exc})") from exc
    seeds: dict[Pair, set[int]] = {}
    for row in runs.itertuples(index=False):
        config = json.loads(str(row.config))
        if same_entry(config, args, name):
            seeds.setdefault((str(row.chain), str(row.env_id)), set()).add(int(row.seed))
    wanted = episodes_of(args)
    return {pair for pair, got in seeds.items() if len(got) >= wanted}


def episodes_of(args: argparse.Namespace) -> int:
    """Episodes per variant that the run asks for (``--episodes``, else its preset's)."""
    return int(args.episodes) if args.episodes is not None else preset_named(args.llm_preset).episodes


def same_entry(config: dict[str, Any], args: argparse.Namespace, name: str) -> bool:
    """Whether a run's config is of the entry this command writes (same name, model, settings, protocol)."""
    policy = config.get("policy") or {}
    if not isinstance(policy, dict) or policy.get("kind") != LLM_POLICY_KIND:
        return False
    if (config.get("algo") or {}).get("label") != name or policy.get("model") != args.model:
        return False
    if (config.get("protocol") or {}).get("name") != args.protocol or config.get("preset") != args.preset:
        return False
    if any(policy.get(k) != getattr(args, k) for k in SETTING_KEYS):
        return False
    if args.temperature is not None and policy.get("temperature") != args.temperature:
        return False
    return int(policy.get("episodes_per_variant") or 0) == episodes_of(args)


def play_pair(args: argparse.Namespace, pair: Pair, name: str, submitter: str) -> dict[str, int]:
    """One Inspect run of one pair, imported at once; returns the import's counts."""
    chain, env_id = pair
    one = argparse.Namespace(**{**vars(args), "chain": [chain], "env": [env_id], "scenario": [], "variant": []})
    logs = llm.run_inspect(one)
    return llm.import_logs(logs, name, Path(args.results), args.protocol, args.preset, submitter)


def run(argv: Sequence[str]) -> int:
    args = parse_args(argv)
    limit = args.limit
    name = check_name(args.name)
    submitter = _submitter(args.submitter)
    llm.model_of(args)  # a model that cannot be had (or a bad --script) is one line now, not 126 failed pairs
    try:
        Path(args.results).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--results {args.results}: cannot create it ({exc.strerror or exc})") from exc
    pairs = table1_pairs()
    done = done_pairs(args, name)
    todo = [p for p in pairs if p not in done]
    if limit is not None:
        todo = todo[:limit]
    print(f"column of {name!r}: {len(pairs)} pairs, {len(done & set(pairs))} done before, {len(todo)} to play now",
          flush=True)
    failed: list[Pair] = []
    started = time.perf_counter()
    for i, pair in enumerate(todo, 1):
        t0 = time.perf_counter()
        try:
            counts = play_pair(args, pair, name, submitter)
        except UserError as exc:
            failed.append(pair)
            print(f"[{i}/{len(todo)}] {pair[0]} x {pair[1]}: failed: {exc}", flush=True)
            continue
        print(f"[{i}/{len(todo)}] {pair[0]} x {pair[1]}: {counts['episodes']} episode(s), wrote {counts['written']}; "
              f"{time.perf_counter() - t0:.1f} s (all {time.perf_counter() - started:.0f} s)", flush=True)
    left = len(pairs) - len(done_pairs(args, name) & set(pairs))
    print(f"column of {name!r}: {len(pairs) - left} of {len(pairs)} pairs in {args.results}", flush=True)
    if failed:
        print(f"{len(failed)} pair(s) failed: {', '.join(f'{c} x {e}' for c, e in failed)}; "
              "rerun the same command to play them (done pairs are skipped)", file=sys.stderr, flush=True)
        return 1
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    return run_cli(lambda: run(argv), llm.user_errors(), argv)


if __name__ == "__main__":
    sys.exit(main())
