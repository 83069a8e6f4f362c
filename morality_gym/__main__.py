"""Command line: ``python -m morality_gym {play,eval,oracle,list,docs,generate}``.

``eval`` and ``oracle`` are stable interfaces (other tools call them with ``--json``); their JSON
shapes are documented in docs/getting-started.md ("A first evaluation") and covered by tests. User errors (unknown names, bad numbers,
unusable model files, invalid scenario files) print one line and exit 2; ``--debug`` shows their
traceback (:mod:`morality_gym.clitools`).
"""

from __future__ import annotations

import argparse
import json
import secrets
import shutil
import sys
from pathlib import Path
from typing import Any

from morality_gym import play
from morality_gym.baselines.io import ModelError
from morality_gym.baselines.policy_ref import PolicyError, in_context, load_policy, probe
from morality_gym.clitools import OneLineParser, add_debug_flag, console, non_negative_int, positive_int, run_cli
from morality_gym.constants import BETA, EVAL_EPISODES, MAX_STEPS
from morality_gym.envs.naming import find_scenario as scenario_named  # either spelling: SwitchStandard, switch_standard
from morality_gym.envs.registration import env_class
from morality_gym.envs.registry import UnknownEnvError, list_envs, scenarios
from morality_gym.envs.trolley import InvalidActionError
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.horizon import truncation_problem
from morality_gym.evaluation.montecarlo import evaluate
from morality_gym.evaluation.oracle import oracle
from morality_gym.evaluation.policies import PolicyFailure
from morality_gym.generator.pipeline import REJECTION_REASONS, RunReport, generate
from morality_gym.generator.splits import ProgressLine, SplitError, split_names, write_split
from morality_gym.norms.chain import ChainError, MoralityChain, builtin_chains, chain_file_stem, get_chain
from morality_gym.norms.metric import bind_chain
from morality_gym.world.layout import ScenarioError
from morality_gym.world.rules import ACTION_NAMES


def _console() -> Any:
    """A rich console; when output is piped, wide enough that tables are never cut (and a closed
    pipe ends the command quietly, :func:`morality_gym.clitools.console`)."""
    return console(width=None if sys.stdout.isatty() else 200)


class CliError(Exception):
    """A user error: printed without a traceback, exit code 2."""


def _env_ids(scenario: str, variants: list[str] | None) -> list[str]:
    scn = scenario_named(scenario)
    if not variants:
        return scn.env_ids
    unknown = [v for v in variants if v not in scn.variants]
    if unknown:
        raise CliError(f"scenario {scn.name} has no variant {', '.join(unknown)}; variants: {', '.join(scn.variants)}")
    return [scn.env_id(v) for v in variants]


def drawn_seed() -> int:
    """A Monte-Carlo seed from the operating system's entropy, for ``eval`` without ``--seed``."""
    return secrets.randbelow(2**31)


def _beta(text: str) -> float | str:
    if text == "derived":
        return text
    try:
        value = float(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"beta must be a number in (0, 1] or 'derived', got {text!r}") from exc
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"beta must be in (0, 1], got {value}")
    return value


def _max_steps(text: str) -> int | None:
    if text.lower() == "none":
        return None
    try:
        value = int(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"max-steps must be a non-negative integer or 'none', got {text!r}") from exc
    if value < 0:
        raise argparse.ArgumentTypeError(f"max-steps must be >= 0, got {value}")
    return value


def _check_max_steps(chain: MoralityChain, env_ids: list[str], beta: float, max_steps: int | None) -> None:
    """Refuse a ``--max-steps`` too short to score the chain on every env, before any work (one line)."""
    for env_id in env_ids:
        problem = truncation_problem(bind_chain(chain, env_id, beta), max_steps)
        if problem is not None:
            raise CliError(f"--max-steps: {problem}")


def _load_policy(spec: str, env_ids: list[str], allow_other_env: bool) -> Any:
    """The policy ``spec`` names (:mod:`morality_gym.baselines.policy_ref`), checked against every env it
    will be evaluated on; a callable is asked for a first action so its mistakes fail early."""

    loaded = load_policy(spec, env_ids, allow_other_env)
    if loaded.kind == "callable":
        probe(loaded, env_ids[0])
    return loaded.policy


