"""The sweep's command line: its flags, the overrides made ready to compose, and what ``--help``,
``--cfg`` and ``--info`` print.

Steps 1 and 2 of :mod:`runners.sweep`'s path (that module's docstring lists the flags and why they
are this command's own rather than a ``@hydra.main`` application's): :func:`parse_command_line`
reads ``argv`` once; :func:`prepare_overrides` adds the installed plugins' config packages to the
search path, rewrites user scenarios and chain files into options Hydra can compose
(:mod:`runners.compose.options`) and checks group options and hyper-parameter names, naming the closest
valid ones (:func:`precheck`); :func:`load_sweeps` composes ``conf/`` with Hydra's compose API
(:func:`compose_sweep`) and validates each sweep. Kept apart from planning and dispatch so that
each module reads as one concern: what the user typed, and what the sweep then does.
"""

from __future__ import annotations

import argparse
import itertools
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import yaml
from hydra import compose, initialize_config_dir
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.utils import configure_log
from omegaconf import DictConfig, OmegaConf

from morality_gym.baselines.hparams import accepted_hparams
from morality_gym.baselines.specs import CONF_DIR, SpecError
from morality_gym.baselines.targets import add_python_roots
from morality_gym.clitools import DEBUG_ENV, did_you_mean
from morality_gym.envs.naming import squash
from morality_gym.envs.registry import skipped_scenario_files
from runners.compose.options import normalise_argv
from runners.compose.options import options as group_options
from runners.compose.schema import composition_error
from runners.compose.search_path import find_config, plugin_sources, source_dir, sources_from_argv, split_list
from runners.compose.sweep_config import (  # also stores the schemas (runners.compose.schema)
    ConfigError,
    SweepConfig,
    validate,
)

#: How the manifest names the program (``sys.argv[0]`` of ``python -m runners.sweep``, also when
#: :mod:`runners.table1` runs the sweep in its own process): the sweep's file, not this one, which
#: sits one folder below it (``runners/compose/``).
PROGRAM = os.path.join(os.path.dirname(os.path.dirname(__file__)), "sweep.py")

_GROUPS = ("scenario", "chain", "algo", "protocol", "preset", "launcher", "experiment")

