"""``python -m leaderboard.llm``: a language-model agent on the leaderboard, beside the RL baselines.

Two commands:

* ``run``: play the chain's dilemmas with a model through Inspect AI
  (:mod:`morality_gym.llm.inspect_tasks`), then ``import`` the log. ``--model openai/gpt-4o-mini``
  (any Inspect provider) for a hosted model; ``--model mockllm/model --script FILE`` for Inspect's
  mock model answering from a script (offline: line ``k`` of the file is the answer at step ``k``,
  the last line repeats), which is how the tests and the docs' example run end to end.
* ``import LOG...``: turn Inspect logs (from ``run`` or from ``inspect eval``) into submitted runs.

Each sample (one episode of one env id) becomes one submitted run row (:mod:`morality_gym.results.schema`):
``algo`` ``submitted``, ``learner`` the ``--name``, ``seed`` the episode's sampling seed, and the
episode's own morality metric and morality functions. So the leaderboard's cell mean is the mean
over episodes (equal per variant), and its interval (whole sampling seeds resampled, each with its
episodes on every variant, :mod:`leaderboard.stats.cells`) is the bootstrap interval over them. The run config records the model, framing, temperature, answer
mode, episodes per variant and the preset; ``config["provenance"]`` the submitter, the tokens and calls
of the episode, its fallback steps and the log file with the transcript. A run's id hashes the
config without provenance, so importing a log twice writes nothing new.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import socket
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from leaderboard.runs.aggregate import LLM_POLICY_KIND
from leaderboard.submit import _submitter, check_name, code_version
from morality_gym.clitools import OneLineParser, UserError, add_debug_flag, positive_float, run_cli
from morality_gym.constants import BETA
from morality_gym.envs.registry import UnknownEnvError, parse_env_id
from morality_gym.llm.episode import EPISODE_KEY
from morality_gym.llm.settings import ANSWER_MODES, DEFAULT_PRESET, PRESETS, PROMPT_MODES, AgentSettings, SettingsError
from morality_gym.llm.text import FRAMINGS, FramingError
from morality_gym.llm.tokens import estimate_tokens
from morality_gym.norms.chain import ChainError, get_chain
from morality_gym.results.identity import PROVENANCE_KEY as PROVENANCE
from morality_gym.results.identity import SUBMITTED_ALGO as SUBMITTED
from morality_gym.results.identity import run_identity
from morality_gym.results.recording import RunLock, finished_status, versions
from morality_gym.results.schema import MF_PREFIX, SCHEMA_VERSION, write_run

# Inspect AI (the llm extra) is imported inside the functions that run or read it, so that
# --help and the one-line errors work without the extra installed.

DEFAULT_LOG_DIR = Path("logs") / "llm"
#: How long one model call may take, retries included (``run --timeout``): hosted models answer in
#: seconds; ten minutes without an answer is a provider that hangs.
DEFAULT_TIMEOUT_S = 600.0


@dataclass(frozen=True)
class Episode:
    """One scored sample of an Inspect log."""

    sample_id: str
    env_id: str
    seed: int
    chain: str
    metric: float
    functions: dict[str, float]
    relevant: list[str]
    record: dict[str, Any]  # morality_gym.llm.inspect_tasks.episode_record
    model: str
    log: str
    started_at: str
    finished_at: str
    wall_time_s: float


def read_episodes(path: Path) -> tuple[list[Episode], dict[str, Any]]:
    """The scored episodes of an Inspect log and the task's ``morality_gym`` metadata."""
    log, meta = _read_log(path)
    # The temperature the calls used: the task's, else Inspect's --temperature, else the provider's default.
    eval_temperature = log.plan.config.temperature if log.plan is not None else None
    episodes = [_episode(path, log, meta, sample, EPISODE_KEY, eval_temperature) for sample in log.samples or []]
    if not episodes:
        raise UserError(f"{path}: the log has no samples")
    return episodes, meta