def _evaluate_one(args: argparse.Namespace, policy: Any, env_id: str, chain: Any, episodes: int) -> Any:
    """One env's result, exact or Monte Carlo, as ``eval``'s options ask."""
    if args.exact:
        return exact_evaluate(policy, env_id, chain, max_steps=args.max_steps, beta=args.beta, deterministic=args.deterministic)
    return evaluate(policy, env_id, chain, n_episodes=episodes, seed=args.seed, max_steps=args.max_steps, beta=args.beta,
                    deterministic=args.deterministic, progress=not args.json and sys.stderr.isatty(), keep_episodes=False)


def cmd_eval(args: argparse.Namespace) -> int:
    """``eval``: evaluate a policy on every variant asked for, then print JSON or a table."""

    if args.exact and (args.episodes is not None or args.seed is not None):
        raise CliError("--exact computes expectations; it does not take --episodes or --seed")
    chain = get_chain(args.chain)
    env_ids = _env_ids(args.scenario, args.variant)
    _check_max_steps(chain, env_ids, args.beta, args.max_steps)
    policy = _load_policy(args.policy, env_ids, args.allow_other_env)
    episodes = args.episodes if args.episodes is not None else DEFAULT_EPISODES
    drawn = not args.exact and args.seed is None
    if drawn:  # sampling needs a seed; one drawn here is shown, so that the answer can be repeated
        args.seed = drawn_seed()
    results = {}
    for env_id in env_ids:
        try:
            results[env_id] = _evaluate_one(args, policy, env_id, chain, episodes)
        except PolicyFailure as exc:  # the policy raised mid-episode: name it, the env, and the fix
            raise in_context(exc, args.policy, env_id) from exc.__cause__
    mean_metric = sum(r.metric for r in results.values()) / len(results)

    if args.json:
        print(json.dumps(_eval_json(args, chain, results, drawn, mean_metric)))
        return 0
    console = _console()
    console.print(_eval_table(args, chain, results, episodes, drawn))
    console.print(f"mean metric over {len(results)} variant(s): [bold]{mean_metric:.4f}[/bold]  (dim = norm not relevant in that variant)")
    console.print(_columns_legend(chain, args.exact), markup=False, highlight=False, soft_wrap=True)
    if drawn:
        console.print(f"Monte Carlo with a seed drawn at random ({args.seed}): --seed {args.seed} repeats this evaluation")
    return 0


def _eval_json(args: argparse.Namespace, chain: MoralityChain, results: dict[str, Any], drawn: bool, mean_metric: float) -> dict[str, Any]:
    """``eval --json``: the settings, each env's result, and the mean metric."""
    return {
        "chain": chain.name,
        "scenario": scenario_named(args.scenario).name,
        "beta": next(iter(results.values())).beta,
        "exact": bool(args.exact),
        **({} if args.exact else {"seed": args.seed, "seed_drawn": drawn}),  # Monte Carlo: which draws
        "envs": {
            env_id: {
                "metric": r.metric,
                "functions": r.functions,
                "mean_return": r.mean_return,
                "mean_length": r.mean_length,
            }
            for env_id, r in results.items()
        },
        "mean_metric": mean_metric,
    }


def _columns_legend(chain: MoralityChain, exact: bool) -> str:
    """What the table's columns mean: each norm code spelt out, in the chain's order of force."""
    norms = "; ".join(f"{n.abbreviation} = {n.label}" for n in chain.norms)
    spread = "" if exact else "± s.e. = standard error of the metric over the episodes; "
    return (f"columns: metric = the morality metric (0-1, higher is better); {spread}each norm's morality function "
            f"(1 = the norm fully respected), highest force first: {norms}; return = mean episode return; "
            "length = mean episode length (steps)")