# ---------------------------------------------------------------------------------------- command line
class CommandLineError(ValueError):
    """A flag this command does not take, or a flag without its value (one line, exit 2)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override] - argparse's prints the usage and exits
        raise CommandLineError(f"{message}; see python -m runners.sweep --help")


#: Flags of a ``@hydra.main`` application that mean nothing to a composed sweep (module docstring),
#: by the name of their value (None: a switch): known to the parser, so that ``-cp DIR`` is not read
#: as ``-c p``, and refused with the reason.
HYDRA_ONLY_FLAGS: dict[tuple[str, ...], str | None] = {
    ("--hydra-help",): None, ("-sc", "--shell-completion"): "ACTION", ("-cp", "--config-path"): "DIR",
    ("--experimental-rerun",): "FILE",
}


def _hydra_only_dest(flags: tuple[str, ...]) -> str:
    return "hydra_only_" + flags[-1].lstrip("-").replace("-", "_")


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="python -m runners.sweep", add_help=False)
    parser.add_argument("overrides", nargs="*", help="key=value: a config group option or any setting")
    parser.add_argument("-h", "--help", action="store_true", help="show this help, the groups and the composed configuration")
    parser.add_argument("--version", action="store_true", help="show the version (and Hydra's)")
    parser.add_argument("--debug", action="store_true", help=f"show tracebacks of user errors too (or set {DEBUG_ENV}=1)")
    parser.add_argument("-c", "--cfg", choices=["job", "hydra", "all"], help="print the composed configuration; run nothing")
    parser.add_argument("--resolve", action="store_true", help="with --cfg: resolve interpolations")
    parser.add_argument("-p", "--package", help="with --cfg: print this node only")
    parser.add_argument("-i", "--info", nargs="?", const="searchpath", choices=["searchpath", "config"],
                        help="print the config search path or the composed configuration")
    parser.add_argument("-m", "--multirun", action="store_true", help="one sweep per combination of a,b,... values")
    parser.add_argument("-r", "--run", action="store_true", help="one sweep (the default)")
    parser.add_argument("-cd", "--config-dir", help="a directory of your own config files (algo/, chain/, ...)")
    parser.add_argument("-cn", "--config-name", default="config", help="the primary config (default: config)")
    for flags, value in HYDRA_ONLY_FLAGS.items():
        if value is None:
            parser.add_argument(*flags, action="store_true", dest=_hydra_only_dest(flags), help=argparse.SUPPRESS)
        else:
            parser.add_argument(*flags, metavar=value, dest=_hydra_only_dest(flags), help=argparse.SUPPRESS)
    return parser


@dataclass(frozen=True)
class CommandLine:
    """The command line, read once: the overrides as typed and what the flags ask for."""

    overrides: tuple[str, ...]
    argv: tuple[str, ...] = ()  # as typed, for the manifest's record of the command
    config_dir: str | None = None
    config_name: str = "config"
    show: str | None = None  # --cfg job|hydra|all
    resolve: bool = False
    package: str | None = None
    info: str | None = None
    help: bool = False
    multirun: bool = False
    version: bool = False
    debug: bool = False

    @property
    def search_args(self) -> list[str]:
        """``--config-dir DIR`` as the helpers that read search paths from a command line expect it."""
        return ["--config-dir", self.config_dir] if self.config_dir else []



def parse_command_line(argv: Sequence[str]) -> CommandLine:
    """The flags and overrides of ``argv`` (flags may come before, between or after overrides)."""
    args = _parser().parse_intermixed_args(list(argv))
    for flags in HYDRA_ONLY_FLAGS:
        if getattr(args, _hydra_only_dest(flags)):
            raise CommandLineError(f"{flags[-1]} is a flag of Hydra applications that this command does not take (it "
                                   "composes its configuration with Hydra's compose API); see python -m runners.sweep --help")
    return CommandLine(overrides=tuple(args.overrides), argv=tuple(argv), config_dir=args.config_dir, config_name=args.config_name,
                       show=args.cfg, resolve=args.resolve, package=args.package, info=args.info, help=args.help,
                       multirun=args.multirun, version=args.version, debug=args.debug)


# ---------------------------------------------------------------------------------------- before composition
def _hparam_override(key: str, value: str, argv: list[str]) -> str | None:
    """An ``[+]algo.<option>.hparams.<name>=...`` override whose name the algorithm does not take.

    Hydra would answer a name without ``+`` with "Key ... is not in struct" and advise adding
    ``+``; the real problem is usually a typo, so it is named here, with the closest names. Works
    for any learner: the names are its class's constructor parameters.
    """
    parts = key.lstrip("+~").split(".")
    if len(parts) != 4 or parts[0] != "algo" or parts[2] != "hparams" or key.startswith("~"):
        return None
    path = find_config("algo", parts[1], argv)
    if path is None:
        return None
    target = (yaml.safe_load(path.read_text()) or {}).get("_target_")
    try:
        accepted = accepted_hparams(str(target))
    except (SpecError, ValueError):
        return None  # reported with its file by the validation
    if parts[3] in accepted:
        return None
    hint = did_you_mean(parts[3], accepted)
    return f"{key}={value}: {parts[3]!r} is not a hyper-parameter of algo {parts[1]}{hint}; valid: {', '.join(sorted(accepted))}"


def _group_selection(group: str, value: str, argv: list[str]) -> str | None:
    """A ``group=option`` or ``group=[a,b]`` selection naming an option the group does not have."""
    value = value.strip()
    options = [o.strip() for o in value.strip("[]").split(",") if o.strip()] if value not in ("null", "[]") else []
    valid = group_options(group, argv)
    for option in options:
        if option not in valid:
            skipped = _skipped_scenario(option) if group == "scenario" else None
            if skipped:
                return f"scenario={option}: {skipped}"
            hint = did_you_mean(option, valid)
            return f"{group}={value}: unknown {group} {option!r}{hint}; valid: {', '.join(valid)}"
    return None


def precheck(argv: list[str]) -> str | None:
    """Check config-group selections and hyper-parameter names on the command line, before Hydra
    (whose messages for these do not say what the valid options are). Returns an error or None.

    Options are looked up on the whole search path: ``conf/``, ``--config-dir DIR`` (either form),
    ``hydra.searchpath=[...]`` and the installed plugins.
    """
    for source in sources_from_argv(argv):
        directory = source_dir(source)
        if directory is None or not directory.is_dir():
            return (f"config search path entry {source!r} is not a directory; give an existing directory "
                    "(--config-dir DIR, hydra.searchpath=[file:///abs/dir] or [pkg://package])")
    for arg in argv:
        if "=" not in arg or arg.startswith("-"):
            continue
        key, value = arg.split("=", 1)
        problem = _hparam_override(key, value, argv)
        if not problem and key.lstrip("+~") in _GROUPS:
            problem = _group_selection(key.lstrip("+~"), value, argv)
        if problem:
            return problem
    return None


def _skipped_scenario(option: str) -> str | None:
    """Why a scenario of this name is missing, when a ``MORALITY_GYM_SCENARIOS`` file declaring it
    was skipped as invalid (its file, field and fix), else None."""
    for item in skipped_scenario_files():
        if squash(item.name or item.path.stem) == squash(option):
            return f"the file defining it, {item.path}, was skipped as invalid: {item.error.removeprefix(f'{item.path}: ')}"
    return None


def with_plugins(argv: list[str]) -> list[str]:
    """``argv`` with the installed plugins' config packages added to ``hydra.searchpath`` (merged
    with the user's own entries, which come first), and every user config directory made
    importable, here and in the workers (:func:`morality_gym.baselines.targets.add_python_roots`):
    a ``_target_`` module kept next to ``algo/`` in a config directory needs no install."""
    add_python_roots([d for s in sources_from_argv(argv) if not s.startswith("pkg://") and (d := source_dir(s)) is not None])
    plugins = plugin_sources()
    if not plugins:
        return argv
    out, merged = [], False
    for arg in argv:
        if arg.lstrip("+").startswith("hydra.searchpath="):
            key, value = arg.split("=", 1)
            items = [*split_list(value), *(p for p in plugins if p not in split_list(value))]
            out.append(f"{key}=[{','.join(items)}]")
            merged = True
        else:
            out.append(arg)
    if not merged:
        out.append(f"hydra.searchpath=[{','.join(plugins)}]")
    return out


def _with_config_dir(overrides: list[str], config_dir: str | None) -> list[str]:
    """``--config-dir DIR`` as an entry of ``hydra.searchpath`` (after the user's own), which is what
    Hydra itself made of the flag: one more directory on the search path."""
    if not config_dir:
        return overrides
    extra = f"file://{source_dir(config_dir)}"
    out, merged = [], False
    for item in overrides:
        if item.lstrip("+").startswith("hydra.searchpath="):
            key, value = item.split("=", 1)
            item, merged = f"{key}=[{','.join([*split_list(value), extra])}]", True
        out.append(item)
    return out if merged else [*out, f"hydra.searchpath=[{extra}]"]


def prepare_overrides(line: CommandLine) -> tuple[list[str], str]:
    """The overrides to compose and the command line the manifest records.

    The plugins' search path, the user's spellings of scenarios and chains (:mod:`runners.compose.options`)
    and :func:`precheck` see ``--config-dir`` as typed; composition sees it as a search-path entry.
    Raises :class:`ConfigError` (or :class:`~morality_gym.norms.chain.ChainError` for a user's chain
    file that cannot be read) with one line.
    """
    tokens = normalise_argv(with_plugins([*line.search_args, *line.overrides]))
    problem = precheck(tokens)
    if problem:
        raise ConfigError(problem)
    rewritten = tokens[len(line.search_args):]
    return _with_config_dir(rewritten, line.config_dir), _recorded_command(line, rewritten)


def _recorded_command(line: CommandLine, rewritten: list[str]) -> str:
    """The command line as the manifest records it: as typed, without ``--debug``, each override
    as it is composed (a chain file as its option) and the plugins' search path added at the end
    when the line gave none (:func:`with_plugins`)."""
    out, i = [PROGRAM], 0
    for arg in line.argv:
        if i < len(line.overrides) and arg == line.overrides[i]:
            out.append(rewritten[i])
            i += 1
        elif arg != "--debug":
            out.append(arg)
    return " ".join([*out, *rewritten[len(line.overrides):]])


# ---------------------------------------------------------------------------------------- composition
def compose_sweep(overrides: Sequence[str], config_name: str = "config") -> DictConfig:
    """``conf/`` composed with ``overrides`` over the typed schemas (:mod:`runners.compose.schema`),
    with its ``hydra`` node (the search path, logging). A key or value the schemas refuse is a
    :class:`ConfigError` of one line naming the key, its file or override and the closest valid key."""
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            return compose(config_name, overrides=list(overrides), return_hydra_config=True)
    except Exception as exc:
        raise ConfigError(composition_error(exc, lambda group, option: find_config(group, option, list(overrides)))) from exc


def compose_check(argv: list[str]) -> str | None:
    """The one-line composition error of a command line's overrides (``--config-dir`` in either
    form), or None: :func:`compose_sweep`'s check on its own, for tests and tools."""
    try:
        line = parse_command_line(argv)
        compose_sweep(_with_config_dir(list(line.overrides), line.config_dir), line.config_name)
    except (ConfigError, CommandLineError) as exc:
        return str(exc)
    return None