def _read_log(path: Path) -> tuple[Any, dict[str, Any]]:
    """The Inspect log (``EvalLog``) of a finished MoralityGym task, and its ``morality_gym`` metadata."""
    # Inspect waits: importing leaderboard.llm (its --help too) must not load it
    from inspect_ai.log import read_eval_log

    if not path.is_file():
        raise UserError(f"{path}: no such Inspect log file")
    try:
        log = read_eval_log(str(path))
    except Exception as exc:  # Inspect raises several types for a file it cannot read
        raise UserError(f"{path}: not an Inspect log ({type(exc).__name__}: {exc})") from exc
    meta = (log.eval.metadata or {}).get("morality_gym")
    if not isinstance(meta, dict):
        raise UserError(f"{path}: not a MoralityGym task's log (no 'morality_gym' task metadata); "
                        "run the tasks of morality_gym/llm/inspect_tasks.py")
    if log.status != "success":
        raise UserError(f"{path}: the evaluation did not finish (status {log.status}); "
                        "rerun it (inspect eval-retry resumes it) and import the finished log")
    return log, meta


def _episode(path: Path, log: Any, meta: dict[str, Any], sample: Any, episode_key: str,
             eval_temperature: float | None) -> Episode:
    """One scored sample as an :class:`Episode` (a sample without a score is an error: rerun it first)."""
    score = (sample.scores or {}).get("morality_score")
    record = sample.store.get(episode_key)
    if score is None or record is None or sample.error:
        raise UserError(f"{path}: sample {sample.id} has no score ({sample.error or 'not scored'}); "
                        "rerun the failed samples before importing")
    value = dict(score.value)
    record = dict(record)
    settings = dict(record["settings"])
    if settings.get("temperature") is None:
        settings["temperature"] = eval_temperature if eval_temperature is not None else "provider default"
    record["settings"] = settings
    return Episode(
        sample_id=str(sample.id), env_id=str(sample.metadata["env_id"]), seed=int(sample.metadata["seed"]),
        chain=str(meta["chain"]), metric=float(value.pop("metric")),
        functions={k[3:]: float(v) for k, v in value.items() if k.startswith("mf_")},
        relevant=list((score.metadata or {}).get("relevant_norms", [])), record=dict(record),
        model=str(log.eval.model), log=str(path), started_at=str(log.stats.started_at or ""),
        finished_at=str(log.stats.completed_at or ""),
        wall_time_s=float(sample.total_time or 0.0),
    )


def episode_config(ep: Episode, meta: dict[str, Any], name: str, protocol: str, preset: str, submitter: str) -> dict[str, Any]:
    """The recorded config of one episode's run (identity, plus ``provenance`` outside it)."""

    scenario, variant = parse_env_id(ep.env_id)
    chain = get_chain(ep.chain)
    settings = ep.record["settings"]
    return {
        "schema_version": SCHEMA_VERSION,
        "env_id": ep.env_id, "scenario": scenario.name, "variant": variant,
        "chain": {"name": chain.name, "norms": [[n.name, n.modality] for n in chain.norms]},
        "algo": {"name": SUBMITTED, "label": name},
        "protocol": {"name": protocol}, "preset": preset, "seed": ep.seed, "budget": 0,
        "beta": BETA, "max_steps": int(settings["max_steps"]), "eval_episodes": 1,
        "policy": {"kind": LLM_POLICY_KIND, "model": ep.model, **settings,
                   "llm_preset": meta.get("preset"), "episodes_per_variant": int(meta.get("episodes", 0))},
        PROVENANCE: {"submitter": submitter, "log": ep.log, "sample": ep.sample_id,
                     "calls": ep.record["calls"], "input_tokens": ep.record["input_tokens"],
                     "output_tokens": ep.record["output_tokens"], "fallbacks": ep.record["fallbacks"],
                     "unreadable": ep.record["unreadable"],
                     # the prompt's size (a compact prompt's bound; logs before issue 49 lack them)
                     "max_prompt_chars": ep.record.get("max_prompt_chars"),
                     "max_input_tokens": ep.record.get("max_input_tokens")},
    }


