"""Adam and gradient clipping for parameters stacked along a leading run axis.

Each run of a fleet owns slice ``k`` of every stacked tensor (shape ``[K, ...]``). The runs are
independent trainings, so everything here is per slice: :class:`BatchedAdam` keeps per-run step
counts and moments and takes, on each run's slice, exactly the step of ``torch.optim.Adam(...,
fused=True)``, with a per-run learning rate and a per-run mask (a masked run's parameters, moments
and step count stay untouched, e.g. a PPO-Lag run whose KL early stop fired while the others
continue). :func:`clip_grad_norm` is ``clip_grad_norm_`` with each run clipped by its own norm. A
test compares both with the PyTorch originals slice by slice, bit for bit.

Why PyTorch's *fused* Adam: it is one pass over the parameters, where the default implementation
(the one a single run's ``torch.optim.Adam`` takes on the CPU) is seven, each allocating a buffer
of the size of all parameters of all runs. For a fleet of 12 PPO runs (154k parameters) the
default arithmetic took 180 us a step, and 500-800 us whenever the C library handed those buffers
back to the system between steps (fresh pages every step); the fused kernel takes 50 us. The two
implementations are the same algorithm and differ by float rounding (about 1e-7 after 50 steps),
which is within the tolerance the fleet already has against its single runs.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch as th


class BatchedAdam:
    """``torch.optim.Adam(fused=True)`` (no weight decay, no amsgrad) for ``K`` runs at once.

    :param params: stacked leaf tensors ``[K, ...]``. Their values move into one run-major buffer
        ``[K, P]`` (row ``k`` holds all of run ``k``'s parameters; each tensor's ``.data`` becomes a
        view of its columns, batch-strided), so a step is one fused kernel over each run's row,
        instead of a dozen operations per tensor; the tensors keep their shapes.
    :param eps: Adam's ``eps`` (PyTorch's default 1e-8; SB3's policies pass 1e-5).
    :param padded: ``{index: widths}`` for parameters ``[K, out, W]`` of which run ``k`` uses only the
        first ``widths[k]`` columns (a fleet that mixes observation sizes: the rest stays exactly 0).
        Gradient norms are taken over each run's own columns, laid out as its unpadded tensor, so
        clipping gives the bits a fleet of one observation size gives.
    """

    def __init__(
        self, params: Sequence[th.Tensor], n_runs: int, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8,
        padded: dict[int, list[int]] | None = None,
    ) -> None:
        self.params = list(params)
        self.n_runs = n_runs
        self._padded = {i: np.asarray(widths, dtype=np.int64) for i, widths in (padded or {}).items()}
        self.beta1, self.beta2 = float(betas[0]), float(betas[1])
        self.eps = float(eps)
        for p in self.params:
            if p.dim() == 0 or p.shape[0] != n_runs:
                raise ValueError(f"stacked parameter of shape {tuple(p.shape)} has no run axis of {n_runs}")
        sizes = [p[0].numel() for p in self.params]
        #: Column range of each parameter in the ``[K, P]`` buffers.
        self._columns = list(zip(np.cumsum([0, *sizes])[:-1].tolist(), np.cumsum(sizes).tolist()))
        self.flat = th.empty(n_runs, int(sum(sizes)), dtype=self.params[0].dtype, device=self.params[0].device)
        with th.no_grad():
            for p, (a, b) in zip(self.params, self._columns):
                view = self.flat[:, a:b].view(p.shape)
                view.copy_(p)
                p.data = view
        self.exp_avg = th.zeros_like(self.flat)
        self.exp_avg_sq = th.zeros_like(self.flat)
        #: Each run's step count (float, as ``torch.optim.Adam`` keeps it), and one 0-d view per run.
        self._step_counts = th.zeros(n_runs, dtype=th.float32, device=self.flat.device)
        self._steps = list(self._step_counts.unbind())
        # Row views, one per run: the fused kernel walks a list of tensors.
        self._rows = [list(buf.unbind()) for buf in (self.flat, self.exp_avg, self.exp_avg_sq)]

    @property
    def steps(self) -> np.ndarray:
        """``[K]`` int: each run's number of steps taken."""
        return self._step_counts.cpu().numpy().astype(np.int64)

    @th.no_grad()
    def step(
        self,
        grads: Sequence[th.Tensor],
        lr: np.ndarray | float,
        mask: np.ndarray | None = None,
        max_norm: float | None = None,
        clip_groups: Sequence[Sequence[int]] | None = None,
        l2: float | None = None,
    ) -> None:
        """One Adam step of every run (or of the runs where ``mask`` is true) with per-run ``lr``.

        ``grads`` are stacked like the parameters (``[K, ...]``), or, with a ``mask``, may hold only
        the masked-in runs' rows (``[mask.sum(), ...]``, in run order). With ``l2`` the gradient of
        ``l2 * sum ||theta||^2`` (``l2 * (2 * theta)``, float32, as autograd takes it) is added
        first. With ``max_norm`` the gradients are then clipped per run as :func:`clip_grad_norm`
        does, each group of ``clip_groups`` (indices into the parameters; default: all of them) by
        its own norm, e.g. the reward and the cost critic of one Adam separately.
        """
        lr = np.broadcast_to(np.asarray(lr, dtype=np.float64), (self.n_runs,))
        active = np.ones(self.n_runs, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        runs = np.flatnonzero(active)
        if not len(runs):
            return
        g = self._active_gradient(grads, runs)  # from here on ``g``'s rows are the active runs'
        if l2:
            params = self.flat if len(runs) == self.n_runs else self.flat[th.from_numpy(runs)]
            g.add_(params * (2.0 * l2))  # = l2 * (2 * theta) exactly: doubling is exact in binary floats
        if max_norm is not None:
            self._clip(g, max_norm, clip_groups, runs)
        # As torch.optim.Adam: the step count first, then the kernel.
        if len(runs) == self.n_runs:
            self._step_counts.add_(1.0)
        else:
            self._step_counts[th.from_numpy(runs).to(self._step_counts.device)] += 1.0
        self._fused_step(g, runs, lr[runs])

    def _active_gradient(self, grads: Sequence[th.Tensor], runs: np.ndarray) -> th.Tensor:
        """The gradients as one ``[R, P]`` matrix whose rows are the active ``runs``' (given for
        every run, or for the active runs only)."""
        rows = grads[0].shape[0]
        g = th.cat([x.reshape(rows, -1) for x in grads], dim=1)
        if rows == self.n_runs and len(runs) < rows:
            return g[th.from_numpy(runs)]
        if rows != len(runs):
            raise ValueError(f"gradients for {rows} runs, but {len(runs)} runs are masked in")
        return g

    def _fused_step(self, g: th.Tensor, runs: np.ndarray, rates: np.ndarray) -> None:
        """PyTorch's fused Adam kernel on the active ``runs`` (``g``'s rows), once per distinct
        learning rate among ``rates`` (one call when they share one, as they usually do)."""
        flat, avg, avg_sq = self._rows
        g_rows = g.unbind()
        for rate in (rates[:1] if (rates == rates[0]).all() else np.unique(rates)):
            group = range(len(runs)) if len(rates) == 1 or (rates == rate).all() else np.flatnonzero(rates == rate).tolist()
            members = runs[list(group)].tolist()
            th._fused_adam_(
                [flat[k] for k in members], [g_rows[i] for i in group], [avg[k] for k in members], [avg_sq[k] for k in members],
                [], [self._steps[k] for k in members], lr=float(rate), beta1=self.beta1, beta2=self.beta2, weight_decay=0.0,
                eps=self.eps, amsgrad=False, maximize=False,
            )

    def _clip(self, g: th.Tensor, max_norm: float, groups: Sequence[Sequence[int]] | None, runs: np.ndarray) -> None:
        """Scale the gradient ``g`` (one row per run of ``runs``, ``[R, P]``) in place:
        :func:`clip_grad_norm` per run and group."""
        groups = [range(len(self.params))] if groups is None else groups
        for grp in groups:
            idx = list(grp)
            norms = th.stack([self._norms(g, i, runs) for i in idx], dim=1)
            coef = th.clamp(max_norm / (th.linalg.vector_norm(norms, 2.0, dim=1) + 1e-6), max=1.0).unsqueeze(1)
            if idx == list(range(idx[0], idx[-1] + 1)):  # contiguous parameters: one block of columns
                g[:, self._columns[idx[0]][0] : self._columns[idx[-1]][1]].mul_(coef)
            else:
                for i in idx:
                    g[:, slice(*self._columns[i])].mul_(coef)

    def _norms(self, g: th.Tensor, i: int, runs: np.ndarray) -> th.Tensor:
        """``[R]``: each row's 2-norm of parameter ``i``'s gradient, over the run's own columns."""
        block = g[:, slice(*self._columns[i])]
        widths = self._padded.get(i)
        if widths is None:
            return th.linalg.vector_norm(block, 2.0, dim=1)
        out_dim, width = self.params[i].shape[1:]
        norms = block.new_empty(block.shape[0])
        row_widths = widths[runs]
        for d in np.unique(row_widths).tolist():
            rows = th.from_numpy(np.flatnonzero(row_widths == d)).to(g.device)
            own = block.index_select(0, rows).view(len(rows), out_dim, width)[:, :, :d].reshape(len(rows), -1)
            norms[rows] = th.linalg.vector_norm(own, 2.0, dim=1)
        return norms

    def state_dict(self) -> dict[str, th.Tensor]:
        """The moments and step counts of every run (CPU copies; the parameters are their owner's
        to save). For a training checkpoint (:mod:`.checkpoint`)."""
        return {"exp_avg": self.exp_avg.cpu().clone(), "exp_avg_sq": self.exp_avg_sq.cpu().clone(), "steps": self._step_counts.cpu().clone()}

    @th.no_grad()
    def load_state_dict(self, state: dict[str, th.Tensor]) -> None:
        """Restore :meth:`state_dict` *in place*: the fused kernel walks row views of these very
        buffers (and the per-run step views), so they must stay the same tensors."""
        for name, buf in (("exp_avg", self.exp_avg), ("exp_avg_sq", self.exp_avg_sq), ("steps", self._step_counts)):
            value = state[name]
            if value.shape != buf.shape or value.dtype != buf.dtype:
                raise ValueError(f"Adam {name}: expected {tuple(buf.shape)} {buf.dtype}, got {tuple(value.shape)} {value.dtype}")
            buf.copy_(value)

    def state_of(self, k: int) -> list[dict[str, th.Tensor]]:
        """Run ``k``'s Adam state per parameter, as ``torch.optim.Adam.state`` holds it."""
        def own(buf: th.Tensor, i: int, p: th.Tensor, a: int, b: int) -> th.Tensor:
            value = buf[k, a:b].reshape(p.shape[1:])
            return (value[:, : int(self._padded[i][k])] if i in self._padded else value).clone()

        return [
            {"step": self._steps[k].clone(), "exp_avg": own(self.exp_avg, i, p, a, b), "exp_avg_sq": own(self.exp_avg_sq, i, p, a, b)}
            for i, (p, (a, b)) in enumerate(zip(self.params, self._columns))
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
