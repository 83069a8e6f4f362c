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


class BatchedAdam:
    """``torch.optim.Adam`` (no weight decay, no amsgrad) for ``K`` runs at once.

    :param params: stacked leaf tensors ``[K, ...]``. They are moved into one flat buffer (each
        tensor's ``.data`` becomes a view of it), so a step is a handful of operations over all
        parameters of all runs instead of a dozen per tensor; the tensors keep their shapes.
    :param eps: Adam's ``eps`` (PyTorch's default 1e-8; SB3's policies pass 1e-5).
    """

    def __init__(self, params: Sequence[th.Tensor], n_runs: int, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8) -> None:
        self.params = list(params)
        self.n_runs = n_runs
        self.beta1, self.beta2 = float(betas[0]), float(betas[1])
        self.eps = float(eps)
        self.steps = np.zeros(n_runs, dtype=np.int64)
        sizes = [p.numel() for p in self.params]
        self._offsets = np.cumsum([0, *sizes])
        self.flat = th.empty(int(self._offsets[-1]), dtype=self.params[0].dtype)
        runs = []
        with th.no_grad():
            for p, start, end in zip(self.params, self._offsets[:-1], self._offsets[1:]):
                if p.shape[0] != n_runs:
                    raise ValueError(f"stacked parameter of shape {tuple(p.shape)} has no run axis of {n_runs}")
                view = self.flat[start:end].view(p.shape)
                view.copy_(p)
                p.data = view
                runs.append(th.arange(n_runs).repeat_interleave(p[0].numel()))
        #: The run each element of the flat buffer belongs to.
        self._run_of = th.cat(runs)
        self.exp_avg = th.zeros_like(self.flat)
        self.exp_avg_sq = th.zeros_like(self.flat)

    def _per_element(self, values: np.ndarray) -> th.Tensor | float:
        """A per-run ``[K]`` float array as a per-element factor (a plain scalar when all runs agree,
        which is exact: the kernels round the scalar to float32 as they would the tensor)."""
        if np.all(values == values[0]):
            return float(values[0])
        return th.as_tensor(values, dtype=self.flat.dtype)[self._run_of]

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
        step_size = np.where(active, lr / bc1, lr[active][0] / bc1[active][0])  # masked runs: any value
        bc2_sqrt = np.where(active, bc2_sqrt, bc2_sqrt[active][0])
        g = th.cat([x.reshape(-1) for x in grads])
        m, v, p = self.exp_avg, self.exp_avg_sq, self.flat
        new_m = m.lerp(g, 1 - self.beta1)
        new_v = (v * self.beta2).addcmul_(g, g, value=1 - self.beta2)
        denom = (new_v.sqrt() / self._per_element(bc2_sqrt)).add_(self.eps)
        new_p = p - self._per_element(step_size) * new_m / denom
        if active.all():
            m.copy_(new_m)
            v.copy_(new_v)
            p.copy_(new_p)
        else:
            keep = th.as_tensor(active)[self._run_of]
            m.copy_(th.where(keep, new_m, m))
            v.copy_(th.where(keep, new_v, v))
            p.copy_(th.where(keep, new_p, p))
        self.steps = steps

    def _slices(self, buffer: th.Tensor, k: int) -> list[th.Tensor]:
        return [buffer[a:b].view(p.shape)[k].clone() for p, a, b in zip(self.params, self._offsets[:-1], self._offsets[1:])]

    def state_of(self, k: int) -> list[dict[str, th.Tensor]]:
        """Run ``k``'s Adam state per parameter, as ``torch.optim.Adam.state`` holds it."""
        step = th.tensor(float(self.steps[k]))
        return [
            {"step": step.clone(), "exp_avg": m, "exp_avg_sq": v}
            for m, v in zip(self._slices(self.exp_avg, k), self._slices(self.exp_avg_sq, k))
        ]


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