def episode_row(ep: Episode, config: dict[str, Any], run_id: str) -> dict[str, Any]:
    """The schema row of one episode's run."""

    r = ep.record
    return {
        "schema_version": SCHEMA_VERSION, "run_id": run_id, "status": "ok", "error": None, "traceback": None,
        "env_id": ep.env_id, "scenario": config["scenario"], "variant": config["variant"], "chain": config["chain"]["name"],
        "algo": SUBMITTED, "learner": config["algo"]["label"], "protocol": config["protocol"]["name"],
        "preset": config["preset"], "seed": ep.seed, "budget": 0, "total_steps": 0, "beta": config["beta"],
        "max_steps": config["max_steps"], "eval_episodes": 1, "relevant_norms": ep.relevant,
        "metric": ep.metric, "metric_stderr": math.nan, "exact_metric": None,
        "mean_return": float(r["return"]), "mean_cost": None, "mean_length": float(r["length"]),
        "truncation_rate": float(bool(r["truncated"])), "goal_rate": float(bool(r["goal_reached"])),
        # the model's compute is not ours to measure: an Inspect log records wall time only
        "wall_time_s": ep.wall_time_s, "cpu_time_s": None, "started_at": ep.started_at, "finished_at": ep.finished_at,
        "hostname": socket.gethostname(), "git_commit": code_version(), "versions": versions(),
        "config": json.dumps(config, sort_keys=True), "model_path": None, "gif_path": None, "engine": None,
        **{f"{MF_PREFIX}{n}": ep.functions[n] for n in ep.functions},
    }


def import_logs(paths: Sequence[Path], name: str, results: Path, protocol: str, preset: str,
                submitter: str) -> dict[str, int]:
    """Write the run of every episode of ``paths`` not in ``results`` yet; returns counts."""

    loaded = [read_episodes(Path(p)) for p in paths]  # every log is checked before anything is written
    counts = {"written": 0, "present": 0, "episodes": 0, "fallback_only": 0}
    for episodes, meta in loaded:
        for ep in episodes:
            counts["episodes"] += 1
            counts["fallback_only"] += fallback_only(ep)
            config = episode_config(ep, meta, name, protocol, preset, submitter)
            run_id = run_identity(config)
            lock = RunLock(results, run_id)
            if not lock.acquire():
                raise UserError(f"run {run_id} ({ep.env_id}, seed {ep.seed}) is being written by another process; retry later")
            try:
                if finished_status(results, run_id) == "ok":
                    counts["present"] += 1
                    continue
                write_run(results, episode_row(ep, config, run_id), get_chain(ep.chain).norm_names)
                counts["written"] += 1
            finally:
                lock.release()
    return counts


def fallback_only(ep: Episode) -> bool:
    """Whether every step of the episode was played by the fallback action (no answer of the model
    was used): its metric measures ``--fallback``, not the model."""
    length = int(ep.record.get("length") or 0)
    return length > 0 and int(ep.record.get("fallbacks") or 0) >= length


def fallback_warning(counts: dict[str, int]) -> str | None:
    """One line when some imported episodes were played by the fallback action alone, else None."""
    n = counts.get("fallback_only", 0)
    if not n:
        return None
    which = "every" if n == counts["episodes"] else f"{n} of the {counts['episodes']}"
    return (f"warning: in {which} episode(s) no answer of the model was used (each step fell back to --fallback "
            "after its retries): those runs measure the fallback action, not the model; check the model's answers "
            "in the log (the format asked for, a provider error)")


