"""``python -m leaderboard.submit POLICY --name "My agent"``: score a policy trained elsewhere.

A policy from another library, a hand-written rule or a language model gets the evaluation every
trained run of the sweep gets, and lands in the results directory as ordinary run rows
(:mod:`morality_gym.results.schema`), so ``python -m leaderboard.build`` shows it next to the baselines:

* for each selected (chain, scenario) cell, each variant of the scenario and each seed of the
  preset (``paper``: 41, 42, 43), the paper's final evaluation: ``eval_episodes`` (100) Monte-Carlo
  episodes of the stochastic policy seeded by the seed, at ``beta`` 0.1 and ``max_steps`` 200 -
  exactly :meth:`morality_gym.baselines.learners.Learner.final_evaluation` of a trained run;
* the exact expectation (``exact_metric``) when the policy is stationary, i.e. its action
  probabilities are a fixed function of the observation (:func:`morality_gym.baselines.policy_ref.is_stationary`:
  ``random`` and saved models always; a callable when asking it twice for every reachable state
  gives the same answers); otherwise ``exact_metric`` is null and the config says why.

Rows are labelled ``algo = "submitted"``, ``learner = <display name>`` and carry provenance in
``config["provenance"]`` (submitter, policy reference, code version) plus the usual ``git_commit``,
``versions``, ``hostname`` and ``started_at``/``finished_at`` columns. A run's id hashes what
determines its numbers (cell, variant, seed, evaluation settings, display name and the SHA-256 of
the policy's files), not the provenance: re-submitting the same files under the same name writes
nothing new, and a changed one gives new runs whose newer configuration the leaderboard counts,
reporting the old ones as superseded (:func:`leaderboard.runs.aggregate.select_configurations`).
The policy's files are its own file and every module and data file beside it that it imports or
opens while it is loaded and answers its first observation (:mod:`morality_gym.baselines.policy_files`),
or every file of a directory declared with ``--policy-dir`` (for a policy that reads files later).
Files are written atomically, one per run, after the whole evaluation of the run succeeded.
"""

from __future__ import annotations

import argparse
import getpass
import json
import math
import os
import shutil
import socket
import sys
from collections.abc import Sequence
from dataclasses import dataclass, replace
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import morality_gym
from leaderboard.runs.display_order import REFERENCE_LEARNERS
from morality_gym.baselines.io import ModelError
from morality_gym.baselines.policy_files import watching
from morality_gym.baselines.policy_ref import LoadedPolicy, PolicyError, is_stationary, load_policy, probe
from morality_gym.baselines.specs import CONF_DIR
from morality_gym.clitools import (
    OneLineParser,
    UserError,
    add_debug_flag,
    did_you_mean,
    non_negative_int,
    positive_float,
    run_cli,
    writing,
)
from morality_gym.constants import BETA, MAX_STEPS
from morality_gym.envs.registry import UnknownEnvError, scenario_named, scenarios
from morality_gym.envs.trolley import InvalidActionError
from morality_gym.evaluation.deadline import Deadline, PolicyTimeout
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.gif import record_episode
from morality_gym.evaluation.montecarlo import evaluate
from morality_gym.evaluation.policies import PolicyFailure
from morality_gym.norms.chain import ChainError, MoralityChain, get_chain
from morality_gym.norms.metric import bind_chain
from morality_gym.paper import LEARNERS, table1
from morality_gym.results.identity import PROVENANCE_KEY as PROVENANCE
from morality_gym.results.identity import SUBMITTED_ALGO as SUBMITTED
from morality_gym.results.identity import run_identity
from morality_gym.results.presets import PresetError, load_preset
from morality_gym.results.quarantine import read_table_or_quarantine
from morality_gym.results.recording import RunClock, RunLock, finished_status, git_commit, utc_now, versions
from morality_gym.results.schema import MF_PREFIX, SCHEMA_VERSION, run_path, runs_dir, write_run

DEFAULT_PROTOCOL = "paper"
DEFAULT_PRESET = "paper"
#: How long a callable policy may take to answer one observation (``--timeout``): a rule or a
#: network answers in microseconds to milliseconds; one that calls a remote service may take
#: seconds; a minute without an answer is a hang.
DEFAULT_TIMEOUT_S = 60.0
#: A GIF shows one evaluation episode of up to this many steps (as a trained run's render episode).
GIF_STEPS = 50