def expand(overrides: list[str], multirun: bool) -> list[list[str]]:
    """The overrides of each sweep: one, or with ``--multirun`` one per combination of the values
    of sweep overrides (``algo=random,ppo``, ``seed=range(1,3)``), in the order Hydra's basic
    sweeper ran them. Without ``--multirun`` such a value is refused at composition."""
    if not multirun:
        return [overrides]
    try:
        parsed = OverridesParser.create().parse_overrides(overrides)
    except Exception as exc:
        raise ConfigError(composition_error(exc)) from exc
    choices = [[f"{o.get_key_element()}={v}" for v in o.sweep_string_iterator()] if o.is_sweep_override() else [o.input_line]
               for o in parsed]
    return [list(combination) for combination in itertools.product(*choices)]


def load_sweeps(overrides: list[str], line: CommandLine) -> list[SweepConfig]:
    """Each sweep of the command line composed and validated, before the first one runs.

    Logging is configured from the first composition as ``@hydra.main`` configured it, Hydra's
    own first, then the job's (``conf/config.yaml``: Hydra's disabled, the job's to stdout), before
    validation imports the learners."""
    sweeps = []
    for i, each in enumerate(expand(overrides, line.multirun)):
        cfg = compose_sweep(each, line.config_name)
        if i == 0:
            configure_log(cfg.hydra.hydra_logging, cfg.hydra.verbose)
            configure_log(cfg.hydra.job_logging, cfg.hydra.verbose)
        sweeps.append(validate(cfg))
    return sweeps


