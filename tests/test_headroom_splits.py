"""Splits v2 (issue 44 item 2): the (env id, chain) pairs of the v1 splits where Random leaves the
oracle's best at least the threshold of headroom; their manifests are checked before use."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from morality_gym.generalisation.headroom import headroom_summary, manifest_record, manifest_text, select
from morality_gym.generalisation.selection import THRESHOLD, manifest_path, read_manifest, selection_digest
from morality_gym.generalisation.sets import PairValues
from morality_gym.generator.splits import SplitError, split_manifest


def _pv(env_id: str, headroom: float) -> PairValues:
    return PairValues(env_id, "Utility", 0.9, 0.0, 0.9 - headroom)


def test_the_selection_keeps_the_pairs_with_headroom_and_says_what_it_dropped() -> None:
    ids = ["Gen0-HumanA-v1", "Gen0-HumanB-v1", "Gen1-Human-v1", "Gen2-Human-v1"]
    values = {"Utility": [_pv(ids[0], 0.02), _pv(ids[1], 0.1), _pv(ids[2], 0.6)]}  # ids[3]: not a dilemma
    assert select(values["Utility"], 0.1) == [ids[1], ids[2]]
    record = manifest_record("train", ids, values, 0.1)
    assert record["pairs"] == {"Utility": [ids[1], ids[2]]}
    assert record["chains"]["Utility"]["dropped"] == {"not_a_dilemma": 1, "below_threshold": 1}
    assert record["chains"]["Utility"]["headroom"]["below"]["0.05"] == pytest.approx(1 / 3, abs=1e-4)
    assert record["seeds_tried"] == 1000 and record["base_digest"] == split_manifest("train").digest
    assert record["digest"] == selection_digest(record["base_digest"], 0.1, record["pairs"])
    assert headroom_summary([]) == {"pairs": 0}


def test_an_edited_or_stale_v2_manifest_is_refused(tmp_path: Path) -> None:
    record = manifest_record("test", ["Gen1000000-Human-v1"], {"Utility": [_pv("Gen1000000-Human-v1", 0.5)]}, 0.1)
    path = manifest_path("test", tmp_path)
    path.write_text(manifest_text(record))
    assert read_manifest("test", tmp_path).env_ids("Utility") == ["Gen1000000-Human-v1"]
    with pytest.raises(SplitError, match="no pairs of chain 'DualProcess'; it has Utility"):
        read_manifest("test", tmp_path).env_ids("DualProcess")
    edited = json.loads(path.read_text())
    edited["pairs"]["Utility"].append("Gen1000001-Human-v1")
    path.write_text(json.dumps(edited))
    with pytest.raises(SplitError, match="its pairs do not give its digest .*: edited"):
        read_manifest("test", tmp_path)
    stale = {**record, "base_digest": "0" * 64}
    stale["digest"] = selection_digest(stale["base_digest"], 0.1, stale["pairs"])
    path.write_text(manifest_text(stale))
    with pytest.raises(SplitError, match="selects from split test of digest 0000000000000000"):
        read_manifest("test", tmp_path)


@pytest.mark.parametrize("split", ["train", "test"])
def test_the_published_v2_manifests_are_consistent(split: str) -> None:
    manifest = read_manifest(split)
    assert manifest.threshold == THRESHOLD and manifest.base_digest == split_manifest(split).digest
    raw = json.loads(Path(manifest.source).read_text())
    assert Path(manifest.source).read_text() == manifest_text(raw), "republish with headroom.publish"
    files = split_manifest(split).files
    for chain, ids in manifest.pairs.items():
        summary = raw["chains"][chain]
        assert summary["kept"] == len(ids) and summary["kept"] + sum(summary["dropped"].values()) == summary["env_ids"]
        assert all(f"{env_id.split('-')[0]}.yaml" in files for env_id in ids)


@pytest.mark.usefixtures("isolated_scenarios")
def test_a_kept_and_a_dropped_pair_of_the_train_manifest_are_right_exactly(tmp_path: Path) -> None:
    """The manifest is exact values, so anyone can check it: regenerate two of its dilemmas and
    compute their headroom under Utility."""
    import morality_gym
    from morality_gym.generalisation.sets import dilemma_values
    from morality_gym.generator.pipeline import generate

    manifest = read_manifest("train")
    kept = manifest.pairs["Utility"][0]
    seeds = [int(f.removeprefix("Gen").removesuffix(".yaml")) for f in split_manifest("train").files]
    kept_set = set(manifest.pairs["Utility"])
    generate(sorted(seeds)[:12], tmp_path, pictures=False, with_values=False)
    ids = morality_gym.add_scenario_dir(tmp_path)
    dropped = next(e for e in ids if e not in kept_set)
    assert kept in ids, "the first kept pair comes from the first seeds"
    for env_id, inside in [(kept, True), (dropped, False)]:
        values = dilemma_values(env_id, ["Utility"])
        headroom = values[0].best - values[0].random if values else None
        assert (headroom is not None and headroom >= manifest.threshold) == inside, (env_id, headroom)