# ---------------------------------------------------------------------------------------- selection
@dataclass(frozen=True)
class Cell:
    """One Table 1 cell to evaluate: a chain on the chosen variants of a scenario."""

    chain: Any  # MoralityChain
    scenario: str
    variants: tuple[str, ...]


def scenario_by_any_name(name: str) -> str:
    """A scenario's name from either spelling (``push_or_switch`` or ``PushOrSwitch``)."""
    by_key = {s.replace("_", "").lower(): s for s in scenarios()}
    found = by_key.get(name.replace("_", "").replace("-", "").lower())
    if found is not None:
        return found
    return scenario_named(name).name  # raises UnknownEnvError with the closest names


def select_cells(chains: Sequence[str], scenario_names: Sequence[str], variants: Sequence[str]) -> list[Cell]:
    """The cells of a selection (the sweep's names): chains x scenarios when both are given; the
    Table 1 scenarios of the chains, or the Table 1 chains of the scenarios, when one is; every
    Table 1 cell when neither is. ``variants`` keeps only those variants (each must exist in at
    least one selected scenario)."""
    pairs = _selected_pairs([get_chain(c) for c in chains], [scenario_by_any_name(s) for s in scenario_names])
    _check_variants(pairs, variants)
    cells = []
    seen: set[tuple[str, str]] = set()
    for chain, scenario in pairs:
        if (chain.name, scenario) in seen:
            continue
        seen.add((chain.name, scenario))
        keep = tuple(v for v in scenario_named(scenario).variants if not variants or v in variants)
        if keep:
            cells.append(Cell(chain, scenario, keep))
    if not cells:
        raise UserError(f"no selected scenario has the variant(s) {', '.join(variants)}")
    return cells


def _selected_pairs(wanted_chains: list[MoralityChain], wanted_scenarios: list[str]) -> list[tuple[MoralityChain, str]]:
    """(chain, scenario) pairs of the selection, before de-duplication (see :func:`select_cells`)."""
    rows = [(get_chain(r.chain), r.scenario) for r in table1()]
    if wanted_chains and wanted_scenarios:
        return [(c, s) for c in wanted_chains for s in wanted_scenarios]
    if wanted_chains:
        names = {c.name for c in wanted_chains}
        pairs = [(c, s) for c, s in rows if c.name in names]
        if not pairs:
            raise UserError(f"chain {', '.join(sorted(names))} is in no Table 1 cell; name the scenario(s) with --scenario")
        return pairs
    if wanted_scenarios:
        pairs = [(c, s) for c, s in rows if s in wanted_scenarios]
        if not pairs:
            raise UserError(f"scenario {', '.join(wanted_scenarios)} is in no Table 1 cell; name the chain(s) with --chain")
        return pairs
    return rows


def _check_variants(pairs: list[tuple[MoralityChain, str]], variants: Sequence[str]) -> None:
    """Every asked-for variant must exist in at least one selected scenario (else a did-you-mean error)."""
    all_variants = {v for _, s in pairs for v in scenario_named(s).variants}
    unknown = [v for v in variants if v not in all_variants]
    if unknown:
        hint = did_you_mean(unknown[0], sorted(all_variants), n=3, quote=False)
        raise UserError(f"--variant {unknown[0]}: no selected scenario has it{hint}; variants: {', '.join(sorted(all_variants))}")


def preset_facts(preset: str) -> tuple[tuple[int, ...], int]:
    """(seeds, final-evaluation episodes) of ``conf/preset/<preset>.yaml``, read and checked by the
    sweep's own preset schema (:func:`morality_gym.results.presets.load_preset`)."""
    try:
        loaded = load_preset(preset)
    except PresetError as exc:
        raise UserError(f"--preset {preset}: {exc}") from exc
    return loaded.seeds, loaded.eval_episodes


# ---------------------------------------------------------------------------------------- provenance
def code_version() -> str:
    """The git commit of this checkout, else the installed package's version."""
    commit = git_commit()
    if commit != "unknown":
        return commit

    try:
        return f"morality-gym {version('morality-gym')}"
    except PackageNotFoundError:
        return f"morality-gym {morality_gym.__version__}"