# ---------------------------------------------------------------------------------------- running Inspect
def scripted_model(script: Path) -> Any:
    """Inspect's mock model answering from ``script``: line ``k`` at step ``k`` (the last line repeats).

    The step is read from the latest observation (``Step k``), so the answers do not depend on the
    order in which Inspect runs samples. Tokens are set to the rule-of-thumb estimate
    (:func:`morality_gym.llm.tokens.estimate_tokens`): the mock's own count needs a tokenizer download.
    """

    from inspect_ai.model import ModelOutput, ModelUsage, get_model  # the llm extra: loaded by this command only

    try:
        lines = script.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise UserError(f"--script {script}: cannot read it ({exc.strerror or exc})") from exc
    except UnicodeDecodeError as exc:
        line = script.read_bytes()[: exc.start].count(b"\n") + 1
        raise UserError(f"--script {script}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} on line {line}); "
                        "save the answers as UTF-8, one per line") from exc
    if not lines:
        raise UserError(f"--script {script}: empty; write one answer per line")

    def answer(messages: list[Any], tools: Any, tool_choice: Any, config: Any) -> Any:
        seen = [m.text for m in messages if m.role in ("user", "tool") and m.text.startswith("Step ")]
        step = int(re.match(r"Step (\d+)", seen[-1]).group(1)) if seen else 0  # type: ignore[union-attr]
        text = lines[min(step, len(lines) - 1)]
        output = ModelOutput.from_content(model="mockllm/model", content=text)
        prompt = estimate_tokens("\n".join(m.text for m in messages))
        output.usage = ModelUsage(input_tokens=prompt, output_tokens=estimate_tokens(text),
                                  total_tokens=prompt + estimate_tokens(text))
        return output

    return get_model("mockllm/model", custom_outputs=answer, memoize=False)


def run_inspect(args: argparse.Namespace) -> list[Path]:
    """Run the task of each ``--chain`` with Inspect; returns the log files."""
    # Inspect waits: importing leaderboard.llm (its --help too) must not load it
    from inspect_ai import eval as inspect_eval

    from morality_gym.llm.inspect_tasks import morality_gym_task

    model = model_of(args)
    logs: list[Path] = []
    for chain in args.chain or ["Utility"]:
        task = morality_gym_task(
            chain, scenario=args.scenario or None, variant=args.variant or None, env=args.env or None,
            preset=args.llm_preset, episodes=args.episodes, framing=args.framing, answer=args.answer,
            window=args.window, max_retries=args.max_retries, fallback=args.fallback, temperature=args.temperature,
            seed=args.seed, max_tokens=args.max_tokens, prompt=args.prompt, recent=args.recent, cache=args.cache,
        )
        # Inspect bounds no model call by default (its timeout and attempt_timeout are None, its
        # retries unlimited): a provider that stops answering would hang the run. --timeout bounds
        # each call, retries included; past it the sample fails and the run ends with one line.
        result = inspect_eval(task, model=model, log_dir=str(args.log_dir), display=args.display,
                              max_connections=args.max_connections, timeout=math.ceil(args.timeout),
                              attempt_timeout=math.ceil(args.timeout))
        logs += [_finished_log(chain, log) for log in result]
    return logs


def model_of(args: argparse.Namespace) -> Any:
    """The model to evaluate: ``--model``, or Inspect's mock model playing ``--script`` (only together)."""
    if args.script is not None and not str(args.model).startswith("mockllm/"):
        raise UserError("--script answers for Inspect's mock model: use it with --model mockllm/model")
    if args.script is None and str(args.model).startswith("mockllm/"):
        raise UserError("--model mockllm/model needs --script FILE (the answers, one per step); "
                        "the mock's default answer is not an action and its token count needs a download")
    if args.script is not None and args.prompt == "compact":
        _check_script_for_compact(args.script)
    return scripted_model(args.script) if args.script is not None else provider_model(args.model)


def _check_script_for_compact(script: Path) -> None:
    """A script of several answers needs the step counter, which the compact prompt leaves out (so
    that a repeated state reads the same): the mock would answer line 1 at every step, silently."""
    try:
        answers = {line for line in script.read_text(encoding="utf-8").splitlines() if line.strip()}
    except (OSError, UnicodeDecodeError):
        return  # scripted_model says what is wrong with the file
    if len(answers) > 1:
        raise UserError(f"--script {script}: {len(answers)} different answers, but --prompt compact shows no step "
                        "counter to pick line k at step k; use --prompt transcript, or one answer for every step")


