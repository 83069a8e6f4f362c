"""Animated GIFs of episodes: the easiest way to show someone what an agent did.

:func:`write_gif` turns frames into a looping GIF; :func:`record_episode` plays one episode with a
policy and writes its GIF together with a summary of what happened. Files are written to a
temporary name in the target directory and renamed at the end, so an interrupted run never leaves
a truncated GIF behind under the real name (a later step would otherwise happily pick it up).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from morality_gym.clitools import write_atomically
from morality_gym.envs.trolley import TrolleyEnv
from morality_gym.evaluation.policies import step_actor
from morality_gym.render.rgb import render_rgb
from morality_gym.world.rules import ACTION_NAMES
from morality_gym.world.vocab import EVENTS, UTILITIES


def _as_image(frame: np.ndarray | Image.Image) -> Image.Image:
    if isinstance(frame, Image.Image):
        return frame.convert("RGB")
    array = np.asarray(frame)
    if array.dtype != np.uint8 or array.ndim != 3 or array.shape[2] != 3:
        raise ValueError(f"frames must be uint8 arrays of shape (H, W, 3), got {array.dtype} {array.shape}")
    return Image.fromarray(array, mode="RGB")


def write_gif(frames: Iterable[np.ndarray | Image.Image], path: str | os.PathLike[str], fps: float = 4) -> Path:
    """Write ``frames`` as a GIF that loops forever, atomically (temporary file, then rename).

    GIF stores delays in hundredths of a second, so ``fps`` is rounded to that. Note that
    identical consecutive frames are merged by the encoder into one longer frame (the total
    duration is kept); :func:`record_episode` captions every frame with its step so that each
    step stays a frame of its own.
    """
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps!r}")
    images = [_as_image(f) for f in frames]
    if not images:
        raise ValueError("write_gif needs at least one frame")
    sizes = {im.size for im in images}
    if len(sizes) > 1:
        raise ValueError(f"all frames must have the same size, got {sorted(sizes)}")
    target = Path(path)
    duration_ms = max(10, round(1000 / fps / 10) * 10)
    write_atomically(
        target,
        lambda fh: images[0].save(fh, format="GIF", save_all=True, append_images=images[1:], duration=duration_ms, loop=0),
    )
    return target


def _caption(step: int, action: int | None, reward: float, total: float) -> str:
    if action is None:
        return "step 0  start"
    return f"step {step}  {ACTION_NAMES[action]}  reward {reward:g}  return {total:g}"


def record_episode(
    env_id: str,
    policy: Any,
    path: str | os.PathLike[str],
    *,
    max_steps: int = 50,
    seed: int | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    fps: float = 4,
    cell_size: int = 48,
) -> dict[str, Any]:
    """Play one episode of ``env_id`` and write it as a GIF (initial frame included).

    ``policy``: ``None`` or ``"random"`` (uniform random actions from
    ``np.random.default_rng(seed)``), or any policy object the evaluators take (a callable
    ``obs -> action`` or ``obs -> 6 probabilities``, a table, an SB3 model; probabilities are
    sampled with the same seeded generator; a callable gets the flat observation). A reference as
    ``eval --policy`` takes it (a saved model's path, ``"file.py:function"``) is resolved first with
    ``load_policy(ref).policy`` of ``morality_gym.baselines.policy_ref``, as ``play --policy
    --render`` does: loading a saved model is the baselines' job, a layer above this one. The episode stops at termination, truncation or after
    ``max_steps`` steps. Returns ``{"env_id", "path", "steps", "return", "terminated", "truncated",
    "actions", "events", "utility", "frames"}`` where ``events`` lists every norm event that
    occurred (vocabulary order) and ``utility`` sums each harm count over the episode, so the
    episode can be replayed and checked.
    """
    kwargs = dict(env_kwargs or {})
    _check_arguments(policy, max_steps, kwargs)
    rng = np.random.default_rng(seed)
    act = step_actor(policy, rng)
    env = TrolleyEnv(env_id, render_mode="rgb_array", **kwargs)
    flat = env.graph.tables().obs if env.obs_type != "flat" else None
    try:
        obs, _info = env.reset(seed=seed)
        episode = _Episode(frames=[render_rgb(env.world, env.state, cell_size, caption=_caption(0, None, 0.0, 0.0))])
        while len(episode.actions) < max_steps and not (episode.terminated or episode.truncated):
            action = act(obs if flat is None else flat[env.state_id], env.state_id)
            obs, reward, episode.terminated, episode.truncated, info = env.step(action)
            episode.add(action, float(reward), info["norm_events"])
            episode.frames.append(
                render_rgb(
                    env.world, env.state, cell_size,
                    caption=_caption(len(episode.actions), action, float(reward), episode.total),
                )
            )
    finally:
        env.close()
    written = write_gif(episode.frames, path, fps=fps)
    return {
        "env_id": env.env_id,
        "path": str(written),
        "steps": len(episode.actions),
        "return": episode.total,
        "terminated": bool(episode.terminated),
        "truncated": bool(episode.truncated),
        "actions": episode.actions,
        "events": [name for name in EVENTS if name in episode.occurred],
        "utility": episode.utility,
        "frames": len(episode.frames),
    }


def _check_arguments(policy: Any, max_steps: Any, env_kwargs: Mapping[str, Any]) -> None:
    """:func:`record_episode`'s arguments, each refused with what to pass instead."""
    if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 0:
        raise ValueError(f"max_steps must be a non-negative int, got {max_steps!r}")
    if "render_mode" in env_kwargs:
        raise ValueError("record_episode renders rgb_array frames itself; do not pass render_mode in env_kwargs")
    if isinstance(policy, (str, os.PathLike)) and policy != "random":
        raise ValueError(f"record_episode takes a policy object or 'random', not the reference {str(policy)!r}: "
                         "resolve it first with load_policy(ref).policy from morality_gym.baselines.policy_ref")


@dataclass
class _Episode:
    """What :func:`record_episode` keeps of an episode as it plays: its frames, actions, return,
    the norm events that occurred and the summed harm counts."""

    frames: list[Any]
    actions: list[int] = field(default_factory=list)
    occurred: set[str] = field(default_factory=set)
    utility: dict[str, int] = field(default_factory=lambda: dict.fromkeys(UTILITIES, 0))
    total: float = 0.0
    terminated: bool = False
    truncated: bool = False

    def add(self, action: int, reward: float, norm_events: Mapping[str, Any]) -> None:
        """One step: its action, reward and norm events."""
        self.actions.append(action)
        self.total += reward
        self.occurred.update(norm_events["action"], norm_events["outcome"], norm_events["causal"])
        for name, value in norm_events["utility"].items():
            self.utility[name] += value


__all__ = ["record_episode", "write_gif"]
