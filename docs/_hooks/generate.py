"""MkDocs hook: the pages that are generated from the code, made while the site builds.

Nothing here is committed output: every page below is made from its source of truth each time
``mkdocs build`` (``make docs``) or ``mkdocs serve`` runs, so it cannot go stale.

* ``envs/`` - the environment catalogue: one page per scenario from its env class's docstring
  (itself generated from the scenario file), a picture of every variant, the relevant norms, the
  exact Random value and the oracle's best and worst metric under each chain the paper ran on the
  scenario, and a GIF of the oracle's best episode. Pictures and GIFs are drawn by
  :mod:`morality_gym.render` into the build, never into ``docs/``.
* ``reference/cli.md`` - every command line, from its argparse parser object (every module with a
  ``build_parser()`` that runs as a program).
* ``reference/api.md`` - every name ``morality_gym`` exports (``__all__``), from its docstring.
* ``reference/configuration.md`` - every configuration group and field with its default, from the
  typed schemas of :mod:`runners.compose.schema` and the files of ``conf/``.
* ``reference/results-schema.md`` - every column of the results contract, from
  :mod:`morality_gym.results.schema` (its fields and the comments beside them).
* ``reference/modules.md`` - every module, folder by folder, with its size and the first line of
  its docstring.

The functions return ``{path: str | bytes}`` so that tests can call them without MkDocs.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import importlib
import io
import re
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:  # mkdocs may run from elsewhere; the checkout's packages come first
    sys.path.insert(0, str(ROOT))

CELL = 32  # pixels per grid cell of the pictures (the GIFs use the same)
GIF_STEPS = 40  # the oracle's best actions, then STAY until the episode ends or this many steps


# ------------------------------------------------------------------------------------------------
# The environment catalogue
# ------------------------------------------------------------------------------------------------


def _paper_chains() -> dict[str, list[str]]:
    """Scenario name -> the chains the paper's Table 1 ran on it (in the table's order)."""
    from morality_gym.paper import table1

    out: dict[str, list[str]] = {}
    for row in table1():
        out.setdefault(row.scenario, []).append(row.chain)
    return out


def _png(frame: Any) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(frame).save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def _initial_frame(env_id: str) -> Any:
    from morality_gym.envs.trolley import TrolleyEnv
    from morality_gym.render.rgb import render_rgb

    env = TrolleyEnv(env_id, render_mode="rgb_array")
    try:
        env.reset(seed=0)
        return render_rgb(env.world, env.state, CELL)
    finally:
        env.close()


def _replay_policy(actions: list[int]) -> Callable[[Any], int]:
    """A policy that plays ``actions`` in order, then stays."""
    queue: Iterator[int] = iter(actions)
    return lambda _obs: next(queue, 4)


def _gif(env_id: str, actions: list[int]) -> bytes:
    from morality_gym.evaluation.gif import record_episode

    with tempfile.TemporaryDirectory(prefix="docs-gif-") as tmp:
        path = Path(tmp) / "episode.gif"
        record_episode(env_id, _replay_policy(actions), path, max_steps=GIF_STEPS, cell_size=CELL)
        return path.read_bytes()


def _actions(actions: list[int]) -> str:
    from morality_gym.world.rules import ACTION_NAMES

    return " ".join(ACTION_NAMES[a] for a in actions) or "(none)"


def _variant_label(spec: Any) -> str:
    return ", ".join(f"{t} {a}" for t, a in zip(spec.types, spec.amounts, strict=True))


def scenario_page(name: str, chains: list[str]) -> dict[str, str | bytes]:
    """The catalogue page of one scenario and its pictures: ``{path under envs/: content}``."""
    from morality_gym import exact_evaluate, oracle, scenarios
    from morality_gym.envs.registration import env_class

    scenario = scenarios()[name]
    files: dict[str, str | bytes] = {}
    doc = env_class(name).__doc__ or ""
    summary, _, body = doc.partition("\n")
    first = scenario.env_ids[0]
    lines = [f"# {name}", "", summary.partition(": ")[2] or summary, ""]
    if chains:
        best = oracle(first, chains[0])
        files[f"img/{name}.gif"] = _gif(first, best.best.actions)
        lines += [
            '<figure markdown="span">',
            f"  ![The oracle's best episode of {first} under {chains[0]}](img/{name}.gif){{ loading=lazy }}",
            (f"  <figcaption>The best episode of <code>{first}</code> under {chains[0]} "
            f"(metric {best.best.metric:.3f}): {_actions(best.best.actions)}, then STAY.</figcaption>"),
            "</figure>",
            "",
        ]
    lines += [body.strip(), "", "## Variants", ""]
    if chains:
        lines += [
            ("Each variant's starting picture, its relevant norms (the only ones that carry weight in "
            "the metric) and, under each chain the paper ran on this scenario (Table 1, beta = 0.1, "
            "`max_steps` = 200): the exact metric of the uniform Random policy "
            "(`exact_evaluate(\"random\", env_id, chain)`) and the best and worst metric any policy can "
            "reach (`oracle(env_id, chain)`), with the best action sequence."),
            "",
        ]
    else:
        lines += ["The paper ran no chain on this scenario; each variant's picture and relevant norms:", ""]
    for variant, spec in scenario.variants.items():
        env_id = scenario.env_id(variant)
        files[f"img/{env_id}.png"] = _png(_initial_frame(env_id))
        lines += [
            f"### {variant}",
            "",
            f"`MoralityGym/{env_id}`: {_variant_label(spec)} (a `*` in the table above marks the pushable group).",
            "",
            f"![{env_id} at the start]({'img/' + env_id + '.png'}){{ loading=lazy }}",
            "",
            "Relevant norms: " + ", ".join(f"`{n}`" for n in spec.relevant) + ".",
            "",
        ]
        if chains:
            lines += ["| chain | Random (exact) | oracle best | oracle worst | best actions |", "|---|---|---|---|---|"]
            for chain in chains:
                random = exact_evaluate("random", env_id, chain)
                result = oracle(env_id, chain)
                lines.append(f"| {chain} | {random.metric:.3f} | {result.best.metric:.3f} | {result.worst.metric:.3f} "
                             f"| {_actions(result.best.actions)} |")
            lines.append("")
    files[f"{name}.md"] = "\n".join(lines) + "\n"
    return files


def catalogue() -> dict[str, str | bytes]:
    """Every scenario's page and pictures plus the catalogue's index: ``{path under envs/: content}``."""
    from morality_gym import scenarios

    chains = _paper_chains()
    files: dict[str, str | bytes] = {}
    index = [
        "# Environment catalogue",
        "",
        (f"{len(scenarios())} scenarios, {sum(len(s.variants) for s in scenarios().values())} variants "
        "(Gymnasium ids `MoralityGym/{Scenario}-{Variant}-v1`). Each page is generated from the "
        "scenario's file (`morality_gym/data/scenarios/`) and its env class's docstring when the site "
        "is built; `python -m morality_gym docs --output DIR` writes the docstrings alone as Markdown."),
        "",
        '<div class="catalogue-index" markdown>',  # docs/stylesheets/tables.css gives "what happens" room
        "",
        "| scenario | | variants | Table 1 chains | what happens |",
        "|---|---|---|---|---|",
    ]
    for name, scenario in scenarios().items():
        files.update(scenario_page(name, chains.get(name, [])))
        first = scenario.env_id(next(iter(scenario.variants)))
        index.append(f"| [{name}]({name}.md) | ![{name}](img/{first}.png){{ width=160 loading=lazy }} "
                     f"| {len(scenario.variants)} | {', '.join(chains.get(name, [])) or '-'} | {scenario.summary} |")
    index += ["", "</div>"]
    files["index.md"] = "\n".join(index) + "\n"
    return files


# ------------------------------------------------------------------------------------------------
# Command lines, from their parser objects
# ------------------------------------------------------------------------------------------------

#: (module, what it does): each module's parser is captured as its own code builds it.
COMMANDS: list[tuple[str, str]] = [
    ("morality_gym", "environments: play, evaluate, oracle, list, docs, generate"),
    ("leaderboard.build", "Table 1, figures and the static leaderboard from results directories and releases"),
    ("leaderboard.submit", "score a policy of your own into a results directory"),
    ("leaderboard.release", "freeze results into a checksummed release; verify one"),
    ("leaderboard.compare", "compare two results directories cell by cell"),
    ("leaderboard.reproduction", "Table 1 against the paper, cell by cell, with the evidence"),
    ("leaderboard.engines", "compare the single and fleet engines' Table 1s"),
    ("leaderboard.llm", "language-model agents through Inspect AI"),
    ("leaderboard.llm_column", "a language model's whole Table 1 column, pair by pair, resumable"),
    ("leaderboard.llm_track", "a language model on the generalisation track's unseen set (or a seeded sample)"),
    ("leaderboard.screenshot", "PNG screenshots of a built leaderboard"),
    ("runners.migrate", "move an older results directory to the current run ids"),
    ("runners.track", "train and score the generalisation track's held-out splits"),
    ("runners.cache", "what the simulator-table cache holds; prune the entries unused for N days"),
    ("leaderboard.track", "the generalisation track's table from a results directory or a track release"),
    ("leaderboard.track_release", "freeze the generalisation track's results into a checksummed release; verify one"),
    ("benchmarks.run", "speed benchmarks (BENCHMARKS.md)"),
    ("benchmarks.project_table1", "price a whole Table 1 from measured runs"),
]


#: The packages whose modules may be commands (``python -m package.module``).
COMMAND_PACKAGES = ("morality_gym", "runners", "leaderboard", "benchmarks")


def command_modules() -> list[str]:
    """Every ``python -m`` command with an argparse parser, found in the code: a module that defines
    ``build_parser()`` and runs as a program (``if __name__ == "__main__"``, or a package's
    ``__main__.py``). The page lists these; :data:`COMMANDS` gives each its one-line description,
    and a command missing there fails tests/test_docs_site.py (the page once lacked two of them)."""
    found = []
    for package in COMMAND_PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            if "def build_parser(" not in text:
                continue
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            if path.name == "__main__.py":
                found.append(module.removesuffix(".__main__"))
            elif 'if __name__ == "__main__"' in text:
                found.append(module)
    return found


def capture_parser(module: str) -> argparse.ArgumentParser:
    """The parser ``python -m <module>`` uses: every listed command exposes ``build_parser()`` (the
    parser apart from parsing), so the page shows exactly what the command accepts and runs nothing."""
    mod = importlib.import_module(module + (".__main__" if module == "morality_gym" else ""))
    build = getattr(mod, "build_parser", None)
    if build is None:
        raise RuntimeError(f"{module} has no build_parser(): a command listed in COMMANDS must expose its parser")
    return build()


def _rst(text: str) -> str:
    """Sphinx markup of the docstrings as Markdown: ``x`` and :role:`~a.b.c` become `x` and `c`."""
    text = re.sub(r":\w+:`~?([\w.]+)`", lambda m: f"`{m.group(1).rsplit('.', 1)[-1]}`", text)
    return re.sub(r"``(.+?)``", r"`\1`", text)


def _cell(text: str) -> str:
    return _rst(" ".join(text.split())).replace("|", "\\|")


def _parser_markdown(parser: argparse.ArgumentParser, level: int) -> list[str]:
    import os

    columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"  # argparse wraps the usage at the terminal's width: the page's, here
    try:
        formatter = parser._get_formatter()
        usage = parser.format_usage().removeprefix("usage: ").rstrip()
    finally:
        if columns is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = columns
    lines = ["```text", usage, "```", ""]
    if parser.description:
        lines += [_cell(parser.description), ""]
    rows = []
    subparsers: list[tuple[str, argparse.ArgumentParser]] = []
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if isinstance(action, argparse._SubParsersAction):
            subparsers += list(action.choices.items())
            continue
        if action.help == argparse.SUPPRESS:
            continue
        name = ", ".join(f"`{s}`" for s in action.option_strings) or f"`{action.dest}`"
        if action.option_strings and action.nargs != 0:
            name += f" `{action.metavar or action.dest.upper()}`"
        default = action.default
        if isinstance(action, argparse._VersionAction | argparse._StoreTrueAction | argparse._StoreFalseAction):
            shown = "" if isinstance(action, argparse._VersionAction) else f"`{default}`"
        else:
            shown = "" if default in (None, argparse.SUPPRESS) else f"`{default}`"
        if action.choices and not isinstance(action.choices, dict):
            shown += (" " if shown else "") + "(one of " + ", ".join(f"`{c}`" for c in action.choices) + ")"
        help_text = formatter._expand_help(action) if action.help else ""
        rows.append(f"| {name} | {'yes' if action.required else ''} | {_cell(shown)} | {_cell(help_text)} |")
    if rows:
        lines += ["| argument | required | default | what it does |", "|---|---|---|---|", *rows, ""]
    for sub_name, sub in subparsers:
        lines += [f"{'#' * (level + 1)} `{sub_name}`", "", *_parser_markdown(sub, level + 1)]
    return lines


def cli_page() -> str:
    lines = [
        "# Command lines",
        "",
        ("Generated from each command's argparse parser when the site is built, so every flag and "
        "default here is the one the code has. Every command answers `--help`; user errors print one "
        "line and exit 2 (`--debug`, or `MORALITY_GYM_DEBUG=1`, shows the traceback). The sweeps "
        "(`python -m runners.sweep`, `python -m runners.table1`) are Hydra applications: their "
        "command line is the configuration, see [Configuration](configuration.md)."),
        "",
    ]
    described = dict(COMMANDS)
    for module in [m for m, _ in COMMANDS] + [m for m in command_modules() if m not in described]:
        parser = capture_parser(module)
        what = described.get(module) or (parser.description or module).rstrip(".")
        lines += [f"## `python -m {module}`", "", f"{what[0].upper()}{what[1:]}.", "", *_parser_markdown(parser, 2)]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------
# The Python API, from morality_gym.__all__
# ------------------------------------------------------------------------------------------------

#: The API page's sections, by the subpackage a name is defined in (the first that matches).
API_SECTIONS: list[tuple[str, str]] = [
    ("Environments", "morality_gym.api"),
    ("Environments", "morality_gym.envs"),
    ("Norms, chains, the metric and the cost", "morality_gym.norms"),
    ("Evaluation", "morality_gym.evaluation"),
    ("Generated dilemmas and held-out splits", "morality_gym.generator"),
    ("The world's vocabulary", "morality_gym.world"),
]
#: The reading order within a section (the rest follow, alphabetically): how to make an env before its errors.
API_FIRST = ["make", "list_envs", "env_ids", "scenarios", "parse_env_id", "add_scenario_dir", "TrolleyEnv",
             "BatchedTrolleyEnv", "TrolleyVectorEnv", "TrolleyVecEnv", "TorchTrolleyVectorEnv", "get_chain",
             "builtin_chains", "MoralityChain", "bind_chain", "BoundChain", "VectorCost", "RewardCostSpec",
             "MoralityWrapper", "VecMoralityWrapper", "TorchCostWrapper", "evaluate", "exact_evaluate", "oracle"]
#: Which members a class's entry shows (default: none, the class docstring says how to use it).
API_MEMBERS: dict[str, list[str]] = {
    "TrolleyEnv": ["reset", "step", "render"],
    "TorchTrolleyVectorEnv": ["reset", "step", "utility"],
    "TrolleyVectorEnv": ["reset", "step"],
    "BoundChain": ["morality_functions", "metric", "weight_sum"],
    "VectorCost": ["reset", "from_norm_events"],
}
#: Documented beside the exported names: what the exported functions return.
API_EXTRAS: list[tuple[str, str]] = [
    ("morality_gym.evaluation.result", "EvaluationResult"),
    ("morality_gym.evaluation.oracle", "OracleResult"),
]
#: Subpackages without an ``__init__.py``: mkdocstrings loads them as top-level packages (mkdocs.yml paths).
_NAMESPACE = ("envs", "norms", "evaluation")


def api_home(name: str) -> str:
    """The module that defines ``morality_gym.<name>`` (a lazy name: the module it is loaded from)."""
    import morality_gym

    obj = getattr(morality_gym, name)  # a lazy name is loaded here
    module = getattr(obj, "__module__", None)
    if isinstance(module, str) and module.startswith("morality_gym"):
        return module
    for path in sorted((ROOT / "morality_gym").rglob("*.py")):  # a constant: the module that assigns it
        if re.search(rf"^{re.escape(name)}\b.*=", path.read_text(encoding="utf-8"), re.MULTILINE):
            return ".".join(path.relative_to(ROOT).with_suffix("").parts)
    raise RuntimeError(f"cannot tell where morality_gym.{name} is defined")


def _identifier(module: str, name: str) -> str:
    parts = module.split(".")
    if len(parts) > 1 and parts[1] in _NAMESPACE:
        parts = parts[1:]
    return ".".join([*parts, name])


def _api_entry(module: str, name: str, heading: str) -> list[str]:
    import inspect

    obj = getattr(importlib.import_module(module), name)
    members = API_MEMBERS.get(name, [] if inspect.isclass(obj) else None)
    lines = [f"::: {_identifier(module, name)}", "    options:", f"      heading: {heading}"]
    if members is not None:
        lines.append(f"      members: [{', '.join(members)}]" if members else "      members: false")
    return [*lines, ""]


def api_page() -> str:
    """``reference/api.md``: every name of ``morality_gym.__all__``, by section, generated from the
    docstrings; the page once lacked nine exported names (``load_split``, ``TrolleyVectorEnv``, ...)."""
    import morality_gym

    homes = {name: api_home(name) for name in morality_gym.__all__}
    lines = ["# Python API", "",
             ("The public API of `morality_gym` (`import morality_gym`): every name it exports "
              "(`morality_gym.__all__`), generated from the docstrings when the site is built. The "
              "[concepts](../concepts.md) page explains what the pieces mean."), ""]
    placed: set[str] = set()
    titles = list(dict.fromkeys(title for title, _ in API_SECTIONS))
    for title in titles:
        prefixes = tuple(prefix for t, prefix in API_SECTIONS if t == title)
        names = sorted((n for n in morality_gym.__all__ if n not in placed
                        and any(homes[n] == p or homes[n].startswith(p + ".") for p in prefixes)),
                       key=lambda n: (API_FIRST.index(n) if n in API_FIRST else len(API_FIRST), n))
        extras = [(m, n) for m, n in API_EXTRAS if any(m.startswith(p) for p in prefixes)]
        if not names and not extras:
            continue
        lines += [f"## {title}", ""]
        for name in names:
            lines += _api_entry(homes[name], name, f"morality_gym.{name}")
            placed.add(name)
        for module, name in extras:
            lines += _api_entry(module, name, f"{module}.{name}")
    rest = [n for n in morality_gym.__all__ if n not in placed]
    if rest:
        lines += ["## Other", ""]
        for name in rest:
            lines += _api_entry(homes[name], name, f"morality_gym.{name}")
    return "\n".join(lines).rstrip() + "\n"


# ------------------------------------------------------------------------------------------------
# Configuration, from the typed schemas and conf/
# ------------------------------------------------------------------------------------------------


def _default(f: dataclasses.Field) -> str:
    if f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        value = f.default_factory()  # type: ignore[misc]
        if dataclasses.is_dataclass(value):
            return f"{type(value).__name__}() (below)"
    else:
        return "required"
    if isinstance(value, str):
        return f"`{value}`"
    return f"`{_yaml_scalar(value)}`"


def _yaml_scalar(value: Any) -> str:
    import yaml

    text = yaml.safe_dump(value, default_flow_style=True, width=10_000).strip()
    return text.removesuffix("\n...").removesuffix("...").strip()


def _comment_of(cls: type) -> dict[str, str]:
    """``field: type = default  # comment``: the comments beside a dataclass's fields in its source."""
    import inspect

    try:
        source = inspect.getsource(cls)
    except (OSError, TypeError):
        return {}
    out = {m.group(1): m.group(2).strip() for m in re.finditer(r"^[ \t]+(\w+):[^#\n]*#[ \t]*(.+)$", source, re.MULTILINE)
           if not m.group(2).startswith("type:")}
    # ``name``: what it is; ``other``: ... (the way Sweep documents its fields in its docstring)
    doc = " ".join((inspect.getdoc(cls) or "").split())
    for m in re.finditer(r"``(\w+)``: (.*?)(?=; ``\w+``:|\.$|$)", doc):
        out.setdefault(m.group(1), m.group(2))
    return out


