"""Adam and gradient clipping for parameters stacked along a leading run axis.

Each run of a fleet owns slice ``k`` of every stacked tensor (shape ``[K, ...]``). The runs are
independent trainings, so everything here is per slice: :class:`BatchedAdam` keeps per-run step
counts and moments and takes, on each slice, exactly the arithmetic of ``torch.optim.Adam``'s
single-tensor path (the one PyTorch uses on CPU), with a per-run learning rate and a per-run mask
(a masked run's parameters, moments and step count stay untouched, e.g. a PPO-Lag run whose KL
early stop fired while the others continue). :func:`clip_grad_norm` is ``clip_grad_norm_`` with
each run clipped by its own norm. A test compares both with the PyTorch originals slice by slice.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch as th


def _per_run(values: np.ndarray, like: th.Tensor) -> th.Tensor:
    """A ``[K]`` array as a tensor that broadcasts against ``like`` (``[K, 1, ...]``), in its dtype."""
    return th.as_tensor(values, dtype=like.dtype).reshape((-1,) + (1,) * (like.dim() - 1))


class BatchedAdam:
    """``torch.optim.Adam`` (no weight decay, no amsgrad) for ``K`` runs at once.

    :param params: stacked tensors ``[K, ...]`` updated in place (leaf tensors; the update runs
        under ``no_grad``).
    :param eps: Adam's ``eps`` (PyTorch's default 1e-8; SB3's policies pass 1e-5).
    """

    def __init__(self, params: Sequence[th.Tensor], n_runs: int, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8) -> None:
        self.params = list(params)
        self.n_runs = n_runs
        self.beta1, self.beta2 = float(betas[0]), float(betas[1])
        self.eps = float(eps)
        self.steps = np.zeros(n_runs, dtype=np.int64)
        self.exp_avg = [th.zeros_like(p) for p in self.params]
        self.exp_avg_sq = [th.zeros_like(p) for p in self.params]

    @th.no_grad()
    def step(self, grads: Sequence[th.Tensor], lr: np.ndarray | float, mask: np.ndarray | None = None) -> None:
        """One Adam step of every run (or of the runs where ``mask`` is true) with per-run ``lr``."""
        lr = np.broadcast_to(np.asarray(lr, dtype=np.float64), (self.n_runs,))
        active = np.ones(self.n_runs, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        if not active.any():
            return
        steps = self.steps + active
        # As torch: the bias corrections are Python floats (float64) from the step count; the step
        # size and sqrt(bias_correction2) enter the float32 kernels as scalars, i.e. rounded to float32.
        bc1 = 1.0 - self.beta1 ** np.maximum(steps, 1).astype(np.float64)
        bc2_sqrt = (1.0 - self.beta2 ** np.maximum(steps, 1).astype(np.float64)) ** 0.5
        step_size = lr / bc1
        everyone = bool(active.all())
        for i, (p, g) in enumerate(zip(self.params, grads)):
            m, v = self.exp_avg[i], self.exp_avg_sq[i]
            new_m = m.lerp(g, 1 - self.beta1)
            new_v = (v * self.beta2).addcmul_(g, g, value=1 - self.beta2)
            denom = (new_v.sqrt() / _per_run(bc2_sqrt, p)).add_(self.eps)
            new_p = p - _per_run(step_size, p) * new_m / denom
            if everyone:
                m.copy_(new_m)
                v.copy_(new_v)
                p.copy_(new_p)
            else:
                keep = _per_run(active, p).bool()
                m.copy_(th.where(keep, new_m, m))
                v.copy_(th.where(keep, new_v, v))
                p.copy_(th.where(keep, new_p, p))
        self.steps = steps

    def state_of(self, k: int) -> list[dict[str, th.Tensor]]:
        """Run ``k``'s Adam state per parameter, as ``torch.optim.Adam.state`` holds it."""
        return [
            {"step": th.tensor(float(self.steps[k])), "exp_avg": m[k].clone(), "exp_avg_sq": v[k].clone()}
            for m, v in zip(self.exp_avg, self.exp_avg_sq)
        ]

    def load_state_of(self, k: int, states: Sequence[dict[str, th.Tensor]]) -> None:
        """Set run ``k``'s state from ``torch.optim.Adam.state`` entries (same parameter order)."""
        steps = {int(s["step"]) for s in states if "step" in s}
        if len(steps) > 1:
            raise ValueError(f"Adam state of run {k} has differing step counts {sorted(steps)}")
        self.steps[k] = steps.pop() if steps else 0
        with th.no_grad():
            for m, v, s in zip(self.exp_avg, self.exp_avg_sq, states):
                m[k] = s["exp_avg"] if "exp_avg" in s else 0.0
                v[k] = s["exp_avg_sq"] if "exp_avg_sq" in s else 0.0


def run_norms(grads: Sequence[th.Tensor]) -> th.Tensor:
    """Each run's 2-norm over all the given stacked tensors, ``[K]`` (``clip_grad_norm_``'s total norm)."""
    k = grads[0].shape[0]
    per_tensor = th.stack([th.linalg.vector_norm(g.reshape(k, -1), 2.0, dim=1) for g in grads], dim=1)
    return th.linalg.vector_norm(per_tensor, 2.0, dim=1)


def clip_grad_norm(grads: Sequence[th.Tensor], max_norm: float) -> tuple[list[th.Tensor], th.Tensor]:
    """``torch.nn.utils.clip_grad_norm_`` per run: each run's gradients scaled by
    ``min(1, max_norm / (its norm + 1e-6))``. Returns the clipped gradients and the norms."""
    norms = run_norms(grads)
    coef = th.clamp(max_norm / (norms + 1e-6), max=1.0)
    return [g * coef.reshape((-1,) + (1,) * (g.dim() - 1)) for g in grads], norms
