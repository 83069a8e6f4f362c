"""From seeds to kept dilemmas: draw, write, load as a user file, measure, score, keep or reject.

Each seed is one attempt (:func:`attempt`):

1. draw a plan (:mod:`~morality_gym.generator.grammar`);
2. enumerate each variant's state graph, within :data:`~morality_gym.generator.measure.MAX_STATES`
   (else rejected: ``graph_too_large``), which gives the exact harm bounds the file must declare;
3. write the scenario file and load it exactly as a user's file is loaded
   (:func:`~morality_gym.envs.registry.load_user_file`: fields, layout, wiring, and the bounds
   checked again by enumeration; a failure would be a bug of the grammar: ``invalid``);
4. score every variant under every built-in chain (:mod:`~morality_gym.generator.scoring`) and
   keep the variants that are a dilemma under at least one chain; none: ``not_a_dilemma``.

:func:`generate` runs attempts over consecutive seeds and writes each kept dilemma as
``<name>.yaml`` (the scenario file), ``<name>.json`` (its exact values) and ``<name>.png`` (its
picture, by the catalogue's renderer), and ``index.json``: the seeds tried, the rejected seeds by
reason, and the SHA-256 of every scenario file with their :func:`files_digest`. Nothing in these
files depends on the clock or the machine, so the same seeds give the same bytes (the pictures
depend on the installed Pillow and fonts, so digests cover the scenario files only).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import multiprocessing
import os
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import yaml
from PIL import Image

from morality_gym.envs.registry import BUILTIN_DIR, load_user_file, scenario_on_trial
from morality_gym.generator.grammar import GRAMMAR_VERSION, Plan, draw_plan
from morality_gym.generator.measure import (
    HORIZON,
    MAX_STATES,
    GraphTooLarge,
    VariantMeasure,
    measure_variant,
    scenario_bounds,
    variant_bounds,
)
from morality_gym.generator.scoring import VariantScore, score_variant
from morality_gym.generator.writer import SCENARIO_UTILITIES, scenario_text
from morality_gym.render.rgb import render_rgb
from morality_gym.world.bounds import Spans
from morality_gym.world.bounds_cache import CACHE_FOLDER, write_entry
from morality_gym.world.layout import UTILITY_TYPES, Scenario, ScenarioError, load_scenario, parse_scenario
from morality_gym.world.rules import World

#: Why a seed gives no dilemma (the keys of ``index.json``'s ``rejected``).
GRAPH_TOO_LARGE = "graph_too_large"
NOT_A_DILEMMA = "not_a_dilemma"
INVALID = "invalid"
REJECTION_REASONS = (GRAPH_TOO_LARGE, NOT_A_DILEMMA, INVALID)
INDEX_FILE = "index.json"
#: A drawn scenario is scored under this prefix and its name, so that scoring seeds whose dilemmas
#: are already registered in the process (a loaded split) neither clashes with nor replaces them.
TRIAL_PREFIX = "GeneratorTrial"
PICTURE_CELL = 32  # pixels per grid cell, as the catalogue's pictures


@dataclass
class Attempt:
    """What one seed gave: a kept dilemma (its file's text and scores) or the reason it was rejected."""

    seed: int
    plan: Plan
    text: str | None = None
    reason: str | None = None
    detail: str = ""
    states: dict[str, int] = field(default_factory=dict)  # per kept env id
    scores: dict[str, VariantScore] = field(default_factory=dict)  # per kept env id
    spans: Spans = field(default_factory=dict)  # per kept variant name: what its bounds were measured from

    @property
    def kept(self) -> bool:
        return self.text is not None


@cache
def builtin_names() -> frozenset[str]:
    """The built-in scenarios' names, which no generated name may take."""
    return frozenset(load_scenario(path).name for path in BUILTIN_DIR.glob("*.yaml"))


def _draft(plan: Plan) -> Scenario:
    """The plan as a scenario with placeholder bounds: enough to enumerate its worlds."""
    zero = {key: (0, 0) for key in UTILITY_TYPES}
    text = scenario_text(plan, {v.name: zero for v in plan.variants}, {key: (0, 1) for key in SCENARIO_UTILITIES})
    return parse_scenario(yaml.safe_load(text), f"<draft of {plan.name}>")


def _write_and_load(plan: Plan, measures: Mapping[str, VariantMeasure], workdir: Path,
                    utility_bounds: Mapping[str, tuple[int, int]] | None = None) -> tuple[str, Scenario]:
    """The plan's file with its measured bounds, loaded back as a user's file is. The scenario-wide
    ``utility_bounds`` default to those of ``measures``; a file rewritten without some variants
    keeps those of every variant drawn, so that dropping one changes no other line."""
    text = scenario_text(plan, {name: variant_bounds(m) for name, m in measures.items()},
                         utility_bounds or scenario_bounds(list(measures.values())))
    path = workdir / f"{plan.name}.yaml"
    path.write_text(text)
    return text, load_user_file(path, {name: m.graph for name, m in measures.items()})


def attempt(seed: int, workdir: Path, *, with_values: bool = True, max_states: int = MAX_STATES) -> Attempt:
    """Draw seed ``seed``'s dilemma and keep or reject it (module docstring); files go to ``workdir``."""
    plan = draw_plan(seed)
    if plan.name in builtin_names():
        raise RuntimeError(f"generated name {plan.name} is a built-in scenario's: change grammar.NAME_PREFIX")
    result = Attempt(seed, plan)
    try:
        draft = _draft(plan)
        measures = {v.name: measure_variant(draft, v.name, max_states) for v in plan.variants}
    except GraphTooLarge as exc:
        result.reason, result.detail = GRAPH_TOO_LARGE, str(exc)
        return result
    try:
        text, scenario = _write_and_load(plan, measures, workdir)
        trial = dataclasses.replace(scenario, name=TRIAL_PREFIX + scenario.name)
        with scenario_on_trial(trial, {name: m.graph for name, m in measures.items()}):
            scores = {v.name: score_variant(trial.env_id(v.name), with_values) for v in plan.variants}
        kept = {name for name, score in scores.items() if score.is_dilemma}
        if not kept:
            result.reason = NOT_A_DILEMMA
            return result
        if len(kept) < len(plan.variants):  # the file is written again without the other variants
            plan = result.plan = plan.with_variants(kept)
            text, scenario = _write_and_load(plan, {name: measures[name] for name in kept}, workdir,
                                             scenario_bounds(list(measures.values())))
    except ScenarioError as exc:
        result.reason, result.detail = INVALID, str(exc)
        return result
    result.text = text
    result.states = {scenario.env_id(v.name): measures[v.name].n_states for v in plan.variants}
    result.scores = {scenario.env_id(v.name): scores[v.name] for v in plan.variants}
    result.spans = {v.name: dict(measures[v.name].spans) for v in plan.variants}
    return result


# ------------------------------------------------------------------------------------ files
def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def files_digest(hashes: Mapping[str, str]) -> str:
    """The digest of a set of files: SHA-256 of their ``sha256sum`` listing sorted by file name,
    so ``LC_ALL=C sha256sum *.yaml | sha256sum`` in their directory prints it too."""
    listing = "".join(f"{hashes[name]}  {name}\n" for name in sorted(hashes))
    return sha256_bytes(listing.encode())


def values_record(result: Attempt) -> dict[str, object]:
    """``<name>.json``: the dilemma's blocks and, per variant, its graph size and exact values."""
    assert result.text is not None
    return {
        "name": result.plan.name,
        "seed": result.seed,
        "grammar_version": GRAMMAR_VERSION,
        "scenario_sha256": sha256_bytes(result.text.encode()),
        "summary": result.plan.summary,
        "blocks": result.plan.blocks,
        "variants": {
            env_id: {
                "states": result.states[env_id],
                "dilemma_under": score.dilemma_under,
                "chains": {name: values.to_dict() for name, values in score.chains.items()},
            }
            for env_id, score in result.scores.items()
        },
    }


def picture_png(path: Path) -> bytes:
    """The start of the scenario file's first variant, drawn by the catalogue's renderer."""
    scenario = load_scenario(path)
    world = World(scenario, next(iter(scenario.variants)))
    buffer = io.BytesIO()
    Image.fromarray(render_rgb(world, world.initial_state, PICTURE_CELL)).save(buffer, format="PNG", optimize=True)
    return buffer.getvalue()


def _json_text(data: object) -> str:
    return json.dumps(data, indent=1, sort_keys=False) + "\n"


@dataclass
class RunReport:
    """What :func:`generate` did: the index it wrote, each kept attempt, and how long it took."""

    index: dict[str, object]
    attempts: list[Attempt]
    seconds: float

    @property
    def kept(self) -> list[Attempt]:
        return [a for a in self.attempts if a.kept]


def _index(attempts: list[Attempt], hashes: dict[str, str], max_states: int) -> dict[str, object]:
    rejected = {reason: [a.seed for a in attempts if a.reason == reason] for reason in REJECTION_REASONS}
    return {
        "grammar_version": GRAMMAR_VERSION,
        "max_states": max_states,
        "seeds": [attempts[0].seed, attempts[-1].seed] if attempts else [],
        "tried": len(attempts),
        "kept": len(hashes),
        "rejected": rejected,
        "digest": files_digest(hashes),
        "files": {name: hashes[name] for name in sorted(hashes)},
    }


#: ``progress(done, total, kept, seconds)``: called as seeds finish (``total`` is ``None`` when unknown).
Progress = Callable[[int, int | None, int, float], None]


def _attempt_in_worker(seed: int, workdir: str, with_values: bool, max_states: int) -> Attempt:
    """:func:`attempt` in a pool worker, with a scratch directory of its own under ``workdir``."""
    mine = Path(workdir) / f"worker-{os.getpid()}"
    mine.mkdir(exist_ok=True)
    return attempt(seed, mine, with_values=with_values, max_states=max_states)


def _attempts(seeds: Iterable[int], workdir: Path, with_values: bool, max_states: int, workers: int) -> Iterator[Attempt]:
    """Every seed's attempt, in seed order; over ``workers`` processes when more than one.

    Workers are spawned, not forked: a fork copies whatever threads and locks the caller holds
    (torch's, a test runner's), and a fresh import costs a second per worker against minutes of work.
    """
    if workers <= 1:
        for seed in seeds:
            yield attempt(seed, workdir, with_values=with_values, max_states=max_states)
        return
    seed_list = list(seeds)
    chunk = max(1, min(8, len(seed_list) // (workers * 8)))
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        try:
            yield from pool.map(_attempt_in_worker, seed_list, [str(workdir)] * len(seed_list),
                                [with_values] * len(seed_list), [max_states] * len(seed_list), chunksize=chunk)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)  # a caller that stops early (``count``) waits for no more


def generate(
    seeds: Iterable[int],
    out: str | Path,
    *,
    count: int | None = None,
    pictures: bool = True,
    with_values: bool = True,
    max_states: int = MAX_STATES,
    workers: int = 1,
    progress: Progress | None = None,
    bounds_cache: bool = False,
) -> RunReport:
    """Attempt ``seeds`` in order (stopping once ``count`` are kept, if given) and write the kept
    dilemmas, their values and pictures, and ``index.json`` into ``out`` (module docstring).

    ``workers`` > 1 attempts the seeds in that many processes (the files and the index are the same
    bytes: each seed's attempt depends on the seed alone, and results are taken in seed order).
    ``bounds_cache``: record each kept file's measured bounds in ``out``'s bounds cache
    (:mod:`~morality_gym.world.bounds_cache`), so that loading ``out`` enumerates nothing again.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if bounds_cache:
        (out / CACHE_FOLDER).mkdir(exist_ok=True)
    started = time.perf_counter()
    attempts: list[Attempt] = []
    hashes: dict[str, str] = {}
    total = len(seeds) if count is None and isinstance(seeds, range | list | tuple) else None  # else: unknown
    with tempfile.TemporaryDirectory(prefix="morality-gym-generate-") as tmp:
        for result in _attempts(seeds, Path(tmp), with_values, max_states, workers):
            if count is not None and len(hashes) >= count:
                break
            attempts.append(result)
            if result.kept:
                hashes[f"{result.plan.name}.yaml"] = _write_kept(result, out, pictures, with_values)
                if bounds_cache:
                    write_entry(out / CACHE_FOLDER, hashes[f"{result.plan.name}.yaml"], HORIZON, result.spans)
            if progress is not None:
                progress(len(attempts), total, len(hashes), time.perf_counter() - started)
    index = _index(attempts, hashes, max_states)
    (out / INDEX_FILE).write_text(_json_text(index))
    return RunReport(index, attempts, time.perf_counter() - started)


def _write_kept(result: Attempt, out: Path, pictures: bool, with_values: bool) -> str:
    """Write one kept dilemma's files; returns the scenario file's SHA-256."""
    assert result.text is not None
    path = out / f"{result.plan.name}.yaml"
    path.write_bytes(result.text.encode())
    if with_values:
        (out / f"{result.plan.name}.json").write_text(_json_text(values_record(result)))
    if pictures:
        (out / f"{result.plan.name}.png").write_bytes(picture_png(path))
    return sha256_bytes(result.text.encode())
