"""Where the sweep configuration lives: ``conf/``, the user's directories and the plugins' (the search path).

The location is defined once, as :data:`morality_gym.baselines.specs.CONF_DIR` (the package
directory ``morality_gym/conf``): the library's loaders (``learner_spec("ppo_lag")``) read the same
files as a sweep, and they sit below ``runners`` in the layers. In the repository that directory is
a symbolic link to ``conf/`` at the root (where people look for it and edit it); a wheel installs
the files themselves there (``pyproject.toml``'s package data), so a checkout, an editable install
and ``pip install .`` find it the same way. Users do not edit it: they add or override files from
their own directory (``--config-dir``).

Kept apart from :mod:`runners.compose.sweep_config` (which validates whole sweeps and so imports the learners,
and with them torch). What readers of results need of the configuration (a preset's seeds) is
:mod:`morality_gym.results.presets`, below the runners.
"""

from __future__ import annotations

import importlib.util
import sys
from importlib.metadata import entry_points
from pathlib import Path

from morality_gym.baselines.specs import CONF_DIR

#: Entry-point group of installed plugins: each entry point names a package that is a config root
#: (holding ``algo/*.yaml`` and, if it likes, ``chain/``, ``scenario/``, ...), e.g. in a plugin's
#: pyproject.toml: ``[project.entry-points."morality_gym.algos"] my_algos = "my_algos.conf"``.
ENTRY_POINT_GROUP = "morality_gym.algos"


def plugin_sources() -> list[str]:
    """``pkg://`` search-path entries of the installed plugins (:data:`ENTRY_POINT_GROUP`)."""
    return [f"pkg://{ep.module}" for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name)]


def source_dir(source: str) -> Path | None:
    """The directory of a Hydra search-path entry (``file://DIR``, ``pkg://package`` or a plain path)."""
    if source.startswith("pkg://"):
        try:
            spec = importlib.util.find_spec(source[len("pkg://"):].replace("/", "."))
        except (ImportError, ValueError):
            return None
        locations = list(spec.submodule_search_locations or []) if spec else []
        return Path(locations[0]) if locations else None
    path = source.removeprefix("file://")
    return Path(path).expanduser().resolve() if path else None


def split_list(value: str) -> list[str]:
    """The items of a command-line list (``[a,b]``, ``a``)."""
    value = value.strip()
    if value.startswith("[") and value.endswith("]"):
        value = value[1:-1]
    return [item.strip().strip("'\"") for item in value.split(",") if item.strip()]


def sources_from_argv(argv: list[str]) -> list[str]:
    """The config search-path entries a sweep's command line adds: ``--config-dir DIR``,
    ``--config-dir=DIR``, ``-cd DIR`` and ``hydra.searchpath=[...]`` (in that order of appearance)."""
    out: list[str] = []
    for i, arg in enumerate(argv):
        if arg in ("--config-dir", "-cd") and i + 1 < len(argv):
            out.append(argv[i + 1])
        elif arg.startswith("--config-dir="):
            out.append(arg.split("=", 1)[1])
        elif arg.lstrip("+").startswith("hydra.searchpath="):
            out.extend(split_list(arg.split("=", 1)[1]))
    return out


def _hydra_sources() -> list[str] | None:
    """The search path of the running Hydra job (``HydraConfig``'s ``runtime.config_sources``,
    which holds ``--config-dir`` in either form, ``hydra.searchpath`` and the plugins merged into
    it), or None where Hydra is not running (before it parses the command line, or a library caller)."""
    try:
        # Hydra waits: importing runners.compose.search_path must not load it
        from hydra.core.hydra_config import HydraConfig

        if not HydraConfig.initialized():
            return None
        sources = HydraConfig.get().runtime.config_sources
    except (ImportError, ValueError, AttributeError):
        return None
    return [f"{s.schema}://{s.path}" if s.schema == "pkg" else str(s.path)
            for s in sources if s.schema in ("file", "pkg") and s.provider not in ("hydra", "schema")]


def config_roots(argv: list[str] | None = None) -> list[Path]:
    """Every directory the sweep composes configuration from: the command line's, the installed
    plugins', then ``conf/`` (Hydra's own order of precedence for the same file name).

    Inside a Hydra job the answer is Hydra's own record of its search path; only where Hydra is not
    running (the command-line checks that run before it) is it read from ``argv``.
    """
    sources = _hydra_sources() if argv is None else None
    if sources is None:
        sources = [*sources_from_argv(sys.argv[1:] if argv is None else argv), *plugin_sources()]
    roots = [d for d in (source_dir(s) for s in sources) if d is not None and d.is_dir()]
    roots = [r for r in roots if r.resolve() != CONF_DIR.resolve()]
    return list(dict.fromkeys([*roots, CONF_DIR]))


def find_config(group: str, option: str, argv: list[str] | None = None) -> Path | None:
    """The file of a config-group option (``algo``, ``a2c``) on the search path, or None."""
    for root in config_roots(argv):
        path = root / group / f"{option}.yaml"
        if path.is_file():
            return path
    return None


def group_options(group: str, argv: list[str] | None = None) -> list[str]:
    """Every option of a config group on the search path."""
    return sorted({p.stem for root in config_roots(argv) for p in (root / group).glob("*.yaml")})
