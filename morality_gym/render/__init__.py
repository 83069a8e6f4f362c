"""Rendering of environment states: ``ansi`` text, ``rgb_array`` images, a ``human`` window, GIFs."""

from __future__ import annotations

from typing import Any

from morality_gym.render.ansi import render_ansi


def render_env(env: Any) -> Any:
    """Render a :class:`~morality_gym.envs.trolley.TrolleyEnv` according to its ``render_mode``."""
    mode = env.render_mode
    if mode is None:
        import gymnasium

        gymnasium.logger.warn("render() called without a render_mode; pass render_mode='ansi', 'rgb_array' or 'human'")
        return None
    if mode == "ansi":
        return render_ansi(env.world, env.state, colour=False)
    from morality_gym.render.rgb import render_rgb

    frame = render_rgb(env.world, env.state)
    if mode == "rgb_array":
        return frame
    from morality_gym.render.window import show_frame

    env._renderer = show_frame(frame, env._renderer, title=env.env_id)
    return None


__all__ = ["render_env", "render_ansi"]
