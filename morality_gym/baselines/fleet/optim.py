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

    :param params: stacked leaf tensors ``[K, ...]``. Their values move into one run-major buffer
        ``[K, P]`` (row ``k`` holds all of run ``k``'s parameters; each tensor's ``.data`` becomes a
        view of its columns, batch-strided), so a step is a handful of operations over all
        parameters of all runs, per-run factors broadcast as ``[K, 1]``, instead of a dozen
        operations per tensor; the tensors keep their shapes.
    :param eps: Adam's ``eps`` (PyTorch's default 1e-8; SB3's policies pass 1e-5).
    """

    def __init__(self, params: Sequence[th.Tensor], n_runs: int, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8) -> None:
        self.params = list(params)
        self.n_runs = n_runs
        self.beta1, self.beta2 = float(betas[0]), float(betas[1])
        self.eps = float(eps)
        self.steps = np.zeros(n_runs, dtype=np.int64)
        for p in self.params:
            if p.dim() == 0 or p.shape[0] != n_runs:
                raise ValueError(f"stacked parameter of shape {tuple(p.shape)} has no run axis of {n_runs}")
        sizes = [p[0].numel() for p in self.params]
        #: Column range of each parameter in the ``[K, P]`` buffers.
        self._columns = list(zip(np.cumsum([0, *sizes])[:-1].tolist(), np.cumsum(sizes).tolist()))
        self.flat = th.empty(n_runs, int(sum(sizes)), dtype=self.params[0].dtype)
        with th.no_grad():
            for p, (a, b) in zip(self.params, self._columns):
                view = self.flat[:, a:b].view(p.shape)
                view.copy_(p)
                p.data = view
        self.exp_avg = th.zeros_like(self.flat)
        self.exp_avg_sq = th.zeros_like(self.flat)

    def _per_run(self, values: np.ndarray) -> th.Tensor | float:
        """A per-run ``[K]`` float array as a ``[K, 1]`` factor (a plain scalar when all runs agree,
        which is exact: the kernels round the scalar to float32 as they would the tensor)."""
        if np.all(values == values[0]):
            return float(values[0])
        return th.as_tensor(values, dtype=self.flat.dtype).unsqueeze(1)

    @th.no_grad()
    def step(
        self,
        grads: Sequence[th.Tensor],
        lr: np.ndarray | float,
        mask: np.ndarray | None = None,
        max_norm: float | None = None,
        clip_groups: Sequence[Sequence[int]] | None = None,
    ) -> None:
        """One Adam step of every run (or of the runs where ``mask`` is true) with per-run ``lr``.

        With ``max_norm`` the gradients are first clipped per run as :func:`clip_grad_norm` does,
        each group of ``clip_groups`` (indices into the parameters; default: all of them) by its own
        norm, e.g. the reward and the cost critic of one Adam separately.
        """
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
        g = th.cat([x.reshape(self.n_runs, -1) for x in grads], dim=1)
        if max_norm is not None:
            self._clip(g, max_norm, clip_groups)
        m, v, p = self.exp_avg, self.exp_avg_sq, self.flat
        if active.all():
            # torch's own in-place sequence (addcdiv_ when every run has the same step size).
            m.lerp_(g, 1 - self.beta1)
            v.mul_(self.beta2).addcmul_(g, g, value=1 - self.beta2)
            denom = (v.sqrt() / self._per_run(bc2_sqrt)).add_(self.eps)
            size = self._per_run(step_size)
            if isinstance(size, float):
                p.addcdiv_(m, denom, value=-size)
            else:
                p.sub_(size * m / denom)
        else:
            new_m = m.lerp(g, 1 - self.beta1)
            new_v = (v * self.beta2).addcmul_(g, g, value=1 - self.beta2)
            denom = (new_v.sqrt() / self._per_run(bc2_sqrt)).add_(self.eps)
            new_p = p - self._per_run(step_size) * new_m / denom
            keep = th.as_tensor(active).unsqueeze(1)
            m.copy_(th.where(keep, new_m, m))
            v.copy_(th.where(keep, new_v, v))
            p.copy_(th.where(keep, new_p, p))
        self.steps = steps

    def _clip(self, g: th.Tensor, max_norm: float, groups: Sequence[Sequence[int]] | None) -> None:
        """Scale the ``[K, P]`` gradient ``g`` in place: :func:`clip_grad_norm` per run and group."""
        groups = [range(len(self.params))] if groups is None else groups
        for grp in groups:
            idx = list(grp)
            norms = th.stack([th.linalg.vector_norm(g[:, slice(*self._columns[i])], 2.0, dim=1) for i in idx], dim=1)
            coef = th.clamp(max_norm / (th.linalg.vector_norm(norms, 2.0, dim=1) + 1e-6), max=1.0).unsqueeze(1)
            if idx == list(range(idx[0], idx[-1] + 1)):  # contiguous parameters: one block of columns
                g[:, self._columns[idx[0]][0] : self._columns[idx[-1]][1]].mul_(coef)
            else:
                for i in idx:
                    g[:, slice(*self._columns[i])].mul_(coef)

    def state_of(self, k: int) -> list[dict[str, th.Tensor]]:
        """Run ``k``'s Adam state per parameter, as ``torch.optim.Adam.state`` holds it."""
        step = th.tensor(float(self.steps[k]))
        return [
            {
                "step": step.clone(),
                "exp_avg": self.exp_avg[k, a:b].reshape(p.shape[1:]).clone(),
                "exp_avg_sq": self.exp_avg_sq[k, a:b].reshape(p.shape[1:]).clone(),
            }
            for p, (a, b) in zip(self.params, self._columns)
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