# ---------------------------------------------------------------------------------------- what Hydra's flags printed
def _search_path_table(cfg: DictConfig) -> str:
    rows = [("Provider", "Search path"), *((s.provider, f"{s.schema}://{s.path}") for s in cfg.hydra.runtime.config_sources)]
    widths = [max(len(r[i]) for r in rows) for i in (0, 1)]
    lines = [f"| {a.ljust(widths[0])} | {b.ljust(widths[1])} |" for a, b in rows]
    rule = "-" * len(lines[0])
    return "\n".join(["", "Config search path", "*" * len("Config search path"), lines[0], rule, *lines[1:], rule])


def _config_yaml(cfg: DictConfig, part: str, resolve: bool = False, package: str | None = None) -> str:
    """The composed configuration as ``--cfg`` prints it: the job's part, Hydra's, or all."""
    keys = {"job": [k for k in cfg if k != "hydra"], "hydra": ["hydra"], "all": list(cfg)}[part]
    node: Any = OmegaConf.masked_copy(cfg, keys)
    header = ""
    if package:
        node, header = OmegaConf.select(node, package), f"# @package {package}\n"
    text = OmegaConf.to_yaml(node, resolve=resolve) if OmegaConf.is_config(node) else f"{node}\n"
    return header + text


def _help(cfg: DictConfig, overrides: list[str]) -> str:
    groups = "\n".join(f"{g}: {', '.join(group_options(g, overrides))}" for g in _GROUPS)
    return (f"{_parser().format_help()}\n== Configuration groups ==\nCompose your configuration from those groups "
            f"(group=option)\n\n{groups}\n\n== Config ==\nOverride anything in the config (foo.bar=value)\n\n"
            f"{_config_yaml(cfg, 'job')}")


def show(line: CommandLine, overrides: list[str]) -> int:
    """``--help``, ``--cfg`` and ``--info``: print what was asked about the composed configuration."""
    cfg = compose_sweep(overrides, line.config_name)
    if line.help:
        print(_help(cfg, overrides))
    elif line.show:
        print(_config_yaml(cfg, line.show, line.resolve, line.package), end="")
    elif line.info == "searchpath":
        print(_search_path_table(cfg))
    else:
        print(_config_yaml(cfg, "job"))
    return 0