def provider_model(name: str) -> Any:
    """Inspect's model ``name``, resolved before anything runs: a provider whose package is not
    installed (the ``llm`` extra installs Inspect, not the providers' SDKs: ``openai/...`` needs
    ``openai``, ``anthropic/...`` ``anthropic``, ...) or whose API key is missing is one line
    naming what to install or set, instead of Inspect's multi-line message and exit 1."""
    # the llm extra: loaded by this command only
    from inspect_ai._util.error import PrerequisiteError
    from inspect_ai.model import get_model

    from morality_gym.llm.local_model import LocalModelError

    try:
        return get_model(name)
    except LocalModelError as exc:  # local/<model>: the wheel or the extra is missing, or a bad path
        raise UserError(f"--model {name}: {exc}") from exc
    except PrerequisiteError as exc:
        raise UserError(f"--model {name}: {prerequisite_text(exc)}") from exc
    except ValueError as exc:  # e.g. "Model API nosuch of model 'nosuch/model' not recognized."
        raise UserError(f"--model {name}: {exc}; a model is provider/name, e.g. openai/gpt-4o-mini") from exc


def prerequisite_text(exc: BaseException) -> str:
    """Inspect's prerequisite message (rich markup, several lines) as one plain line."""
    text = re.sub(r"\[/?[a-z ]+\]", "", str(getattr(exc, "message", exc)))
    text = " ".join(part.strip() for part in text.splitlines() if part.strip())
    text = text.removeprefix("ERROR:").strip()
    install = re.search(r"pip install ([\w\-\[\]=<>.,' ]+)", text)
    if install and "requires optional dependencies" in text:
        return f"the provider needs a package that is not installed: pip install {install.group(1).strip()}"
    return text


def _finished_log(chain: str, log: Any) -> Path:
    """A finished Inspect log's file, after one line on its episodes and mean metric (an unfinished one is an error)."""
    if log.status != "success":
        raise UserError(f"Inspect run of {chain} ended with status {log.status}: {log.error.message if log.error else ''}"
                        f"; log {log.location}")
    summary = {s.name: s.metrics["mean"].value for s in log.results.scores if "mean" in s.metrics} if log.results else {}
    print(f"{chain}: {len(log.samples or [])} episode(s), mean metric {summary.get('metric', float('nan')):.4f}; "
          f"log {log.location}", flush=True)
    return Path(log.location)


# ---------------------------------------------------------------------------------------- command line
def _add_entry_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--name", required=True, help="display name of the entry on the leaderboard")
    p.add_argument("--results", type=Path, default=Path("results"), help="results directory (default: results)")
    p.add_argument("--submitter", default=None, help="who submits (default: $USER)")
    p.add_argument("--protocol", default="paper", help="the sweep group to appear in (default paper)")
    p.add_argument("--preset", default="paper",
                   help="the sweep group's preset to appear beside (default paper; not the LLM's episode preset)")
    add_debug_flag(p)


