"""Morality chains as data: ordered lists of norms in YAML, loaded and validated here.

A chain (paper, Definition 3) is an ordered set of norms, highest force first. Chains ship as YAML
files in ``morality_gym/data/chains``; a user writes a new one as a YAML file (any order, prescribed
or prohibited, event or utility norms) and refers to it by path. A chain is looked up by its name
(``DualProcess``), its file name (``dual_process``), its abbreviation (``DP``), the reference's
internal id, or a path to a YAML file. Every mistake is reported with the file and the fix.
"""

from __future__ import annotations

import difflib
import hashlib
import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import yaml

from morality_gym.clitools import did_you_mean
from morality_gym.norms.catalogue import CATALOGUE
from morality_gym.world.layout import yaml_problem

BUILTIN_DIR = Path(__file__).resolve().parent.parent / "data" / "chains"
MODALITIES = ("prohibited", "prescribed")


class ChainError(ValueError):
    """A chain is malformed or unknown; the message says which and how to fix it."""


@dataclass(frozen=True)
class Norm:
    """One norm of a chain: the signature (an emitted name), its kind and its deontic modality."""

    name: str
    kind: str  # "event" | "utility"
    modality: str = "prohibited"

    @property
    def prohibited(self) -> bool:
        return self.modality == "prohibited"

    @property
    def abbreviation(self) -> str:
        return CATALOGUE[self.name].abbreviation

    @property
    def label(self) -> str:
        return CATALOGUE[self.name].label


@dataclass(frozen=True)
class MoralityChain:
    """An ordered set of norms, ``norms[0]`` with the highest force (paper, Definition 3)."""

    name: str
    norms: tuple[Norm, ...]
    abbreviation: str = ""
    description: str = ""
    aliases: tuple[str, ...] = ()
    source: str = ""

    @property
    def norm_names(self) -> list[str]:
        return [n.name for n in self.norms]

    def norm(self, name: str) -> Norm:
        for n in self.norms:
            if n.name == name:
                return n
        raise KeyError(f"chain {self.name} has no norm {name!r}; norms: {', '.join(self.norm_names)}")

    @property
    def content(self) -> tuple[tuple[str, str], ...]:
        """What the chain *is*: its norms in order of force, each with its modality (not its name)."""
        return tuple((n.name, n.modality) for n in self.norms)

    @property
    def fingerprint(self) -> str:
        """A short hash of :attr:`content`: equal for two chains exactly when they score alike."""
        return chain_fingerprint(self.content)

    @property
    def event_norms(self) -> list[Norm]:
        return [n for n in self.norms if n.kind == "event"]

    @property
    def utility_norms(self) -> list[Norm]:
        return [n for n in self.norms if n.kind == "utility"]


def chain_fingerprint(content: Any) -> str:
    """12 hex digits of SHA-256 over the canonical JSON of ``[[norm, modality], ...]``."""
    canonical = json.dumps([[str(n), str(m)] for n, m in content], separators=(",", ":"))
    return hashlib.sha256(canonical.encode()).hexdigest()[:12]


def _fail(source: str, where: str, problem: str, fix: str) -> ChainError:
    return ChainError(f"{source}: {where}: {problem}. Fix: {fix}")


#: The fields a chain file may have.
_FIELDS = {"name", "abbreviation", "aliases", "description", "norms"}


def parse_chain(raw: Any, source: str = "<chain>") -> MoralityChain:
    """Validate a parsed chain mapping (see the files in ``morality_gym/data/chains``).

    One parser per field, each raising the file / field / fix error it owns, checked in the order a
    person reads the file: the top level, ``name``, ``norms``, ``aliases``.
    """
    _check_top_level(raw, source)
    name = _parse_name(raw, source)
    norms = _parse_norms(raw, source)
    aliases = _parse_aliases(raw, source)
    return MoralityChain(
        name=name,
        norms=norms,
        abbreviation=str(raw.get("abbreviation", "")),
        description=str(raw.get("description", "")).strip(),
        aliases=aliases,
        source=source,
    )


def _check_top_level(raw: Any, source: str) -> None:
    """A mapping with only the known fields (an unknown one gets a did-you-mean)."""
    if not isinstance(raw, dict):
        raise _fail(source, "top level", "expected a mapping with 'name' and 'norms'", "see morality_gym/data/chains/utility.yaml")
    for key in raw:
        if key not in _FIELDS:
            hint = did_you_mean(key, sorted(_FIELDS), quote=False)
            raise _fail(source, str(key), f"unknown field{hint}", f"use only {', '.join(sorted(_FIELDS))}")


def _parse_name(raw: dict[str, Any], source: str) -> str:
    """``name``: a non-empty string, stripped."""
    name = raw.get("name")
    if not isinstance(name, str) or not name.strip():
        raise _fail(source, "name", "missing or not a string", "add 'name: MyChain'")
    return name.strip()


def _parse_norms(raw: dict[str, Any], source: str) -> tuple[Norm, ...]:
    """``norms``: at least one, highest force first, each named once."""
    items = raw.get("norms")
    if not isinstance(items, list) or not items:
        raise _fail(source, "norms", "a chain needs at least one norm", "list norms, highest force first")
    norms: list[Norm] = []
    seen: set[str] = set()
    for i, item in enumerate(items):
        where = f"norms[{i}]"
        norm = _parse_norm(item, source, where)
        if norm.name in seen:
            raise _fail(source, where, f"norm {norm.name!r} appears twice", "list each norm once (forces must be distinct)")
        seen.add(norm.name)
        norms.append(norm)
    return tuple(norms)


