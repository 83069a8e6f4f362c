"""Each run's own random streams: the torch generator that samples its actions and the numpy
``RandomState`` that shuffles its minibatches.

A fleet run must draw exactly what its single run would draw, in the same order, and nothing any
other run draws may change that. So every run owns the global RNG states its single-run learner left
behind after construction (SB3 seeds and then builds the policy), as private generators, and the
fleet never touches the global RNGs while it trains. Both generators live on the CPU: that is where
the single runs draw, so the bits are the same whatever device the fleet trains on.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th


class RunStreams:
    """The torch and numpy generators of ``n_runs`` runs, captured one run at a time by :meth:`capture`."""

    def __init__(self) -> None:
        self.torch: list[th.Generator] = []
        self.numpy: list[np.random.RandomState] = []

    def capture(self) -> None:
        """Take a copy of the global torch and numpy RNG states as the next run's own generators
        (called right after the run's single-run learner was built)."""
        gen = th.Generator(device="cpu")
        gen.set_state(th.get_rng_state())
        self.torch.append(gen)
        rng = np.random.RandomState()
        rng.set_state(np.random.get_state())
        self.numpy.append(rng)

    def __len__(self) -> int:
        return len(self.torch)

    def action_noise(self, shape: tuple[int, ...], device: th.device) -> th.Tensor:
        """Every run's exponential noise for a whole rollout, ``[K, *shape]`` on ``device``.

        ``torch.multinomial(probs, 1)`` (how ``Categorical.sample`` draws one action) is
        ``argmax(probs / q)`` with ``q = empty_like(probs).exponential_(1)`` on the caller's
        generator, element after element. Drawing a rollout's ``q`` in one call per run consumes
        each generator exactly as the rollout's per-step draws would (a test checks the actions
        against ``torch.multinomial``), and turns K sampling calls per step into one ``argmax``.
        Drawn on the CPU, where the generators live, then moved once per rollout.
        """
        return th.stack([th.empty(shape, device="cpu").exponential_(1, generator=g) for g in self.torch]).to(device)

    def permutation(self, k: int, size: int) -> np.ndarray:
        """Run ``k``'s next permutation of ``size`` transitions (its single run's ``np.random.permutation``)."""
        return self.numpy[k].permutation(size)

    def permutations(self, size: int, device: th.device) -> th.Tensor:
        """``[K, size]`` on ``device``: every run's next permutation."""
        return th.from_numpy(np.stack([self.permutation(k, size) for k in range(len(self))])).to(device)

    def state_dict(self) -> dict[str, Any]:
        """Every generator's state, as tensors and plain numbers (``torch.load(weights_only=True)`` reads it)."""
        return {"torch_generators": [g.get_state() for g in self.torch], "np_generators": [_random_state_dict(rng) for rng in self.numpy]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if len(state["torch_generators"]) != len(self) or len(state["np_generators"]) != len(self):
            raise ValueError(f"one generator per run expected ({len(self)} runs)")
        for gen, gen_state in zip(self.torch, state["torch_generators"]):
            gen.set_state(gen_state)
        for rng, rng_state in zip(self.numpy, state["np_generators"]):
            _load_random_state(rng, rng_state)


def _random_state_dict(rng: np.random.RandomState) -> dict[str, Any]:
    """A ``RandomState``'s Mersenne Twister state as a tensor and plain numbers."""
    name, keys, pos, has_gauss, gauss = rng.get_state(legacy=True)  # type: ignore[misc]
    return {"name": str(name), "keys": th.from_numpy(keys.astype(np.int64)), "pos": int(pos), "has_gauss": int(has_gauss),
            "gauss": float(gauss)}


def _load_random_state(rng: np.random.RandomState, state: dict[str, Any]) -> None:
    keys = state["keys"].numpy().astype(np.uint32)
    rng.set_state((state["name"], keys, int(state["pos"]), int(state["has_gauss"]), float(state["gauss"])))