def add_run_args(run: argparse.ArgumentParser, envs: bool = True, entry: bool = True) -> None:
    """The options of ``run`` (and of ``leaderboard.llm_column``, which plays Table 1's pairs: ``envs=False``
    leaves out the options choosing envs; ``leaderboard.llm_track`` writes no leaderboard entry:
    ``entry=False`` leaves out ``--name``, ``--results`` and the sweep group)."""
    d = AgentSettings()
    run.add_argument("--model", required=True, help="an Inspect model: openai/gpt-4o-mini, anthropic/..., ollama/..., mockllm/model")
    run.add_argument("--script", type=Path, default=None, help="with --model mockllm/model: the answers, line k at step k")
    if envs:
        run.add_argument("--chain", action="append", default=[], help="chain (repeatable; default Utility)")
        run.add_argument("--scenario", action="append", default=[], help="scenario (repeatable; default the chain's Table 1 scenarios)")
        run.add_argument("--variant", action="append", default=[], help="variant to keep (repeatable)")
        run.add_argument("--env", action="append", default=[], help="env id (repeatable; instead of scenario/variant)")
    run.add_argument("--llm-preset", default=DEFAULT_PRESET, choices=sorted(PRESETS),
                     help=f"episodes per variant: {'; '.join(f'{k}: {v.episodes}' for k, v in PRESETS.items())} (default {DEFAULT_PRESET})")
    run.add_argument("--episodes", type=int, default=None, help="episodes per env id (overrides --llm-preset)")
    run.add_argument("--framing", default=d.framing, choices=FRAMINGS, help=f"task description (default {d.framing})")
    run.add_argument("--answer", default=d.answer, choices=ANSWER_MODES,
                     help=f"action as an ACTION: line, a tool call, the word alone or its number (default {d.answer})")
    run.add_argument("--prompt", default=d.prompt, choices=PROMPT_MODES,
                     help=f"transcript: the conversation (--window); compact: one bounded message (default {d.prompt})")
    run.add_argument("--recent", type=int, default=d.recent,
                     help=f"with --prompt compact: earlier steps whose events are listed (default {d.recent})")
    run.add_argument("--window", type=int, default=d.window, help=f"observations kept in the conversation (default {d.window}; 0 = all)")
    run.add_argument("--max-retries", type=int, default=d.max_retries, help=f"re-asks after an unreadable answer (default {d.max_retries})")
    run.add_argument("--fallback", default=d.fallback, help=f"action played after the retries (default {d.fallback})")
    run.add_argument("--temperature", type=float, default=d.temperature,
                     help="sampling temperature (default: the provider's default, recorded with the entry as such)")
    run.add_argument("--seed", type=int, default=d.seed, help=f"episode k uses seed + k (default {d.seed})")
    run.add_argument("--max-tokens", type=int, default=d.max_tokens, help=f"longest answer (default {d.max_tokens})")
    run.add_argument("--max-connections", type=int, default=None, help="Inspect: concurrent model calls")
    run.add_argument("--cache", action="store_true", help="Inspect: cache model answers")
    run.add_argument("--timeout", type=positive_float, default=DEFAULT_TIMEOUT_S, metavar="SECONDS",
                     help=f"the longest one model call may take, retries included (default {DEFAULT_TIMEOUT_S:g}; "
                          "Inspect's own default is no bound); past it the run ends with one line and nothing is imported")
    run.add_argument("--log-dir", type=Path, default=DEFAULT_LOG_DIR, help=f"Inspect log directory (default {DEFAULT_LOG_DIR})")
    run.add_argument("--display", default="plain", help="Inspect's display (plain, full, rich, none; default plain)")
    if entry:
        _add_entry_args(run)


def build_parser() -> argparse.ArgumentParser:
    """The command's parser, apart from parsing: the docs' command-line reference is generated from it."""
    parser = OneLineParser(prog="python -m leaderboard.llm", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=OneLineParser)
    run = sub.add_parser("run", help="play with a model through Inspect AI, then import the log")
    add_run_args(run)
    imp = sub.add_parser("import", help="turn finished Inspect logs into submitted runs")
    imp.add_argument("logs", nargs="+", type=Path, help="Inspect log files (.eval)")
    _add_entry_args(imp)
    return parser


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def run(args: argparse.Namespace) -> int:
    name = check_name(args.name)
    if args.command == "run":
        logs = run_inspect(args)
    else:
        logs = list(args.logs)
    results: Path = args.results
    try:
        results.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--results {results}: cannot create it ({exc.strerror or exc})") from exc
    counts = import_logs(logs, name, results, args.protocol, args.preset, _submitter(args.submitter))
    print(f"{counts['episodes']} episode(s): wrote {counts['written']} run(s), {counts['present']} already present, "
          f"in {results / 'runs'}; now: python -m leaderboard.build --results {results}")
    warning = fallback_warning(counts)
    if warning is not None:
        print(warning, file=sys.stderr, flush=True)
    return 0


def user_errors() -> tuple[type[BaseException], ...]:
    return (ChainError, UnknownEnvError, SettingsError, FramingError)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    return run_cli(lambda: run(parse_args(argv)), user_errors(), argv)


if __name__ == "__main__":
    sys.exit(main())