def _split_union(kind: str) -> list[str]:
    """``int | None`` as ``["int", "None"]`` (a ``|`` inside a table cell's code cannot be escaped)."""
    parts, depth, current = [], 0, ""
    for ch in kind:
        if ch in "[(":
            depth += 1
        elif ch in "])":
            depth -= 1
        if ch == "|" and depth == 0:
            parts.append(current)
            current = ""
        else:
            current += ch
    return [*parts, current]


def _schema_table(cls: type) -> list[str]:
    import inspect

    doc = inspect.getdoc(cls) or ""
    comments = _comment_of(cls)
    lines = [_cell(doc.split("\n\n")[0]), "", "| field | type | default | note |", "|---|---|---|---|"]
    for f in dataclasses.fields(cls):
        kind = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
        kind = " or ".join(f"`{part.strip()}`" for part in _split_union(str(kind)))
        lines.append(f"| `{f.name}` | {kind} | {_cell(_default(f))} | {_cell(comments.get(f.name, ''))} |")
    return lines + [""]


def configuration_page() -> str:
    import yaml

    from morality_gym.baselines.specs import CONF_DIR, LearnerSpec, ProtocolSpec
    from runners.compose import schema

    groups: dict[str, tuple[str, list[type]]] = {
        "algo": (("a learner: its class (`_target_`), label and every setting; fields left out take "
                 "these defaults (`LearnerSpec`, `morality_gym/baselines/specs.py`)"), [schema.AlgoFile, schema.Planning]),
        "protocol": ("the reference's behaviours a run reproduces or corrects (`ProtocolSpec`)", [ProtocolSpec]),
        "preset": ("how much each run trains and evaluates", [schema.Preset]),
        "launcher": ("where the runs go: local worker pool or SLURM", [schema.LocalLauncher, schema.SlurmLauncher]),
        "scenario": ("the chains the paper ran on a scenario", [schema.ScenarioFile]),
        "chain": ("a chain option: `ref` names a chain (name, file or path)", []),
        "experiment": ("a fixed selection of (chain, scenario) pairs", [schema.Experiment]),
    }
    del LearnerSpec  # AlgoFile is derived from it; named above for the reader
    defaults = yaml.safe_load((CONF_DIR / "config.yaml").read_text())
    lines = [
        "# Configuration",
        "",
        ("Generated from the typed schemas (`runners/compose/schema.py`, `morality_gym/baselines/specs.py`) "
        "and the files of `conf/` when the site is built. A sweep composes `conf/config.yaml` over "
        "the top-level schema below; each group's files state only what differs from the field "
        "defaults. Override anything on the command line (`preset.budget=200000`, "
        "`launcher.workers=4`), or select another option (`preset=smoke`). See "
        "[Run sweeps](../how-to/sweeps.md) for where each default lives and how to keep your own files."),
        "",
        "## The sweep (`conf/config.yaml`)",
        "",
        "The defaults list: " + ", ".join(f"`{_yaml_scalar(d)}`" for d in defaults.get("defaults", [])) + ".",
        "",
        *_schema_table(schema.Sweep),
    ]
    for group, (what, classes) in groups.items():
        files = sorted((CONF_DIR / group).glob("*.yaml"))
        lines += [f"## `{group}`", "", f"{what[0].upper()}{what[1:]}. Options: "
                  + ", ".join(f"`{p.stem}`" for p in files) + ".", ""]
        for cls in classes:
            lines += [f"### `{cls.__name__}`", "", *_schema_table(cls)]
        for path in files:
            lines += [f'??? note "`conf/{group}/{path.name}`"', "", "    ```yaml",
                      *("    " + line for line in path.read_text().rstrip("\n").splitlines()), "    ```", ""]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------
