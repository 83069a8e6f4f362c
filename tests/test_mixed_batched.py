"""A simulator hosting copies of different variants steps each copy exactly as its own simulator.

The yardstick is :class:`BatchedTrolleyEnv` (itself tested against the single environment), one
per env id, driven with the same actions: a mixed simulator must be nothing but their concatenation.
"""

from __future__ import annotations

import numpy as np
import pytest

from morality_gym import BatchedTrolleyEnv
from morality_gym.envs.mixed import MixedBatchedTrolleyEnv

IDS = ["PushOrSwitch-Human-v1", "PushOrSwitch-Animal-v1", "PushOrSwitch-HumanRobotA-v1"]


@pytest.mark.parametrize("autoreset", ["same_step", "disabled"])
def test_mixed_simulator_is_the_concatenation_of_single_id_simulators(autoreset: str) -> None:
    per_id = 3
    layout = [e for e in IDS for _ in range(per_id)][::-1]  # copies of one id not all adjacent
    layout = layout[1::2] + layout[0::2]
    mixed = MixedBatchedTrolleyEnv(layout, max_steps=20, autoreset=autoreset)
    singles = {e: BatchedTrolleyEnv(e, layout.count(e), max_steps=20, autoreset=autoreset) for e in IDS}
    where = {e: np.flatnonzero(np.array(layout) == e) for e in IDS}
    rng = np.random.default_rng(5)

    def check(obs: np.ndarray, parts: dict[str, np.ndarray]) -> None:
        for e in IDS:
            np.testing.assert_array_equal(obs[where[e]], parts[e])

    check(mixed.reset(), {e: s.reset() for e, s in singles.items()})
    ended_any = 0
    for t in range(300):
        actions = rng.integers(0, 6, size=len(layout))
        res = mixed.step(actions)
        for e, s in singles.items():
            ref = s.step(actions[where[e]])
            idx = where[e]
            np.testing.assert_array_equal(res.obs[idx], ref.obs)
            np.testing.assert_array_equal(res.reward[idx], ref.reward)
            np.testing.assert_array_equal(res.terminated[idx], ref.terminated)
            np.testing.assert_array_equal(res.truncated[idx], ref.truncated)
            np.testing.assert_array_equal(res.events[idx], ref.events)
            np.testing.assert_array_equal(mixed.utility(res.transition)[idx], s.utility(ref.transition))
            np.testing.assert_array_equal(mixed.goal_reached(res.transition)[idx], s.goal_reached(ref.transition))
            if autoreset == "same_step" and ref.final_obs is not None:
                assert res.final_obs is not None
                np.testing.assert_array_equal(res.final_obs[idx], ref.final_obs)
        ended_any += int((res.terminated | res.truncated).sum())
        if autoreset == "disabled" and t % 7 == 6:
            mask = rng.random(len(layout)) < 0.5
            obs = mixed.reset(mask)
            check(obs, {e: s.reset(mask[where[e]]) for e, s in singles.items()})
    assert ended_any > 20  # the run crossed many episode ends


def test_mixed_simulator_refuses_scenarios_of_different_observation_sizes() -> None:
    with pytest.raises(ValueError, match="share an observation size"):
        MixedBatchedTrolleyEnv(["PushOrSwitch-Human-v1", "Switch7-Human-v1"])


def test_mixed_simulator_pads_observations_of_different_sizes_when_asked() -> None:
    ids = ["PushOrSwitch-Human-v1", "Switch7-Human-v1"]
    mixed = MixedBatchedTrolleyEnv(ids, pad_obs=True)
    assert mixed.obs_dims == {"PushOrSwitch-Human-v1": 31, "Switch7-Human-v1": 63} and mixed.obs_dim == 63
    obs = mixed.reset()
    for i, env_id in enumerate(ids):
        alone = MixedBatchedTrolleyEnv([env_id]).reset()[0]
        np.testing.assert_array_equal(obs[i, : len(alone)], alone)
        assert not obs[i, len(alone):].any()


def test_one_env_id_is_a_mixture_of_one_sharing_its_graphs_tables() -> None:
    """The simulator is built once, for the general case: a simulator of one env id is a mixture
    of one (the same layout attributes, its starts in one graph) whose tables are the graph's own
    arrays, not copies, whichever class builds it; a mixture does not build a simulator of its
    first id and then replace its tables."""
    single = BatchedTrolleyEnv("PushOrSwitch-Human-v1", 3, max_steps=20)
    mixture = MixedBatchedTrolleyEnv(["PushOrSwitch-Human-v1"] * 3, max_steps=20)
    for sim in (single, mixture):
        assert sim.env_ids == ["PushOrSwitch-Human-v1"] * 3 and sim.unique_env_ids == ["PushOrSwitch-Human-v1"]
        np.testing.assert_array_equal(sim.copy_graph, [0, 0, 0])
        np.testing.assert_array_equal(sim.graph_offsets, [0])
        assert sim.obs_dims == {"PushOrSwitch-Human-v1": sim.obs_dim}
    for table in ("_next", "_events", "_done"):
        assert np.shares_memory(getattr(single, table), getattr(mixture, table)), table
    with pytest.raises(ValueError, match="at least one env id"):
        MixedBatchedTrolleyEnv("PushOrSwitch-Human-v1")  # type: ignore[arg-type]
