"""Drawing a world state: ``ansi`` text (:mod:`.ansi`), ``rgb_array`` images (:mod:`.rgb`) and a
``human`` window (:mod:`.window`).

The drawing modules sit below the envs: they take a :class:`~morality_gym.world.rules.World` and
a state, never an env, and the env (:meth:`~morality_gym.envs.trolley.TrolleyEnv.render`) owns
its window. GIFs of episodes play a policy in an env, so they live where their imports say, with
the evaluators: :mod:`morality_gym.evaluation.gif` (docs/architecture.md).
"""

from __future__ import annotations

from morality_gym.render.ansi import render_ansi

__all__ = ["render_ansi"]