# The results schema
# ------------------------------------------------------------------------------------------------


def _field_comments(source: str) -> dict[str, str]:
    return {m.group(1): m.group(2).strip()
            for m in re.finditer(r'pa\.field\("(\w+)",[^\n]*?\),?[ \t]*#[ \t]*(.+)$', source, re.MULTILINE)}


def results_schema_page() -> str:
    import inspect

    from morality_gym.results import schema as rs

    source = inspect.getsource(rs)
    comments = _field_comments(source)
    doc = inspect.getdoc(rs) or ""

    def table(fields: list[Any]) -> list[str]:
        rows = ["| column | type | meaning |", "|---|---|---|"]
        rows += [f"| `{f.name}` | `{f.type}` | {_cell(comments.get(f.name, ''))} |" for f in fields]
        return rows + [""]

    lines = [
        "# Results schema",
        "",
        f"Schema version **{rs.SCHEMA_VERSION}**. Generated from `morality_gym/results/schema.py` when the site is built.",
        "",
        *(_cell(p) for p in doc.split("\n\n")), "",
        "## Run rows: `runs/<run_id>.parquet`",
        "",
        (f"One row per run; plus one float column `{rs.MF_PREFIX}<norm>` per norm of the run's chain "
        "(its morality function in the final evaluation)."),
        "",
        *table(rs.RUN_FIELDS),
        "## Learn-time evaluations: `runs/<run_id>.learn.parquet`",
        "",
        f"One row per evaluation during training, plus `{rs.MF_PREFIX}<norm>` columns.",
        "",
        *table(rs.LEARN_FIELDS),
        "## Update diagnostics: `runs/<run_id>.updates.parquet`",
        "",
        "One row per policy update of PPO-Lag and CPO; columns that do not apply to a learner are null.",
        "",
        *table(rs.UPDATE_FIELDS),
        "## Versions",
        "",
        *(f"- **{v}**: {_cell(text)}" for v, text in sorted(rs.CHANGES.items())),
        "",
    ]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------