def check_name(name: str) -> str:
    """A display name that cannot pass for one of the paper's learners or a reference row."""
    cleaned = " ".join(str(name).split())
    if not cleaned:
        raise UserError("--name must not be empty: it is the entry's label on the leaderboard")
    if len(cleaned) > 80:
        raise UserError(f"--name is {len(cleaned)} characters long; use at most 80")
    taken = {n.lower() for n in (*LEARNERS, *REFERENCE_LEARNERS)}
    if cleaned.lower() in taken:
        raise UserError(f"--name {cleaned!r} is the name of a baseline or reference row; choose another name")
    return cleaned


# ---------------------------------------------------------------------------------------- runs
@dataclass(frozen=True)
class Submission:
    """What is submitted and how it is evaluated (everything except the cell)."""

    name: str
    loaded: Any  # morality_gym.baselines.policy_ref.LoadedPolicy
    sha256: str
    submitter: str
    protocol: str
    preset: str
    seeds: tuple[int, ...]
    eval_episodes: int
    beta: float
    max_steps: int
    gif: bool
    #: The environment steps the policy trained for, where it was trained (the torch example's
    #: ``--total-steps``, ``--budget``); 0: not known, or not trained (a rule, a language model).
    #: Recorded as the run's ``budget``: a cell at another budget than its preset's is marked not
    #: comparable beside the paper's values (:func:`leaderboard.runs.cells.delta_note`).
    budget: int = 0
    #: The steps actually trained (``total_steps``): the budget rounded to whole updates; 0 when not known.
    trained_steps: int = 0


def build_hint(results: Path, cwd: Path | None = None) -> str:
    """What to run next: in a checkout, ``make leaderboard``, which rebuilds the site the user
    already has (``leaderboard/site``, the releases beside their runs); ``leaderboard.build
    --results`` alone would build a second site without them. Elsewhere (an installed package),
    the build command itself."""
    here = Path.cwd() if cwd is None else cwd
    if (here / "Makefile").is_file() and (here / "releases").is_dir():
        return "make leaderboard" if Path(results) == Path("results") else f"make leaderboard RESULTS={results}"
    return f"python -m leaderboard.build --results {results}"


def run_config(sub: Submission, cell: Cell, variant: str, seed: int, stationary: bool) -> dict[str, Any]:
    """The recorded config of one submitted run (identity + ``provenance``)."""
    target = sub.loaded.ref.rsplit(":", 1)[1] if sub.loaded.kind == "callable" and ":" in sub.loaded.ref else None
    return {
        "schema_version": SCHEMA_VERSION,
        "env_id": scenario_named(cell.scenario).env_id(variant),
        "scenario": cell.scenario,
        "variant": variant,
        "chain": {"name": cell.chain.name, "norms": [[n.name, n.modality] for n in cell.chain.norms]},
        "algo": {"name": SUBMITTED, "label": sub.name},  # no learner class: the policy came from outside
        "protocol": {"name": sub.protocol},
        "preset": sub.preset,
        "seed": int(seed),
        "budget": int(sub.budget),
        "beta": sub.beta,
        "max_steps": sub.max_steps,
        "eval_episodes": sub.eval_episodes,
        "policy": {"kind": sub.loaded.kind, "sha256": sub.sha256, "attribute": target, "stationary": stationary},
        PROVENANCE: {"submitter": sub.submitter, "policy": sub.loaded.ref,
                     "files": [str(p) for p in sub.loaded.files]},
    }


def at(sub: Submission, where: str) -> None:
    """Tell a time-bounded policy (:class:`~morality_gym.evaluation.deadline.Deadline`) what it is asked about now."""
    if isinstance(sub.loaded.policy, Deadline):
        sub.loaded.policy.where = where


def bounded(loaded: LoadedPolicy, seconds: float) -> LoadedPolicy:
    """``loaded`` with each answer of a callable policy bounded to ``seconds`` (the user's code may
    hang; random and saved models are ours and are left as they are)."""
    policy = loaded.policy
    if loaded.kind != "callable" or not callable(policy) or hasattr(policy, "predict"):
        return loaded
    return replace(loaded, policy=Deadline(policy, seconds, loaded.ref))


