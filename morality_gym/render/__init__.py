"""Drawing a world state: ``ansi`` text (:mod:`.ansi`), ``rgb_array`` images (:mod:`.rgb`), a
``human`` window (:mod:`.window`), and GIFs of episodes (:mod:`.gif`).

The drawing modules sit below the envs: they take a :class:`~morality_gym.world.rules.World` and
a state, never an env, and the env (:meth:`~morality_gym.envs.trolley.TrolleyEnv.render`) owns
its window. :func:`~morality_gym.render.gif.record_episode` plays an episode in an env, so that
one module sits above the envs (docs/architecture.md).
"""

from __future__ import annotations

from morality_gym.render.ansi import render_ansi

__all__ = ["render_ansi"]