# The module map
# ------------------------------------------------------------------------------------------------

#: The packages of the map, in the order of the layers (docs/architecture.md).
MAP_PACKAGES = ("morality_gym", "runners", "leaderboard", "benchmarks")


def _summary(source: str) -> str:
    """The first line of a module's docstring (what the module is for), or a visible gap."""
    doc = ast.get_docstring(ast.parse(source))
    return _cell(doc.strip().splitlines()[0]) if doc and doc.strip() else "**(no docstring)**"


def module_map_page() -> str:
    """Every module with its line count and the first line of its docstring, folder by folder.

    Why generated: the map is how a newcomer finds where something lives from the file list alone;
    written by hand it would fall behind the first rename."""
    lines = ["# Module map", "",
             ("Every module of the code base, folder by folder, with its size and the first line of its "
              "docstring (generated from the code when the site is built). The layers and the rules "
              "between them are on the [architecture](../architecture.md) page."), ""]
    for package in MAP_PACKAGES:
        folders: dict[str, list[tuple[str, str]]] = {}  # folder -> (file name, source), each file read once
        for path in sorted((ROOT / package).rglob("*.py")):
            source = path.read_text(encoding="utf-8")
            if path.name == "__init__.py" and not source.strip():
                continue  # an empty package marker says nothing
            folders.setdefault(path.parent.relative_to(ROOT).as_posix(), []).append((path.name, source))
        total = sum(len(source.splitlines()) for files in folders.values() for _, source in files)
        lines += [f"## `{package}` ({total:,} lines)", ""]
        for folder, files in folders.items():
            lines += [f"### `{folder}/`", "", "| module | lines | what it is |", "|---|---:|---|"]
            lines += [f"| `{name}` | {len(source.splitlines())} | {_summary(source)} |" for name, source in files]
            lines.append("")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------