def evaluate_run(sub: Submission, cell: Cell, config: dict[str, Any], run_id: str, results: Path) -> dict[str, Any]:
    """Evaluate one (cell, variant, seed) and return its schema row (nothing written yet)."""
    clock = RunClock.start()
    env_id = config["env_id"]
    bound = bind_chain(cell.chain, env_id, sub.beta)
    where = f"{env_id}, seed {config['seed']}"
    at(sub, f"{where}, Monte-Carlo evaluation")
    final = evaluate(sub.loaded.policy, env_id, bound, n_episodes=sub.eval_episodes, seed=config["seed"],
                     max_steps=sub.max_steps, keep_episodes=False)
    at(sub, f"{where}, exact evaluation")
    exact = exact_evaluate(sub.loaded.policy, env_id, bound, max_steps=sub.max_steps) if config["policy"]["stationary"] else None
    gif_rel = None
    if sub.gif:
        at(sub, f"{where}, GIF episode")
        gif = runs_dir(results) / run_id / "episode.gif"
        with writing(gif):
            record_episode(env_id, sub.loaded.policy, gif, max_steps=GIF_STEPS, seed=config["seed"] + 7919,
                           env_kwargs={"max_steps": sub.max_steps})
        gif_rel = str(gif.relative_to(results))
    wall, cpu = clock.elapsed()
    return {
        "schema_version": SCHEMA_VERSION, "run_id": run_id, "status": "ok", "error": None, "traceback": None,
        "env_id": env_id, "scenario": cell.scenario, "variant": config["variant"], "chain": cell.chain.name,
        "algo": SUBMITTED, "learner": sub.name, "protocol": sub.protocol, "preset": sub.preset,
        "seed": int(config["seed"]), "budget": int(sub.budget), "total_steps": int(sub.trained_steps), "beta": float(sub.beta), "max_steps": sub.max_steps,
        "eval_episodes": sub.eval_episodes, "relevant_norms": list(bound.relevant),
        "metric": final.metric, "metric_stderr": final.metric_stderr,
        "exact_metric": None if exact is None else exact.metric,
        "mean_return": final.mean_return, "mean_cost": final.mean_cost, "mean_length": final.mean_length,
        "truncation_rate": final.truncation_rate, "goal_rate": final.goal_rate,
        "wall_time_s": wall, "cpu_time_s": cpu, "started_at": clock.started, "finished_at": utc_now(),
        "hostname": socket.gethostname(), "git_commit": git_commit(), "versions": versions(),
        "config": json.dumps(config, sort_keys=True), "model_path": None, "gif_path": gif_rel,
        "engine": None,  # a submitted policy was not trained here
        **{f"{MF_PREFIX}{n}": final.functions[n] for n in cell.chain.norm_names},
    }


def submit(sub: Submission, cells: Sequence[Cell], results: Path, say: Any = print) -> dict[str, int]:
    """Evaluate and write every run of ``cells`` that is not in ``results`` yet; returns counts."""
    counts = {"written": 0, "present": 0}
    for cell in cells:
        scenario = scenario_named(cell.scenario)
        cell_metrics: list[float] = []
        for variant in cell.variants:
            metrics: list[float] = []
            exacts: list[float] = []
            env_id = scenario.env_id(variant)
            at(sub, f"{env_id}, first observation")
            probe(sub.loaded, env_id)  # a policy that cannot answer fails before anything is written
            at(sub, f"{env_id}, stationarity check (every reachable state, twice)")
            stationary = is_stationary(sub.loaded, env_id)
            for seed in sub.seeds:
                config = run_config(sub, cell, variant, seed, stationary)
                run_id = run_identity(config)  # the content hash of the config without the provenance
                lock = RunLock(results, run_id)
                if not lock.acquire():
                    raise UserError(f"run {run_id} ({env_id}, seed {seed}) is being written by another submission; "
                                    "wait for it to finish and submit again")
                try:
                    if finished_status(results, run_id) == "ok":
                        counts["present"] += 1
                        metric, exact = stored_scores(results, run_id)
                        metrics.append(metric)
                        exacts += [] if exact is None else [exact]
                        continue
                    row = evaluate_and_write(sub, cell, config, run_id, results)
                    counts["written"] += 1
                    metrics.append(float(row["metric"]))
                    exacts += [] if row["exact_metric"] is None else [float(row["exact_metric"])]
                finally:
                    lock.release()
            cell_metrics += metrics
            exact_text = f", exact {sum(exacts) / len(exacts):.4f}" if exacts else ""
            say(f"  {cell.chain.name} / {env_id}: metric {sum(metrics) / len(metrics):.4f} over {len(sub.seeds)} seed(s)"
                + (exact_text if stationary else " (not stationary: Monte Carlo only, no exact metric)"))
        say(f"{cell.chain.name} / {cell.scenario}: mean metric {sum(cell_metrics) / len(cell_metrics):.4f} over "
            f"{len(cell.variants)} variant(s) x {len(sub.seeds)} seed(s) (these runs' mean)")
    return counts


