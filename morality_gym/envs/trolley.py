"""The Gymnasium environment: a thin shell over the memoised state graph of one scenario variant.

All rules live in :mod:`morality_gym.world.rules`; this class only keeps the episode's position
in the graph (state id and step counter), applies truncation, and packages what the graph
memoised into Gymnasium's ``(obs, reward, terminated, truncated, info)``. A step is therefore a
couple of list lookups, which is what makes the environments fast enough to train on.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, ClassVar, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.envs.registration import EnvSpec
from gymnasium.error import ResetNeeded

from morality_gym.constants import MAX_STEPS
from morality_gym.envs.registry import DEFAULT_MAX_STEPS, parse_env_id, state_graph  # DEFAULT_MAX_STEPS: re-exported
from morality_gym.render.ansi import render_ansi
from morality_gym.render.rgb import render_rgb
from morality_gym.render.window import show_frame
from morality_gym.world.graph import EMPTY_NORM_EVENTS, StateGraph, norm_events_dict
from morality_gym.world.grid_observe import GridCodec
from morality_gym.world.rules import ACTION_NAMES, Overrides

OBS_TYPES = ("flat", "dict", "dict_flat", "grid")
_OBS_ALIASES = {"flat": "flat", "np.ndarray": "flat", "dict": "dict", "dict_flat": "dict_flat", "grid": "grid"}
#: What a pickled or copied env leaves out and rebuilds: the memoised graph is shared by every env
#: of the same world (and holds a lock), the renderer may hold a window.
_REBUILT = ("graph", "world", "codec", "_edges", "_renderer", "_sid", "_grid_codec", "_grids")


class InvalidActionError(ValueError):
    """An action outside ``Discrete(6)``."""


def _overrides(value: Mapping[str, Any] | Overrides | None) -> Overrides | None:
    if value is None or isinstance(value, Overrides):
        return value
    allowed = {"player_start", "character_starts"}
    unknown = set(value) - allowed
    if unknown:
        raise ValueError(f"unknown override keys {sorted(unknown)}; allowed: {sorted(allowed)}")
    player = value.get("player_start")
    chars = value.get("character_starts")
    return Overrides(
        player_start=tuple(player) if player is not None else None,  # type: ignore[arg-type]
        character_starts=tuple(sorted((k, tuple(v)) for k, v in chars.items())) if chars else None,  # type: ignore[arg-type]
    )


class TrolleyEnv(gym.Env[Any, int]):
    """A MoralityGym trolley dilemma (every scenario; see the per-scenario classes for layouts).

    ## Description
    A grid world with rails, switches, levers, trolleys and groups of humans, animals and robots.
    The agent must walk to the landmark ``G``; on its way it can pull levers that set switches and
    push bystanders onto the rails. Trolleys move one rail cell per step from the first step and
    stop at the first group they hit, harming it. What the agent does (or fails to do) is reported
    as *norm events* that morality chains turn into a morality metric.

    ## Action Space
    ``Discrete(6)``: 0 UP, 1 DOWN, 2 LEFT, 3 RIGHT, 4 STAY, 5 INTERACT (toggle every adjacent
    lever and push every adjacent pushable character one cell away from the agent). Moves into
    walls or off the grid do nothing. Python ints and numpy integers are accepted; anything else
    raises :class:`InvalidActionError`.

    ## Observation Space
    ``obs_type="flat"`` (default): the reference's flat ``float64`` vector. Per entity, in order:
    player ``pos`` (row/H, col/W), ``is_harmed``, ``is_terminated``; each lever's state one-hot;
    each character's ``pos``, ``is_harmed``, ``amount`` (the raw group size), type one-hot; each
    trolley's ``pos``, ``is_harmed``, ``is_actable``. ``obs_type="dict"``: the same numbers as
    ``{entity: {component: array}}`` (the reference's nesting). ``obs_type="dict_flat"``: the same
    numbers as one level ``{"entity/component": array}`` (``player/pos``, ``lever_1/curr_state``,
    ...), the form Stable-Baselines3's ``MultiInputPolicy`` accepts (it refuses nested Dict spaces;
    ``/`` because it keeps a torch module per key and torch forbids ``.`` in their names). ``normalise_obs=False`` gives raw integer positions.
    ``obs_type="grid"``: one fixed shape for every scenario, built-in, user or generated, so that one
    policy can act in all of them: a ``uint8`` array ``(channels, 16, 16)``, the scenario's grid
    padded with zeros, one channel per kind of thing (walls, rails by direction, levers, agent,
    trolleys, groups by type and size, ...; :mod:`morality_gym.world.grid_observe` lists them).

    ## Rewards
    ``step`` per step (-1), ``landmark`` when the landmark is first entered (+100, wins over harm in
    the same step), ``agent_harmed`` when the agent is harmed (-100 or -200, also after the landmark),
    0 on the other steps after the agent has stopped, 0 after the episode has ended.

    ## Termination
    ``terminated`` when the agent has stopped (reached the landmark or been harmed) and every
    trolley has stopped (end of line or collision). ``truncated`` on step ``max_steps + 1``
    (200 by default, as in every run of the paper; ``None`` never truncates, as the reference's
    default). Further steps after either flag change nothing.

    ## Info
    ``norm_events``: this step's ``action``, ``outcome`` and ``causal`` event names (frozensets) and
    ``utility`` (harm counts; empty when nothing was harmed); ``termination_statuses`` of the agent
    and each trolley; ``goal_reached`` (1 on the step the landmark is reached).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array", "ansi"], "render_fps": 4}

    #: Set by the per-scenario subclasses created in :mod:`morality_gym.envs.registration`.
    scenario_name: str | None = None

    def __init__(
        self,
        env_id: str | None = None,
        *,
        variant: str | None = None,
        max_steps: int | None = MAX_STEPS,
        obs_type: str = "flat",
        normalise_obs: bool = True,
        render_mode: str | None = None,
        overrides: Mapping[str, Any] | Overrides | None = None,
    ) -> None:
        if env_id is None:
            if self.scenario_name is None or variant is None:
                raise TypeError("give an env id, e.g. TrolleyEnv('SwitchStandard-HumanA-v1')")
            env_id = f"{self.scenario_name}-{variant}-v1"
        scenario, variant = parse_env_id(env_id)
        if obs_type not in _OBS_ALIASES:
            raise ValueError(f"obs_type must be one of {OBS_TYPES}, got {obs_type!r}")
        if max_steps is not None and (isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 0):
            raise ValueError(f"max_steps must be a non-negative int or None, got {max_steps!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")

        self.env_id = scenario.env_id(variant)
        self.normalise_obs = normalise_obs
        self.overrides = _overrides(overrides)
        self.scenario = scenario
        self.variant = variant
        self.max_steps = max_steps
        self.obs_type = _OBS_ALIASES[obs_type]
        self.render_mode = render_mode
        self._attach_graph()

        self.action_space = spaces.Discrete(6)
        self.observation_space = {"flat": self.codec.flat_space, "dict": self.codec.dict_space,
                                  "dict_flat": self.codec.flat_dict_space, "grid": GridCodec.space}[self.obs_type]()
        self._limit = math.inf if max_steps is None else max_steps
        self._sid = 0
        self._t = 0
        self._done: bool | None = None  # None until the first reset(): step() refuses to run before it
        self._terminated = False
        self._truncated = False
        self._goal = 0
        self._renderer: Any = None

    def _attach_graph(self) -> None:
        """Use the (per-process, shared) memoised state graph of this env's world."""
        self.graph: StateGraph = state_graph(self.env_id, self.overrides, self.normalise_obs)
        self.world = self.graph.world
        self.codec = self.graph.codec
        self._edges = self.graph.edges
        #: The grid observation's encoder (``obs_type="grid"`` only) and the grids met so far, by state id.
        self._grid_codec = GridCodec(self.world) if self.obs_type == "grid" else None
        self._grids: dict[int, np.ndarray] = {}

    # ------------------------------------------------------------------ spec, pickling, copying
    @property  # type: ignore[override]
    def spec(self) -> EnvSpec | None:
        """The spec ``gym.make`` gave this env, with ``max_episode_steps`` saying when it truncates.

        The env truncates by itself (on step ``max_steps + 1``, as the reference), so the
        registered spec has no limit: a ``TimeLimit`` from the registry would also cut episodes
        that ``max_steps=None`` asks to run on. The made env's spec tells the truth instead, so
        that tools reading ``env.spec.max_episode_steps`` (SB3, rl-zoo, ``EnvSpec.make``) see it.
        """
        return self._spec

    @spec.setter
    def spec(self, value: EnvSpec | None) -> None:
        if value is not None:
            value = dataclasses.replace(value, max_episode_steps=None if self.max_steps is None else self.max_steps + 1)
        self._spec = value

    _spec: EnvSpec | None = None

    def __getstate__(self) -> dict[str, Any]:
        """Everything but the shared graph; the episode's position is kept as the kernel state.

        Pickling is how vector envs, process pools and checkpoints hand an env around. State ids
        are local to a process's graph (it grows in the order states are first met), so the
        state itself travels and is interned again by :meth:`__setstate__`.
        """
        state = {k: v for k, v in self.__dict__.items() if k not in _REBUILT}
        state["_kernel_state"] = self.graph.states[self._sid]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        state = dict(state)
        kernel = state.pop("_kernel_state")
        self.__dict__.update(state)
        self._attach_graph()
        self._sid = self.graph.intern(kernel)
        self._renderer = None

    # ------------------------------------------------------------------ Gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        """Start a new episode; the start state is the same for every seed (docs/protocols.md#seeds-have-no-effect)."""
        super().reset(seed=seed)
        self._sid = 0
        self._t = 0
        self._done = self._terminated = self._truncated = False
        self._goal = 0
        if self.render_mode == "human":
            self.render()
        return self._observation(0), {
            "norm_events": norm_events_dict(EMPTY_NORM_EVENTS),
            "termination_statuses": dict(self.graph.statuses[0]),
            "goal_reached": 0,
        }

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        if action.__class__ is not int or not 0 <= action < 6:
            action = self._coerce(action)
        if self._done:
            return self._observation(self._sid), 0.0, self._terminated, self._truncated, {
                "norm_events": norm_events_dict(EMPTY_NORM_EVENTS),
                "termination_statuses": dict(self.graph.statuses[self._sid]),
                "goal_reached": self._goal,
            }
        if self._done is None:  # gym.make's OrderEnforcing says so too; a raw env must not step silently
            raise ResetNeeded(f"{self.env_id}: call reset() before step(): an episode starts with reset()")
        edge = self._edges[self._sid][action] or self.graph.edge(self._sid, action)
        self._sid = edge.next
        self._t += 1
        truncated = self._t > self._limit
        if edge.terminated or truncated:
            self._done = True
            self._terminated = edge.terminated
            self._truncated = truncated
            self._goal = edge.goal
        if self.render_mode == "human":
            self.render()
        action_ev, outcome_ev, causal_ev, utility = edge.norm_events
        return (
            edge.obs.copy() if self.obs_type == "flat" else self._observation(edge.next),
            edge.reward,
            edge.terminated,
            truncated,
            {
                "norm_events": {"action": action_ev, "outcome": outcome_ev, "causal": causal_ev, "utility": dict(utility)},
                "termination_statuses": dict(edge.statuses),
                "goal_reached": edge.goal,
            },
        )

    def render(self) -> Any:
        """``ansi``: the ASCII picture; ``rgb_array``: an image; ``human``: shown in a window.

        The env owns its renderer: :mod:`morality_gym.render` draws a world state and knows
        nothing of envs; the window a ``human`` env draws into is kept here (``self._renderer``)
        and closed by :meth:`close`.
        """
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='ansi', 'rgb_array' or 'human'")
            return None
        if self.render_mode == "ansi":
            return render_ansi(self.world, self.state, colour=False)
        frame = render_rgb(self.world, self.state)
        if self.render_mode == "rgb_array":
            return frame

        self._renderer = show_frame(frame, self._renderer, title=self.env_id)
        return None

    def close(self) -> None:
        if self._renderer is not None and hasattr(self._renderer, "close"):
            self._renderer.close()
        self._renderer = None

    # ------------------------------------------------------------------ helpers
    def _coerce(self, action: Any) -> int:
        if isinstance(action, (int, np.integer)) and not isinstance(action, (bool, np.bool_)):
            value = int(action)
            if 0 <= value < 6:
                return value
        elif isinstance(action, np.ndarray) and action.shape in ((), (1,)) and np.issubdtype(action.dtype, np.integer):
            return self._coerce(action.reshape(()).item())
        names = ", ".join(f"{i}={n}" for i, n in enumerate(ACTION_NAMES))
        raise InvalidActionError(f"invalid action {action!r} for {self.env_id}: expected an integer in 0..5 ({names})")

    def _observation(self, sid: int) -> Any:
        if self.obs_type == "flat":
            return self.graph.obs[sid].copy()
        if self.obs_type == "dict_flat":
            return self.codec.as_flat_dict(self.graph.obs[sid])
        if self._grid_codec is not None:
            grid = self._grids.get(sid)
            if grid is None:
                grid = self._grids[sid] = self._grid_codec.encode(self.graph.states[sid])
            return grid.copy()
        return self.codec.as_dict(self.graph.states[sid])

    # ------------------------------------------------------------------ introspection
    @property
    def state(self) -> tuple:
        """The kernel state of the current step (hashable; see :mod:`morality_gym.world.rules`)."""
        return self.graph.states[self._sid]

    @property
    def state_id(self) -> int:
        """The id of the current state in the shared :class:`~morality_gym.world.graph.StateGraph`."""
        return self._sid

    @property
    def elapsed_steps(self) -> int:
        return self._t

    def ascii(self) -> str:
        return render_ansi(self.world, self.state, colour=False)

    def __repr__(self) -> str:
        return f"<TrolleyEnv {self.env_id} max_steps={self.max_steps} obs_type={self.obs_type}>"


__all__ = ["DEFAULT_MAX_STEPS", "InvalidActionError", "TrolleyEnv"]