# MkDocs events
# ------------------------------------------------------------------------------------------------

TIMINGS: dict[str, float] = {}


def generated_files() -> dict[str, str | bytes]:
    """Every generated file, keyed by its path in the site's source tree."""
    out: dict[str, str | bytes] = {}
    for name, make in (("catalogue", lambda: {f"envs/{k}": v for k, v in catalogue().items()}),
                       ("cli", lambda: {"reference/cli.md": cli_page()}),
                       ("api", lambda: {"reference/api.md": api_page()}),
                       ("configuration", lambda: {"reference/configuration.md": configuration_page()}),
                       ("results schema", lambda: {"reference/results-schema.md": results_schema_page()}),
                       ("module map", lambda: {"reference/modules.md": module_map_page()}),
                       ("screenshots", lambda: {f"images/leaderboard-{p.stem}.png": p.read_bytes()
                                                for p in sorted((ROOT / "leaderboard").glob("*.png"))})):
        start = time.perf_counter()
        out.update(make())
        TIMINGS[name] = time.perf_counter() - start
    return out


def on_files(files: Any, config: Any) -> Any:
    from mkdocs.structure.files import File

    # docs/envs/ is where `python -m morality_gym docs` writes by default: the catalogue replaces it.
    for stale in [f for f in files if f.src_uri.startswith("envs/")]:
        files.remove(stale)
    for path, content in generated_files().items():
        stale = files.get_file_from_path(path)
        if stale is not None:
            files.remove(stale)
        files.append(File.generated(config, path, content=content))
    import logging

    logging.getLogger("mkdocs.hooks.generate").info(
        "generated pages: " + ", ".join(f"{k} {v:.1f}s" for k, v in TIMINGS.items()))
    return files


def on_config(config: Any) -> Any:
    """The catalogue's pages go into the navigation under "Environments", one per scenario."""
    from morality_gym import scenarios

    pages = ["envs/index.md", *(f"envs/{name}.md" for name in scenarios())]
    for i, item in enumerate(config["nav"] or []):
        if isinstance(item, dict) and item.get("Environments") == "envs/index.md":
            config["nav"][i] = {"Environments": pages}
    return config