def evaluate_and_write(sub: Submission, cell: Cell, config: dict[str, Any], run_id: str, results: Path) -> dict[str, Any]:
    """Evaluate one run and write its row; any failure (of the policy, of the disk) is one named
    line, and leaves nothing of this run behind (its GIF is removed with it): runs written before stay."""
    where = f"{config['env_id']}, seed {config['seed']}"
    try:
        try:
            row = evaluate_run(sub, cell, config, run_id, results)
        except PolicyFailure as exc:  # the policy raised at some step: say where, keep what is written
            raise PolicyError(f"policy {sub.loaded.ref} failed while evaluating {where}: {exc}; "
                              "runs written so far are kept") from exc.__cause__
        except (UserError, ValueError):
            raise  # already a named user error (InvalidActionError is a ValueError)
        except Exception as exc:  # the user's code failed mid-evaluation: say where, keep what is written
            raise PolicyError(f"policy {sub.loaded.ref} failed while evaluating {where} "
                              f"({type(exc).__name__}: {exc}); runs written so far are kept") from exc
        write_run(results, row, cell.chain.norm_names)
    except BaseException:
        remove_artifacts(results, run_id)
        raise
    return row


def remove_artifacts(results: Path, run_id: str) -> None:
    """Remove ``runs/<run_id>/`` (what a run writes besides its row) of a run whose row was not written."""
    shutil.rmtree(runs_dir(results) / run_id, ignore_errors=True)


def stored_scores(results: Path, run_id: str) -> tuple[float, float | None]:
    """(metric, exact metric or None) of a run already in ``results`` (re-submission: shown again)."""
    table = read_table_or_quarantine(results, run_path(results, run_id), columns=["metric", "exact_metric"])
    if table is None:
        return math.nan, None
    exact = table.column("exact_metric")[0].as_py()
    return float(table.column("metric")[0].as_py()), None if exact is None else float(exact)


# ---------------------------------------------------------------------------------------- command line
def build_parser() -> argparse.ArgumentParser:
    """The command's parser, apart from parsing: the docs' command-line reference is generated from it."""
    parser = OneLineParser(prog="python -m leaderboard.submit", description=__doc__.splitlines()[0])
    parser.add_argument("policy", help="path/to/file.py:function, package.module:function (a callable obs -> action or "
                                       "6 probabilities), a saved model (model.zip) or 'random'")
    parser.add_argument("--name", required=True, help="display name of the entry on the leaderboard")
    parser.add_argument("--chain", action="append", default=[],
                        help="chain (repeatable; utility, dual_process, DualProcess, DP, or a chain file)")
    parser.add_argument("--scenario", action="append", default=[],
                        help="scenario (repeatable; push_or_switch or PushOrSwitch); default: the Table 1 cells of the chains")
    parser.add_argument("--variant", action="append", default=[], help="variant to keep (repeatable); default: every variant")
    parser.add_argument("--results", type=Path, default=Path("results"), help="results directory (default: results)")
    parser.add_argument("--submitter", default=None, help="who submits (default: $USER)")
    parser.add_argument("--protocol", default=DEFAULT_PROTOCOL,
                        help=f"the sweep group to appear in, as the learners' protocol (default {DEFAULT_PROTOCOL}); "
                             "the evaluation is the same for every protocol")
    parser.add_argument("--preset", default=DEFAULT_PRESET,
                        help=f"seeds and episodes of the final evaluation, from conf/preset (default {DEFAULT_PRESET})")
    parser.add_argument("--policy-dir", type=Path, default=None, metavar="DIR",
                        help="every file under DIR is part of the policy (its identity: a changed file is a new "
                             "submission); default: the policy file and the modules and files beside it that it "
                             "imports or opens while loading and answering its first observation")
    parser.add_argument("--allow-other-env", action="store_true",
                        help="a saved model: evaluate it on other variants than the one it was trained on")
    parser.add_argument("--budget", type=non_negative_int, default=0, metavar="STEPS",
                        help="the environment steps the policy was trained for, recorded with its runs (default 0: not "
                             "known or not trained); at another budget than the preset's, its cells are marked not comparable")
    parser.add_argument("--no-gif", action="store_true", help="do not record a GIF of one episode per run")
    parser.add_argument("--timeout", type=positive_float, default=DEFAULT_TIMEOUT_S, metavar="SECONDS",
                        help=f"the longest a callable policy may take to answer one observation (default {DEFAULT_TIMEOUT_S:g}); "
                             "a policy that takes longer stops the submission with one line, and nothing of the run is written")
    add_debug_flag(parser)
    return parser


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def _submitter(given: str | None) -> str:
    if given:
        return given
    try:
        return os.environ.get("USER") or getpass.getuser()
    except (KeyError, OSError):
        return "unknown"