def _parse_norm(item: Any, source: str, where: str) -> Norm:
    """One entry of ``norms``: ``- name`` (prohibited) or ``- {norm: name, modality: ...}``."""
    if isinstance(item, str):
        norm_name, modality = item, "prohibited"
    elif isinstance(item, dict) and set(item) <= {"norm", "modality"} and "norm" in item:
        norm_name, modality = item["norm"], item.get("modality", "prohibited")
    else:
        raise _fail(source, where, f"expected a norm name or {{norm: name, modality: ...}}, got {item!r}", "write '- n_human_harm'")
    if norm_name not in CATALOGUE:
        close = difflib.get_close_matches(str(norm_name), list(CATALOGUE), n=3)
        hint = f" Did you mean {', '.join(close)}?" if close else ""
        raise _fail(source, where, f"unknown norm {norm_name!r}.{hint}", f"use one of the emitted names: {', '.join(CATALOGUE)}")
    if modality not in MODALITIES:
        raise _fail(source, f"{where}.modality", f"unknown modality {modality!r}", "use prohibited or prescribed")
    return Norm(norm_name, CATALOGUE[norm_name].kind, modality)


def _parse_aliases(raw: dict[str, Any], source: str) -> tuple[str, ...]:
    """``aliases`` (optional): a list of strings."""
    aliases = raw.get("aliases", []) or []
    if not isinstance(aliases, list) or not all(isinstance(a, str) for a in aliases):
        raise _fail(source, "aliases", "expected a list of strings", "write aliases: [OtherName]")
    return tuple(aliases)


def load_chain_file(path: str | Path) -> MoralityChain:
    """Load one chain YAML file."""
    path = Path(path)
    try:
        raw = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ChainError(f"{path}: cannot read the chain file: {exc}") from exc
    except yaml.YAMLError as exc:
        raise ChainError(f"{path}: not valid YAML: {yaml_problem(exc)}") from exc
    return parse_chain(raw, str(path))


@lru_cache(maxsize=1)
def _builtin_index() -> dict[str, MoralityChain]:
    """Built-in chains by config-file stem, in the order of the paper (U, UAH, O, OAH, DP, DPAH)."""
    order = ["utility", "utility_agent_harm", "outcome", "outcome_agent_harm", "dual_process", "dual_process_agent_harm"]
    paths = sorted(BUILTIN_DIR.glob("*.yaml"), key=lambda p: (order.index(p.stem) if p.stem in order else len(order), p.stem))
    return {path.stem: load_chain_file(path) for path in paths}


def builtin_chains() -> dict[str, MoralityChain]:
    """The chains that ship with the project, by name."""
    return {chain.name: chain for chain in _builtin_index().values()}


def builtin_named(name: str) -> MoralityChain | None:
    """The built-in chain that ``name`` refers to (name, file name, abbreviation or alias), if any."""
    wanted = name.strip().lower()
    for stem, chain in _builtin_index().items():
        if wanted in {chain.name.lower(), stem, chain.abbreviation.lower(), *(a.lower() for a in chain.aliases)} - {""}:
            return chain
    return None


def check_name_collision(chain: MoralityChain) -> None:
    """Refuse a user chain that takes a built-in chain's name but is not that chain.

    Results are labelled by the chain's name; a reordered "Utility" would be reported (and compared
    with the paper, and given the built-in's exact and oracle columns) as the real Utility. Scenario
    names are protected the same way. Same content under the same name is the same chain: accepted.
    """
    builtin = builtin_named(chain.name)
    if builtin is None or builtin.content == chain.content:
        return
    ours = " > ".join(f"{n}" + ("" if m == "prohibited" else f" ({m})") for n, m in chain.content)
    theirs = " > ".join(f"{n}" + ("" if m == "prohibited" else f" ({m})") for n, m in builtin.content)
    raise _fail(chain.source or "<chain>", "name",
                f"{chain.name!r} names the built-in chain {builtin.name} ({theirs}), but this chain is {ours}; "
                "results are keyed by what a chain is and labelled by its name, so it would pass for the built-in one",
                f"give it a name of its own (e.g. name: {chain.name}Custom), or use the built-in chain (ref: {builtin.name})")


def get_chain(ref: str | Path | MoralityChain) -> MoralityChain:
    """Resolve a chain reference: name, file name, abbreviation, reference id, or path to a YAML file.

    A chain file that takes a built-in chain's name for other norms is refused
    (:func:`check_name_collision`).
    """
    if isinstance(ref, MoralityChain):
        return ref
    text = str(ref)
    path = Path(text)
    if text.endswith((".yaml", ".yml")) or path.is_file():
        if not path.is_file():
            raise ChainError(f"chain file {text} does not exist")
        chain = load_chain_file(path)
        if path.resolve().parent != BUILTIN_DIR.resolve():
            check_name_collision(chain)
        return chain
    wanted = text.lower()
    for stem, chain in _builtin_index().items():
        keys = {chain.name.lower(), stem, chain.abbreviation.lower(), *(a.lower() for a in chain.aliases)} - {""}
        if wanted in keys:
            return chain
    names = [c.name for c in _builtin_index().values()]
    close = difflib.get_close_matches(text, names + list(_builtin_index()), n=3)
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    raise ChainError(f"Unknown morality chain {text!r}.{hint} Chains: {', '.join(names)} (or a path to a chain YAML file).")


def chain_file_stem(chain: MoralityChain) -> str:
    """The config-file name of a built-in chain (``DualProcess`` -> ``dual_process``); else its name."""
    for stem, known in _builtin_index().items():
        if known.name == chain.name:
            return stem
    return chain.name