def _eval_table(args: argparse.Namespace, chain: MoralityChain, results: dict[str, Any], episodes: int, drawn: bool) -> Any:
    """``eval``'s rich table: one row per env, a column per norm (dim where the norm is not relevant)."""
    from rich.table import Table  # rich waits: `list` and `--help` start without it

    kind = "exact expectation" if args.exact else f"Monte Carlo, {episodes} episodes, seed {args.seed}"
    if drawn:
        kind += " (drawn)"
    beta = next(iter(results.values())).beta
    table = Table(title=f"{chain.name} on {scenario_named(args.scenario).name} ({kind}, beta {beta:g})")
    table.add_column("env id")
    table.add_column("metric", justify="right")
    if not args.exact:
        table.add_column("± s.e.", justify="right")
    for norm in chain.norms:
        table.add_column(norm.abbreviation, justify="right")
    table.add_column("return", justify="right")
    table.add_column("length", justify="right")
    for env_id, r in results.items():
        row = [env_id, f"{r.metric:.4f}"]
        if not args.exact:
            row.append(f"{r.metric_stderr:.4f}")
        for norm in chain.norms:
            value = f"{r.functions[norm.name]:.3f}"
            row.append(value if norm.name in r.relevant else f"[dim]{value}[/dim]")
        row += [f"{r.mean_return:.2f}", f"{r.mean_length:.1f}"]
        table.add_row(*row)
    return table


def cmd_oracle(args: argparse.Namespace) -> int:
    from rich.table import Table  # rich waits: the command line starts without it

    chain = get_chain(args.chain)
    env_ids = _env_ids(args.scenario, args.variant)
    _check_max_steps(chain, env_ids, args.beta, args.max_steps)
    results = {env_id: oracle(env_id, chain, beta=args.beta, max_steps=args.max_steps) for env_id in env_ids}
    first = next(iter(results.values()))
    if args.json:
        out = {
            "chain": chain.name,
            "scenario": scenario_named(args.scenario).name,
            "beta": first.beta,
            "envs": {
                env_id: {
                    "best": {"metric": r.best.metric, "actions": r.best.actions},
                    "worst": {"metric": r.worst.metric, "actions": r.worst.actions},
                }
                for env_id, r in results.items()
            },
        }
        print(json.dumps(out))
        return 0
    short = {i: n[0] if n != "INTERACT" else "I" for i, n in enumerate(ACTION_NAMES)}
    short[4] = "."
    table = Table(title=f"Oracle: {chain.name} on {scenario_named(args.scenario).name} (beta {first.beta:g}, max_steps {args.max_steps})")
    for col in ("env id", "best", "return", "best actions", "worst", "return", "worst actions"):
        table.add_column(col, justify="right" if col in ("best", "worst", "return") else "left")
    for env_id, r in results.items():
        table.add_row(
            env_id,
            f"{r.best.metric:.4f}",
            f"{r.best.ret:g}",
            "".join(short[a] for a in r.best.actions),
            f"{r.worst.metric:.4f}",
            f"{r.worst.ret:g}",
            "".join(short[a] for a in r.worst.actions),
        )
    console = _console()
    console.print(table)
    best = sum(r.best.metric for r in results.values()) / len(results)
    worst = sum(r.worst.metric for r in results.values()) / len(results)
    console.print(f"mean over variants: best {best:.4f}, worst {worst:.4f}   actions: U D L R . (stay) I (interact)")
    return 0


def cmd_list(args: argparse.Namespace) -> int:
    if args.what == "chains":
        for stem_chain in builtin_chains().values():
            print(f"{stem_chain.name:22s} {chain_file_stem(stem_chain):26s} {' > '.join(n.abbreviation for n in stem_chain.norms)}")
    elif args.what == "scenarios":
        for s in scenarios().values():
            print(f"{s.name:28s} {len(s.variants):3d} variants  {s.summary}")
    else:
        for env_id in list_envs(scenario_named(args.scenario).name if args.scenario else None):
            print(env_id)
    return 0


def cmd_docs(args: argparse.Namespace) -> int:
    out = Path(args.output)
    _writable(out, "--output")
    index = ["# MoralityGym environments", "", "Generated by `python -m morality_gym docs` from the scenario files.", ""]
    for s in scenarios().values():
        doc = env_class(s.name).__doc__ or ""
        (out / f"{s.name}.md").write_text(f"# {s.name}\n\n{doc}")
        index.append(f"- [{s.name}]({s.name}.md): {s.summary} ({len(s.variants)} variants)")
    (out / "README.md").write_text("\n".join(index) + "\n")
    print(f"wrote {len(scenarios()) + 1} files to {out}")
    return 0