def run(args: argparse.Namespace) -> int:
    name = check_name(args.name)
    cells = select_cells(args.chain, args.scenario, args.variant)
    seeds, episodes = preset_facts(args.preset)

    protocols = sorted(p.stem for p in (CONF_DIR / "protocol").glob("*.yaml"))
    if protocols and args.protocol not in protocols:
        hint = did_you_mean(args.protocol, protocols, n=3, quote=False)
        raise UserError(f"--protocol {args.protocol}: unknown{hint}; protocols: {', '.join(protocols)}")

    env_ids = [scenario_named(c.scenario).env_id(v) for c in cells for v in c.variants]
    loaded = bounded(load_policy(args.policy, env_ids, args.allow_other_env), args.timeout)
    loaded = policy_files(loaded, args.policy_dir, env_ids[0])
    results: Path = args.results
    try:
        results.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--results {results}: cannot create it ({exc.strerror or exc})") from exc
    if not os.access(results, os.W_OK):
        raise UserError(f"--results {results}: not writable; pass another --results DIR")
    sub = Submission(name=name, loaded=loaded, sha256=loaded.sha256(), submitter=_submitter(args.submitter),
                     protocol=args.protocol, preset=args.preset, seeds=seeds, eval_episodes=episodes,
                     beta=BETA, max_steps=MAX_STEPS, gif=not args.no_gif, budget=args.budget, trained_steps=args.budget)
    n_runs = sum(len(c.variants) for c in cells) * len(seeds)
    print(f"submitting {loaded.ref} as {name!r} (sha256 {sub.sha256[:12]} over {_files_text(loaded)}): "
          f"{len(cells)} cell(s), {n_runs} run(s), "
          f"{episodes} episodes per run, protocol {args.protocol}, preset {args.preset}", flush=True)
    try:
        counts = submit(sub, cells, results, say=lambda line: print(line, flush=True))
    except PolicyTimeout as exc:  # a BaseException, past the evaluators' handlers: one line here
        raise PolicyError(str(exc)) from None
    print(f"wrote {counts['written']} run(s), {counts['present']} already present, in {results / 'runs'}; "
          f"now: {build_hint(results)}")
    return 0


def policy_files(loaded: LoadedPolicy, declared: Path | None, env_id: str) -> LoadedPolicy:
    """``loaded`` with every file its identity covers: a declared directory's files, or the files
    beside the policy it opens while answering its first observation on ``env_id`` (those it
    imports were counted when it was loaded). A saved model's files are its ``.zip`` and ``.json``."""
    if declared is not None:
        if loaded.kind != "callable" or not loaded.files:
            raise UserError(f"--policy-dir {declared}: only for a policy of Python code (file.py:function or module:function)")
        if not declared.is_dir():
            raise UserError(f"--policy-dir {declared}: not a directory")
        return loaded.with_directory(declared)
    if loaded.kind != "callable" or loaded.root is None:
        return loaded
    if isinstance(loaded.policy, Deadline):
        loaded.policy.where = f"{env_id}, first observation"
    with watching(loaded.root) as seen:
        try:
            probe(loaded, env_id)
        except PolicyTimeout as exc:  # a BaseException, past the evaluators' handlers: one line here
            raise PolicyError(str(exc)) from None
    return loaded.with_files(seen)


def _files_text(loaded: LoadedPolicy) -> str:
    """``my_rule.py`` or ``my_rule.py and 2 more file(s)`` (the provenance lists them all)."""
    if not loaded.files:
        return "the reference"
    more = len(loaded.files) - 1
    return loaded.files[0].name + (f" and {more} more file(s)" if more else "")


def user_errors() -> tuple[type[BaseException], ...]:
    return (ChainError, UnknownEnvError, ModelError, InvalidActionError)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    return run_cli(lambda: run(parse_args(argv)), user_errors(), argv)


if __name__ == "__main__":
    sys.exit(main())
