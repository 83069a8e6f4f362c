"""The published splits: their manifests agree with themselves and with what the generator produces
(checked on a sample of seeds: the whole train split takes minutes), and load_split refuses files
that are not the split's."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import pytest

from morality_gym.envs.registry import SCENARIOS_ENV
from morality_gym.generator.grammar import GRAMMAR_VERSION, NAME_PREFIX
from morality_gym.generator.measure import MAX_STATES
from morality_gym.generator.pipeline import REJECTION_REASONS, attempt, files_digest, generate, sha256_bytes
from morality_gym.generator.splits import (
    SPLIT_SEEDS,
    SplitError,
    load_split,
    manifest_record,
    manifest_text,
    split_manifest,
    split_names,
)


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
