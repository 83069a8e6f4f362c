"""The published splits: their manifests agree with themselves and with what the generator produces
(checked on a sample of seeds: the whole train split takes minutes), and load_split refuses files
that are not the split's."""

from __future__ import annotations

import json
import re
from pathlib import Path

import gymnasium as gym
import pytest

from morality_gym.envs.registry import SCENARIOS_ENV, load_user_file
from morality_gym.generator.grammar import GRAMMAR_VERSION, NAME_PREFIX
from morality_gym.generator.measure import HORIZON, MAX_STATES
from morality_gym.generator.pipeline import REJECTION_REASONS, attempt, files_digest, generate, sha256_bytes
from morality_gym.generator.splits import (
    SPLIT_SEEDS,
    ProgressLine,
    SplitError,
    load_split,
    manifest_record,
    manifest_text,
    split_manifest,
    split_names,
)
from morality_gym.world.bounds_cache import CACHE_FOLDER, BoundsCacheWarning, entry_path
from morality_gym.world.layout import ScenarioError


@pytest.mark.parametrize("name", split_names())
def test_manifest_is_consistent(name: str) -> None:
    manifest = split_manifest(name)
    assert manifest.name == name and manifest.seeds == SPLIT_SEEDS[name]
    assert manifest.grammar_version == GRAMMAR_VERSION and manifest.max_states == MAX_STATES
    assert manifest.digest == files_digest(manifest.files)
    text = Path(manifest.source).read_text()
    assert text == manifest_text(json.loads(text)), "regenerate the manifest with splits.publish_split"
    kept = {int(f.removeprefix(NAME_PREFIX).removesuffix(".yaml")) for f in manifest.files}
    rejected = {seed for seeds in manifest.rejected.values() for seed in seeds}
    assert set(manifest.rejected) == set(REJECTION_REASONS) and not kept & rejected
    assert kept | rejected == set(manifest.seed_range)


def test_split_seed_ranges_do_not_overlap() -> None:
    train, test = (range(a, b + 1) for a, b in (SPLIT_SEEDS["train"], SPLIT_SEEDS["test"]))
    assert not set(train) & set(test)


