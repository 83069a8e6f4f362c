"""Command-line selections that need no hand-written config file: user scenarios, chain files, spellings.

Hydra selects config-group options by file name, so on its own ``scenario=MyScenario`` needs a
``scenario/my_scenario.yaml`` with a ``# @package`` line, and ``chain=path/to/mine.yaml`` is not an
option at all. Before Hydra parses the command line, :func:`normalise_argv` rewrites and registers
what a user means:

* ``scenario=SwitchStandard`` (the scenario's name) and ``scenario=switch_standard`` (its file name)
  are the same selection; any spelling that differs only in case and underscores is accepted;
* a scenario loaded from ``MORALITY_GYM_SCENARIOS`` is registered in Hydra's ConfigStore as an
  option of the ``scenario`` group (no paper chains: choose ``chain=...``);
* ``chain=`` takes an option, a chain's name, file name or abbreviation (``DualProcess``, ``DP``),
  or the path of a chain YAML file, which is registered as an option named after the file.

The environment variable is inherited by the workers, which load the same scenario files.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

from hydra.core.config_store import ConfigStore

from morality_gym.envs.naming import snake, squash
from morality_gym.envs.registry import scenarios
from morality_gym.norms.chain import ChainError, chain_file_stem, get_chain
from runners.compose.search_path import find_config, group_options, split_list


def options(group: str, argv: list[str]) -> list[str]:
    """The options of a group: files on the search path plus ConfigStore entries."""
    stored = ConfigStore.instance().repo.get(group, {})
    return sorted({*group_options(group, argv), *(name.removesuffix(".yaml") for name in stored)})


def _store(group: str, name: str, node: dict, package: str) -> None:
    ConfigStore.instance().store(group=group, name=name, node=node, package=package, provider="morality_gym")


def _scenario_option(item: str, argv: list[str], known_options: list[str]) -> str:
    if item in known_options:
        return item
    for name in scenarios():
        if squash(name) == squash(item):
            option = snake(name)
            if option not in known_options and find_config("scenario", option, argv) is None:
                _store("scenario", option, {"chains": []}, f"scenario.{name}")  # a user scenario: no paper chains
                known_options.append(option)
            return option
    return item  # unknown: the precheck names the closest options


def _chain_option(item: str, argv: list[str], known_options: list[str]) -> str:
    if item in known_options:
        return item
    path = Path(item).expanduser()
    is_file = item.endswith((".yaml", ".yml")) or path.is_file()
    try:
        chain = get_chain(str(path) if is_file else item)
    except ChainError as exc:
        if is_file:  # the user's own file: what is wrong in it (a norm, a field), not "unknown chain"
            raise ChainError(f"chain={item}: {str(exc).removeprefix(f'{path}: ')}") from exc
        return item  # an unknown name: the precheck names the closest options
    if not is_file:
        return chain_file_stem(chain)  # a built-in chain by name or abbreviation
    path = path.resolve()
    option = re.sub(r"\W", "_", path.stem)
    if option in known_options or find_config("chain", option, argv) is not None:
        option = f"{option}_{hashlib.sha256(str(path).encode()).hexdigest()[:6]}"
    _store("chain", option, {"ref": str(path)}, f"chain.{option}")
    known_options.append(option)
    return option


def normalise_argv(argv: list[str]) -> list[str]:
    """``argv`` with scenario and chain selections rewritten to options Hydra can compose."""
    out = []
    for arg in argv:
        key, sep, value = arg.partition("=")
        group = key.lstrip("+")
        if not sep or arg.startswith("-") or group not in ("scenario", "chain") or value.strip() in ("null", "[]", ""):
            out.append(arg)
            continue
        known = options(group, argv)
        pick = _scenario_option if group == "scenario" else _chain_option
        items = [pick(item, argv, known) for item in split_list(value)]
        listed = value.strip().startswith("[")
        out.append(f"{key}=" + (f"[{','.join(items)}]" if listed or len(items) > 1 else items[0]))
    return out
