"""The simulators' table cache (issue 44: a fleet on the track's train pool starts in seconds).

* Tables read from the cache are the built tables, bit for bit, so a simulator (and a fleet) built
  from them steps exactly as one built from the graphs.
* The key is what determines the tables: the scenario's content (not its path), the variant, the
  observation and the world layer's code.
* A damaged, edited, renamed or pickled entry is refused on one line and rebuilt, never used.
* A write that dies midway leaves no entry that a later process would trust.
* Entries no process reads any more can be pruned by last use (``python -m runners.cache``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from morality_gym.clitools import UserError, write_atomically
from morality_gym.envs import table_cache
from morality_gym.envs.batched import sim_tables
from morality_gym.envs.drawn import DrawnBatchedTrolleyEnv
from morality_gym.envs.registry import clear_graph_cache, parse_env_id
from morality_gym.envs.table_cache import TableCacheWarning, entry_key, scenario_digest
from runners import cache as cache_cli

POOL = ["Switch7-Human-v1", "PushOrSwitch-Animal-v1", "PushStandard-AnimalA-v1", "Push2OrSwitch-Robot-v1"]
ONE = "PushOrSwitch-Human-v1"
_SIM_ARRAYS = ("_next", "_reward", "_events", "_done", "_obs", "_utility", "_goal", "graph_offsets", "_start")


def _entry(folder: Path, env_id: str = ONE, obs_type: str = "compact") -> Path:
    scenario, variant = parse_env_id(env_id)
    return folder / f"{entry_key(scenario, variant, obs_type, np.float32, True)}.npz"


def _steps(env: DrawnBatchedTrolleyEnv, n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    env.reset()
    out = []
    for _ in range(n):
        res = env.step(rng.integers(0, 6, env.num_envs))
        out += [res.obs.copy(), res.reward.copy(), res.events.copy(), env.utility(res.transition).copy()]
    return out


@pytest.mark.parametrize("obs_type", ["compact", "flat"])
def test_a_simulator_from_cached_tables_is_the_built_one_bit_for_bit(tmp_path, obs_type: str) -> None:
    pool = POOL if obs_type == "compact" else ["PushOrSwitch-Human-v1", "PushOrSwitch-Animal-v1"]  # flat: one width
    built = DrawnBatchedTrolleyEnv([pool], 3, [5], obs_type=obs_type)
    first = DrawnBatchedTrolleyEnv([pool], 3, [5], obs_type=obs_type, table_cache=tmp_path)  # builds, writes
    assert len(list(tmp_path.glob("*.npz"))) == len(pool)
    clear_graph_cache()  # the second reads every table from the files, enumerating nothing
    cached = DrawnBatchedTrolleyEnv([pool], 3, [5], obs_type=obs_type, table_cache=tmp_path)
    for name in _SIM_ARRAYS:
        for env in (first, cached):
            got, want = getattr(env, name), getattr(built, name)
            assert got.dtype == want.dtype and np.array_equal(got, want), name
    for a, b in zip(_steps(built, 300), _steps(cached, 300)):
        np.testing.assert_array_equal(a, b)


def test_the_key_is_the_scenarios_content_variant_observation_and_world_code(tmp_path, monkeypatch) -> None:
    scenario, variant = parse_env_id(ONE)
    base = entry_key(scenario, variant, "compact", np.float32, True)
    assert scenario_digest(dataclasses.replace(scenario, source="/elsewhere/x.yaml", summary="other words")) == \
        scenario_digest(scenario)  # where the file lies changes nothing
    moved = dataclasses.replace(scenario, player_start=(scenario.player_start[0], scenario.player_start[1] + 1))
    assert entry_key(moved, variant, "compact", np.float32, True) != base
    assert entry_key(scenario, "Animal", "compact", np.float32, True) != base
    assert entry_key(scenario, variant, "flat", np.float32, True) != base
    assert entry_key(scenario, variant, "compact", np.float64, True) != base
    assert entry_key(scenario, variant, "flat", np.float32, False) != entry_key(scenario, variant, "flat", np.float32, True)
    monkeypatch.setattr(table_cache, "world_code_digest", lambda: "another version of the rules")
    assert entry_key(scenario, variant, "compact", np.float32, True) != base


def test_overrides_and_grid_rows_are_never_cached(tmp_path) -> None:
    sim_tables(ONE, "compact", np.float32, overrides=table_cache_overrides(), cache_dir=tmp_path)
    sim_tables(ONE, "grid", np.uint8, cache_dir=tmp_path)
    assert list(tmp_path.iterdir()) == []


def table_cache_overrides():  # an edited world: a user's, not a scenario's
    from morality_gym.envs.trolley import _overrides

    return _overrides({"player_start": [1, 1]})


def _tamper_array(path: Path) -> str:
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["next"] = arrays["next"].copy()
    arrays["next"][0] = (arrays["next"][0] + 1) % arrays["done"].shape[0]
    np.savez(path, **arrays)
    return "do not match their checksums"


def _truncate(path: Path) -> str:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return "not a readable table file"


def _pickled(path: Path) -> str:
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["obs"] = np.array([object()], dtype=object)
    np.savez(path, allow_pickle=True, **arrays)
    return "Object arrays cannot be loaded"


def _renamed(path: Path) -> str:
    other = _entry(path.parent, "PushOrSwitch-Animal-v1")
    other.replace(path)
    return "a renamed file"


def _forged_meta(path: Path) -> str:
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(bytes(arrays["meta_json"]).decode())
    arrays["next"] = arrays["next"] + arrays["done"].shape[0]  # out of the graph, with checksums to match
    meta["sha256"]["next"] = table_cache._array_digest(arrays["next"])
    arrays["meta_json"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    np.savez(path, **arrays)
    return "a transition leads outside"


@pytest.mark.parametrize("damage", [_tamper_array, _truncate, _pickled, _renamed, _forged_meta])
def test_a_wrong_or_tampered_entry_is_refused_and_rebuilt(tmp_path, damage) -> None:
    want = sim_tables(ONE, "compact", np.float32)
    sim_tables(ONE, "compact", np.float32, cache_dir=tmp_path)
    sim_tables("PushOrSwitch-Animal-v1", "compact", np.float32, cache_dir=tmp_path)
    path = _entry(tmp_path)
    why = damage(path)
    with pytest.warns(TableCacheWarning, match=why) as caught:
        got = sim_tables(ONE, "compact", np.float32, cache_dir=tmp_path)
    assert len(caught) == 1 and "\n" not in str(caught[0].message) and caught[0].filename == str(path)
    assert "building the tables again" in str(caught[0].message)
    for name in want._fields:
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the entry was rewritten: read now, without a word
        again = table_cache.read_entry(path, path.stem, np.float32)
    assert again is not None and np.array_equal(again.obs, want.obs)


def test_a_write_that_dies_midway_leaves_no_entry(tmp_path, monkeypatch) -> None:
    def dying(path, write, **kwargs):
        def half(fh):
            fh.write(b"PK\x03\x04 half an entry")
            raise KeyboardInterrupt

        return write_atomically(path, half, **kwargs)

    monkeypatch.setattr(table_cache, "write_atomically", dying)
    with pytest.raises(KeyboardInterrupt):
        sim_tables(ONE, "compact", np.float32, cache_dir=tmp_path)
    assert list(tmp_path.iterdir()) == []  # neither the entry nor its temporary file
    monkeypatch.undo()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sim_tables(ONE, "compact", np.float32, cache_dir=tmp_path)
    assert _entry(tmp_path).is_file()


def test_entries_are_listed_by_last_use_and_pruned_only_when_unused(tmp_path, capsys) -> None:
    """A read marks its entry used, so pruning by age removes what no fleet reads any more and keeps
    what one does, whatever code wrote it; the command says how much is this checkout's."""
    for env_id in (ONE, "Switch7-Human-v1"):
        sim_tables(env_id, "compact", np.float32, cache_dir=tmp_path)
    used, unused = _entry(tmp_path), _entry(tmp_path, "Switch7-Human-v1")
    month_ago = time.time() - 30 * 86400
    for path in (used, unused):
        os.utime(path, (month_ago, month_ago))
    (tmp_path / ".left-by-a-killed-writer.npz.123.abc.tmp").write_bytes(b"half")
    os.utime(tmp_path / ".left-by-a-killed-writer.npz.123.abc.tmp", (month_ago, month_ago))
    sim_tables(ONE, "compact", np.float32, cache_dir=tmp_path)  # read back: touched
    listed = table_cache.list_entries(tmp_path)
    assert [e.path for e in listed][-1] == used and len(listed) == 3
    assert all(e.this_code for e in listed if e.path.suffix == ".npz")
    assert [e.env_id for e in listed if e.path.suffix == ".npz"] == ["Switch7-Human-v1", ONE]

    assert cache_cli.main(["--dir", str(tmp_path), "--prune-unused-days", "14"]) == 0
    out = capsys.readouterr().out
    assert "3 entries" in out and "this checkout's world code: 2" in out and "removed 2 entries" in out, out
    assert used.is_file() and not unused.exists() and len(list(tmp_path.iterdir())) == 1
    with pytest.raises(UserError, match="no such folder"):
        cache_cli.main(["--dir", str(tmp_path / "nope")])
