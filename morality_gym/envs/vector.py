"""Vectorised faces of the batched simulator: a Gymnasium ``VectorEnv`` and an SB3 ``VecEnv``.

Both wrap :class:`~morality_gym.envs.batched.BatchedTrolleyEnv`, so N copies step as a few array
operations instead of N Python calls. They report a step's norm events compactly: ``events`` is a
bit mask over :data:`morality_gym.world.vocab.EVENTS` (decode with
:func:`morality_gym.world.vocab.mask_to_names`) and ``transition`` indexes the graph tables for
utilities. :class:`morality_gym.norms.wrappers.VecMoralityWrapper` turns these into ``info["cost"]``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from morality_gym.constants import MAX_STEPS
from morality_gym.envs.batched import BatchedTrolleyEnv, BatchStep
from morality_gym.world.compact_observe import compact_space
from morality_gym.world.observe import flat_key


class TrolleyVectorEnv(VectorEnv):
    """Gymnasium ``VectorEnv`` over the batched simulator (``gymnasium.make_vec(..., vectorization_mode="vector_entry_point")``).

    ``obs_type`` ``flat`` (default) or ``dict_flat`` (``{"entity/component": rows}``, the dict SB3's
    ``MultiInputPolicy`` takes). Supports all three Gymnasium autoreset modes. ``infos`` holds ``events`` (uint32 masks),
    ``goal_reached`` and ``transition`` per copy; in ``SAME_STEP`` mode (the default) a copy that
    ended in the step has them in ``final_info`` and its last observation in ``final_obs``, as
    Gymnasium's own vector envs do.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": [], "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(
        self,
        env_id: str,
        num_envs: int = 1,
        *,
        max_steps: int | None = MAX_STEPS,
        autoreset_mode: str | AutoresetMode = AutoresetMode.SAME_STEP,
        obs_dtype: type = np.float32,
        obs_type: str = "flat",
        normalise_obs: bool = True,
        overrides: dict | None = None,
        render_mode: str | None = None,
    ) -> None:
        if obs_type not in ("flat", "np.ndarray", "dict_flat"):
            raise ValueError(f"the vectorised env gives obs_type='flat' or 'dict_flat', not {obs_type!r}; for the nested "
                             "'dict' use gym.make_vec(..., vectorization_mode='sync') or 'async'")
        if render_mode is not None:
            raise ValueError("the vectorised env does not render; use TrolleyEnv for pictures")
        self.autoreset_mode = AutoresetMode(autoreset_mode) if not isinstance(autoreset_mode, AutoresetMode) else autoreset_mode
        self.metadata = {**self.metadata, "autoreset_mode": self.autoreset_mode}
        self.batch = BatchedTrolleyEnv(
            env_id,
            num_envs,
            max_steps=max_steps,
            obs_dtype=obs_dtype,
            autoreset="same_step" if self.autoreset_mode == AutoresetMode.SAME_STEP else "disabled",
            normalise_obs=normalise_obs,
            overrides=overrides,
        )
        self.num_envs = num_envs
        codec = self.batch.graph.codec
        self.obs_type = "dict_flat" if obs_type == "dict_flat" else "flat"
        self._fields = [(flat_key(f), slice(f.offset, f.offset + f.width)) for f in codec.fields]
        self.single_observation_space = codec.flat_space(obs_dtype) if self.obs_type == "flat" else codec.flat_dict_space(obs_dtype)
        self.single_action_space = spaces.Discrete(6)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, num_envs)
        self.action_space = spaces.MultiDiscrete(np.full(num_envs, 6))
        self.render_mode = None
        self._pending = np.zeros(num_envs, dtype=bool)
        self._ones = np.ones(num_envs, dtype=bool)
        self.spec = None

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset the copies (all, or ``options["reset_mask"]``); the start state does not depend on the seed."""
        if seed is not None:
            self.action_space.seed(seed if isinstance(seed, int) else next((s for s in seed if s is not None), None))
        mask = None if options is None else options.get("reset_mask")
        obs = self.batch.reset(mask)
        if mask is None:
            self._pending[:] = False
        else:
            self._pending[mask] = False
        return self._shaped(obs), {}

    def _shaped(self, obs: np.ndarray) -> Any:
        """``obs`` (rows of flat observations, or one) as the observation type asked for: the
        array itself, or ``{"entity/component": columns}`` for ``dict_flat``."""
        if self.obs_type == "flat":
            return obs
        return {key: obs[..., cut] for key, cut in self._fields}

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        actions = np.asarray(actions)
        res = self.batch.step(actions)
        obs, reward, terminated, truncated, events = res.obs, res.reward, res.terminated, res.truncated, res.events
        infos: dict[str, Any] = {
            "events": events,
            "_events": self._ones,
            "goal_reached": self.batch.goal_reached(res.transition),
            "_goal_reached": self._ones,
            "transition": res.transition,
            "_transition": self._ones,
        }
        if self.autoreset_mode == AutoresetMode.SAME_STEP and res.final_obs is not None:
            # Gymnasium's same-step convention: an ended copy's last observation and step info go to
            # final_obs / final_info; its top-level info is the (empty) reset info.
            ended = terminated | truncated
            final = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(ended):
                final[i] = self._shaped(res.final_obs[i])
            live = ~ended
            infos["final_obs"] = final
            infos["_final_obs"] = ended
            infos["final_info"] = {
                "events": np.where(ended, events, np.uint32(0)),
                "_events": ended,
                "goal_reached": infos["goal_reached"] & ended,
                "_goal_reached": ended,
                "transition": np.where(ended, res.transition, self.batch.no_transition),
                "_transition": ended,
            }
            infos["_final_info"] = ended
            infos["events"] = np.where(live, events, np.uint32(0))
            infos["_events"] = live
            infos["goal_reached"] = infos["goal_reached"] & live
            infos["_goal_reached"] = live
            infos["transition"] = np.where(live, res.transition, self.batch.no_transition)
            infos["_transition"] = live
        elif self.autoreset_mode == AutoresetMode.NEXT_STEP:
            pending = self._pending
            if pending.any():
                obs = self.batch.reset(pending)
                reward = np.where(pending, np.float32(0), reward)
                terminated = terminated & ~pending
                truncated = truncated & ~pending
                infos["events"] = np.where(pending, np.uint32(0), events)
                # Nothing happened to a copy that was reset in this step: no landmark either.
                infos["goal_reached"] = np.where(pending, False, infos["goal_reached"])
            self._pending = terminated | truncated
        return self._shaped(obs), reward, terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        return None


class TrolleyVecEnv(VecEnv):
    """Stable-Baselines3 ``VecEnv`` over the batched simulator (same-step auto-reset, like SB3's own).

    ``obs_type="compact"`` gives the compact observation (:mod:`morality_gym.world.compact_observe`),
    the one the generalisation track's fleets train on. Each step's ``infos[i]`` holds ``events`` (int mask), ``goal_reached`` and ``transition``; ended
    copies also get ``terminal_observation`` and ``TimeLimit.truncated`` as SB3 expects.
    ``last_step`` keeps the whole :class:`~morality_gym.envs.batched.BatchStep` so wrappers can
    work on arrays instead of the info dicts.
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        *,
        max_steps: int | None = MAX_STEPS,
        obs_dtype: type = np.float32,
        normalise_obs: bool = True,
        overrides: dict | None = None,
        obs_type: str = "flat",
    ) -> None:
        if obs_type not in ("flat", "compact"):
            raise ValueError(f"the SB3 vectorised env gives obs_type='flat' or 'compact', not {obs_type!r}")
        self.batch = BatchedTrolleyEnv(
            env_id,
            num_envs,
            max_steps=max_steps,
            obs_dtype=obs_dtype,
            autoreset="same_step",
            normalise_obs=normalise_obs,
            overrides=overrides,
            obs_type=obs_type,
        )
        self.env_id = self.batch.env_id
        space = self.batch.graph.codec.flat_space(obs_dtype) if obs_type == "flat" else compact_space()
        super().__init__(num_envs, space, spaces.Discrete(6))
        self._actions: np.ndarray | None = None
        self.last_step: BatchStep | None = None

    def reset(self) -> np.ndarray:
        obs = self.batch.reset()
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        actions = np.asarray(actions)
        if actions.shape in ((self.num_envs, 1), () if self.num_envs == 1 else (self.num_envs, 1)):
            actions = actions.reshape(self.num_envs)  # SB3 may hand over (n, 1); (2, 2) for 4 copies is refused
        # No cast here: BatchedTrolleyEnv.step rejects non-integer dtypes, wrong shapes and values
        # outside 0..5 (a cast would silently turn 2.5 into 2).
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        res = self.batch.step(self._actions)
        self._actions = None
        self.last_step = res
        ended = res.terminated | res.truncated
        goal = self.batch.goal_reached(res.transition)
        infos: list[dict[str, Any]] = [
            {"events": int(e), "goal_reached": int(g), "transition": int(k)}
            for e, g, k in zip(res.events.tolist(), goal.tolist(), res.transition.tolist())
        ]
        if res.final_obs is not None:
            for i in np.flatnonzero(ended):
                infos[i]["terminal_observation"] = res.final_obs[i]
                infos[i]["TimeLimit.truncated"] = bool(res.truncated[i] and not res.terminated[i])
        return res.obs, res.reward, ended, infos

    def close(self) -> None:
        return None

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        value = getattr(self.batch, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        raise AttributeError("the copies of a batched env share one simulator; attributes cannot differ per copy")

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any) -> list[Any]:
        raise AttributeError(f"the batched env has no per-copy method {method_name!r}")

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seeds have no effect on these deterministic worlds (docs/protocols.md#seeds-have-no-effect); kept for the SB3 API."""
        return super().seed(seed)