#: ``generate --count N`` gives up after this many seeds per dilemma asked for (about 1 in 3 seeds
#: is rejected; this many in a row would mean the grammar is broken, not unlucky).
GENERATE_SEEDS_PER_DILEMMA = 20
#: What one kept dilemma writes (scenario YAML, exact values JSON, PNG picture; measured on seeds
#: 0-2: 1.4 kB, 2-5 kB, 8-14 kB), rounded up: for the up-front size estimate of ``generate --count``.
GENERATE_BYTES = {"with pictures": 24_000, "without pictures": 8_000}
#: Seconds of one core per seed tried (about 1.8 s measured on a shared 2-core machine): for the estimate.
GENERATE_SECONDS_PER_SEED = 2.0
#: Above this many dilemmas ``generate`` says first how much disk and time the run will take.
GENERATE_ANNOUNCE = 1_000


def _writable(out: Path, flag: str) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write-probe"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise CliError(f"{flag} {out}: not a writable directory ({exc.strerror or exc}); choose another {flag}") from exc


def cmd_generate(args: argparse.Namespace) -> int:
    """``generate``: new dilemmas from seeds (or a published split's seeds), with pictures and exact values."""
    out = Path(args.out)
    _writable(out, "--out")
    if args.split:
        try:
            report = write_split(args.split, out, pictures=not args.no_pictures, with_values=True,
                                 workers=args.workers, progress=ProgressLine(f"generating split {args.split}"))
        except SplitError as exc:
            raise CliError(str(exc)) from exc
    else:
        _generate_estimate(out, args.count, not args.no_pictures)
        seeds = range(args.seed, args.seed + GENERATE_SEEDS_PER_DILEMMA * args.count)
        report = generate(seeds, out, count=args.count, pictures=not args.no_pictures, workers=args.workers,
                          progress=ProgressLine("generating"))
    _print_generate(report, out, args.split)
    if not args.split and len(report.kept) < args.count:
        raise CliError(f"only {len(report.kept)} of {args.count} dilemmas among seeds {seeds.start}-{seeds.stop - 1}: "
                       "the grammar rejects nearly everything (a bug); see index.json")
    return 0


def _generate_estimate(out: Path, count: int, pictures: bool) -> None:
    """Refuse a ``--count`` whose files cannot fit on ``out``'s disk, and say up front what a large
    one will take (``--count 100000000`` started writing for years with no word of the size)."""
    size = count * GENERATE_BYTES["with pictures" if pictures else "without pictures"]
    free = shutil.disk_usage(out).free
    hours = count * 1.5 * GENERATE_SECONDS_PER_SEED / 3600  # about 1 in 3 seeds is rejected
    if size > free:
        raise CliError(f"--count {count:,}: the dilemmas would take about {_bytes(size)}, but {out} has {_bytes(free)} "
                       f"free (and about {hours:,.0f} hours of one core); ask for fewer")
    if count > GENERATE_ANNOUNCE:
        print(f"generating {count:,} dilemmas: about {_bytes(size)} in {out} and {hours:,.1f} hours of one core "
              f"(at about {GENERATE_SECONDS_PER_SEED:g} s per seed tried)", flush=True)


def _bytes(n: float) -> str:
    for unit in ("bytes", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:,.0f} {unit}" if unit == "bytes" else f"{n:,.1f} {unit}"
        n /= 1000
    return f"{n:,.1f} TB"


def _print_generate(report: RunReport, out: Path, split: str | None) -> None:
    index = report.index
    rejected = index["rejected"]
    assert isinstance(rejected, dict)
    reasons = ", ".join(f"{reason} {len(rejected[reason])}" for reason in REJECTION_REASONS)
    seeds = index["seeds"]
    print(f"kept {index['kept']} of {index['tried']} seeds ({seeds[0]}-{seeds[-1]}) into {out}; rejected: {reasons}")
    per_seed = report.seconds / max(1, len(report.attempts))
    print(f"{report.seconds:.1f} s, {per_seed:.2f} s per seed; digest of the scenario files: {index['digest']}"
          + (f" (matches split {split}'s manifest)" if split else ""))