@pytest.mark.parametrize("name", split_names())
def test_a_sample_of_the_split_regenerates_to_its_published_bytes(name: str, tmp_path: Path) -> None:
    manifest = split_manifest(name)
    kept = sorted(int(f.removeprefix(NAME_PREFIX).removesuffix(".yaml")) for f in manifest.files)
    sample = [kept[0], kept[len(kept) // 2], kept[-1]]
    for seed in sample:
        result = attempt(seed, tmp_path, with_values=False)
        assert result.text is not None, f"seed {seed} of split {name} is no longer kept ({result.reason})"
        assert sha256_bytes(result.text.encode()) == manifest.files[f"{NAME_PREFIX}{seed}.yaml"], seed
    reason, seeds = next((r, s) for r, s in manifest.rejected.items() if s)
    assert attempt(seeds[0], tmp_path, with_values=False).reason == reason


@pytest.fixture()
def tiny_manifest(tmp_path: Path) -> Path:
    """A split of four seeds, published the way the real ones are."""
    report = generate(range(100, 104), tmp_path / "made", pictures=False, with_values=False)
    path = tmp_path / "tiny.json"
    path.write_text(json.dumps(manifest_record("tiny", report.index)))
    return path


@pytest.mark.usefixtures("isolated_scenarios")
def test_load_split_generates_checks_caches_and_registers(tiny_manifest: Path, tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(SCENARIOS_ENV, "")
    ids = load_split(tiny_manifest, cache_dir=tmp_path / "cache")
    manifest = split_manifest(tiny_manifest)
    assert ids and {i.split("-")[0] + ".yaml" for i in ids} == set(manifest.files)
    shapes = {gym.make(f"MoralityGym/{i}", obs_type="grid").reset()[0].shape for i in ids}
    assert len(shapes) == 1  # one policy can act in all of them
    monkeypatch.setattr("morality_gym.generator.splits.generate", None)  # a second load must not generate
    assert load_split(tiny_manifest, cache_dir=tmp_path / "cache") == ids


@pytest.mark.usefixtures("isolated_scenarios")
def test_files_that_are_not_the_split_are_refused(tiny_manifest: Path, tmp_path: Path) -> None:
    record = json.loads(tiny_manifest.read_text())
    first = next(iter(record["files"]))
    record["files"][first] = "0" * 64
    record["digest"] = files_digest(record["files"])
    forged = tmp_path / "forged.json"
    forged.write_text(json.dumps(record))
    with pytest.raises(SplitError, match=rf"{first}: differs from the published file \(split tiny"):
        load_split(forged, cache_dir=tmp_path / "cache")


def test_unknown_split_is_one_clear_line() -> None:
    with pytest.raises(SplitError, match="unknown split 'valid'. Fix: use one of train, test"):
        split_manifest("valid")


def test_the_docs_publish_the_manifests_digests() -> None:
    page = (Path(__file__).resolve().parents[1] / "docs" / "how-to" / "generate-dilemmas.md").read_text()
    for name in split_names():
        manifest = split_manifest(name)
        assert f"| `{name}` |" in page and f"`{manifest.digest}`" in page, f"the docs' digest of {name} is stale"


# ------------------------------------------------------------------ the bounds cache (issue 44)
def _enumerations(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Record every bounds enumeration of a loaded file (by scenario name)."""
    from morality_gym.envs import registry

    seen: list[str] = []
    real = registry.variant_spans

    def counted(scenario, horizon, graphs=None):  # type: ignore[no-untyped-def]
        seen.append(scenario.name)
        return real(scenario, horizon, graphs)

    monkeypatch.setattr(registry, "variant_spans", counted)
    return seen


@pytest.mark.usefixtures("isolated_scenarios")
def test_a_generated_split_loads_without_enumerating_its_graphs_again(tiny_manifest: Path, tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(SCENARIOS_ENV, "")
    enumerated = _enumerations(monkeypatch)
    ids = load_split(tiny_manifest, cache_dir=tmp_path / "cache")
    assert ids and enumerated == []  # the generator recorded the bounds it measured
    entries = list((tmp_path / "cache" / "splits").glob(f"*/{CACHE_FOLDER}/*.json"))
    assert len(entries) == len(split_manifest(tiny_manifest).files)


@pytest.mark.usefixtures("isolated_scenarios")
def test_a_bounds_entry_of_another_file_or_edited_is_refused_with_one_line(tiny_manifest: Path, tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(SCENARIOS_ENV, "")
    load_split(tiny_manifest, cache_dir=tmp_path / "cache")
    directory = next((tmp_path / "cache" / "splits").glob("tiny-*"))
    files = sorted(directory.glob(f"{NAME_PREFIX}*.yaml"))
    digests = [sha256_bytes(f.read_bytes()) for f in files]
    first = entry_path(directory / CACHE_FOLDER, digests[0], HORIZON)
    second = entry_path(directory / CACHE_FOLDER, digests[1], HORIZON)
    # 1. an entry copied over another file's: it records the other file's digest
    first.write_text(second.read_text())
    # 2. an edited span: the checksum no longer matches
    raw = json.loads(second.read_text())
    variant = next(iter(raw["variants"]))
    raw["variants"][variant]["n_human_harm"][1] += 7
    second.write_text(json.dumps(raw))
    enumerated = _enumerations(monkeypatch)
    with pytest.warns(BoundsCacheWarning) as caught:
        [load_user_file(path) for path in files[:2]]
    messages = [str(w.message) for w in caught]
    assert any("it records the scenario digest" in m for m in messages), messages
    assert any("do not match its checksum: edited or damaged" in m for m in messages), messages
    assert all("\n" not in m and "measuring the bounds again" in m for m in messages)
    assert len(enumerated) == 2  # both measured again
    assert json.loads(second.read_text())["variants"][variant]["n_human_harm"][1] == raw["variants"][variant]["n_human_harm"][1] - 7


def test_a_file_whose_bounds_are_wrong_is_still_refused_from_the_cache(tmp_path: Path) -> None:
    """The cache holds what the worlds produce, not a verdict: a file declaring other bounds fails
    on every load, the cached ones included."""
    made = tmp_path / "made"
    generate(range(100, 101), made, pictures=False, with_values=False, bounds_cache=True)
    path = next(made.glob(f"{NAME_PREFIX}*.yaml"))
    load_user_file(path)  # passes, from the cache
    text = path.read_text()

    # a variant's bounds (a line "  Name: {characters: ..., bounds: {n_human_harm: [a, b], ...}}"), not utility_bounds
    wrong = re.sub(r"(bounds: \{n_human_harm: \[\d+, )(\d+)\]", lambda m: f"{m[1]}{int(m[2]) + 1}]", text, count=1)
    assert wrong != text
    path.write_text(wrong)
    with pytest.raises(ScenarioError, match=r"bounds\.n_human_harm: .* does not match what the variant can produce"):
        load_user_file(path)
    assert len(list((made / CACHE_FOLDER).glob("*.json"))) == 2  # the wrong file's spans were recorded too
    with pytest.raises(ScenarioError, match=r"does not match what the variant can produce"):
        load_user_file(path)  # the second time from the entry the first one wrote


def test_generating_over_workers_writes_the_same_bytes(tmp_path: Path) -> None:
    lines: list[tuple[int, int | None, int]] = []
    serial = generate(range(100, 106), tmp_path / "one", pictures=False, with_values=False)
    parallel = generate(range(100, 106), tmp_path / "two", pictures=False, with_values=False, workers=2,
                        progress=lambda done, total, kept, seconds: lines.append((done, total, kept)))
    assert serial.index == parallel.index
    assert [a.seed for a in parallel.attempts] == list(range(100, 106))
    assert lines[-1] == (6, 6, parallel.index["kept"]) and [d for d, _, _ in lines] == list(range(1, 7))


def test_the_progress_line_says_how_far_and_how_long() -> None:
    import io

    stream = io.StringIO()
    line = ProgressLine("generating split train", every=10.0, stream=stream)
    line(1, 1000, 1, 2.0)
    line(2, 1000, 2, 4.0)  # within 10 s of the last line: quiet
    line(1000, 1000, 850, 2000.0)  # the end is always shown
    assert stream.getvalue().splitlines() == [
        "generating split train: 1/1000 seeds, 1 kept, 2 s, about 1998 s left",
        "generating split train: 1000/1000 seeds, 850 kept, 2000 s, about 0 s left",
    ]