DEFAULT_EPISODES = EVAL_EPISODES  # Monte-Carlo episodes per env, as the paper's final evaluation


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="python -m morality_gym", description=__doc__.splitlines()[0])
    add_debug_flag(parser)
    sub = parser.add_subparsers(dest="command", required=True)

    p_play = sub.add_parser("play", help="play an env in the terminal")
    play.add_arguments(p_play)
    p_play.set_defaults(func=play.run)

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--chain", required=True, help="chain name (DualProcess), file name (dual_process), abbreviation or YAML path")
        p.add_argument("--scenario", required=True, help="scenario name, e.g. PushOrSwitch")
        p.add_argument("--variant", action="append", help="variant name (repeatable); default: every variant")
        p.add_argument("--beta", type=_beta, default=BETA, help=f"weight resolution (default {BETA}, as the paper; 'derived' = reference default)")
        p.add_argument("--json", action="store_true", help="print one JSON object")

    p_eval = sub.add_parser("eval", help="evaluate a policy's morality metric (Monte Carlo or exact)")
    common(p_eval)
    p_eval.add_argument("--policy", default="random",
                        help="'random', a saved model (.zip), or a callable obs -> action or 6 probabilities given as "
                             "path/to/file.py:function or package.module:function")
    p_eval.add_argument("--max-steps", type=_max_steps, default=MAX_STEPS, help=f"truncate on step max_steps + 1 (default {MAX_STEPS}; 'none')")
    p_eval.add_argument("--exact", action="store_true", help="exact expectation instead of sampling")
    p_eval.add_argument("--episodes", type=positive_int, default=None,
                        help=f"Monte-Carlo episodes per env, 1 or more (default {DEFAULT_EPISODES})")
    p_eval.add_argument("--seed", type=non_negative_int, default=None,
                        help="Monte-Carlo seed (default: one drawn at random and shown, so that the run can be repeated)")
    p_eval.add_argument("--deterministic", action="store_true", help="most likely action instead of sampling (models)")
    p_eval.add_argument("--allow-other-env", action="store_true",
                        help="evaluate a saved model on other variants than the one it was trained on "
                             "(refused otherwise; never possible when the observation sizes differ)")
    p_eval.set_defaults(func=cmd_eval)

    p_oracle = sub.add_parser("oracle", help="best and worst achievable metric and the action sequences")
    common(p_oracle)
    p_oracle.add_argument("--max-steps", type=_max_steps, default=MAX_STEPS)
    p_oracle.set_defaults(func=cmd_oracle)

    p_list = sub.add_parser("list", help="list env ids, scenarios or chains")
    p_list.add_argument("what", nargs="?", choices=["envs", "scenarios", "chains"], default="envs")
    p_list.add_argument("--scenario", default=None)
    p_list.set_defaults(func=cmd_list)

    p_docs = sub.add_parser("docs", help="write Markdown docs of every scenario")
    p_docs.add_argument("--output", default="docs/envs")
    p_docs.set_defaults(func=cmd_docs)

    p_gen = sub.add_parser("generate", help="write new trolley dilemmas from seeds, with pictures and exact values")
    p_gen.add_argument("--seed", type=non_negative_int, default=0, help="first seed (default 0); seeds are tried in order")
    p_gen.add_argument("--count", type=positive_int, default=10, help="dilemmas to keep (default 10); rejected seeds are skipped")
    p_gen.add_argument("--split", choices=split_names(), default=None,
                       help="instead of --seed/--count: every seed of a published split, checked against its digest")
    p_gen.add_argument("--out", required=True, help="directory for <name>.yaml, .json, .png and index.json")
    p_gen.add_argument("--no-pictures", action="store_true", help="skip the PNG pictures (faster)")
    p_gen.add_argument("--workers", type=positive_int, default=1,
                       help="attempt the seeds in this many processes (the files are the same bytes; default 1)")
    p_gen.set_defaults(func=cmd_generate)
    return parser


def user_errors() -> tuple[type[BaseException], ...]:
    """What a user can get wrong here (one line, exit 2); anything else is a bug (traceback)."""

    return (CliError, ChainError, UnknownEnvError, ModelError, ScenarioError, InvalidActionError, PolicyError)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    flags = argv  # --debug is accepted anywhere on the line (run_cli reads it from here)
    argv = [a for a in argv if a != "--debug"]

    def body() -> int:
        args = build_parser().parse_args(argv)
        return int(args.func(args) or 0)

    return run_cli(body, user_errors(), flags)


if __name__ == "__main__":
    sys.exit(main())
