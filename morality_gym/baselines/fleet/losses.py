"""The fleet learners' losses, each with its gradient with respect to the networks' outputs.

Every learner's loss is a function of a categorical policy's logits and of value predictions, so
its gradient with respect to those outputs has a closed form, which is then back-propagated
through the stacked networks (:meth:`~.nets.FleetNetworks.backward`). Each function here
reproduces what autograd computes for the single learner's expression, including its choices at
ties (``torch.min`` splits the gradient evenly where both arguments are equal; ``clamp`` passes it
at the bounds), so the two agree to float rounding.

Layout: feature-major as the networks' outputs (:mod:`.nets`): logits and a policy's
log-probabilities are ``[R, A, B]`` (runs, actions, states), values ``[R, 1, B]``. PyTorch's
``log_softmax`` over a last axis of 6 is not vectorised across states (43 us for ``[12, 64, 6]``,
against 3 us over axis 1 of ``[12, 6, 64]``, bit for bit the same values).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch as th


@dataclass
class Policy:
    """A categorical policy over ``A`` actions at ``B`` states of ``R`` runs: log-probabilities and
    probabilities, ``[R, A, B]``."""

    logp: th.Tensor
    p: th.Tensor

    @classmethod
    def of(cls, logits: th.Tensor) -> Policy:
        """From logits ``[R, A, B]`` (the actor head's output)."""
        logp = th.log_softmax(logits, dim=1)
        return cls(logp, logp.exp())

    def log_prob(self, actions: th.Tensor) -> th.Tensor:
        """``[R, B]``: the log-probability of each state's action (``actions``: ``[R, B]`` int64)."""
        return self.logp.gather(1, actions.unsqueeze(1))[:, 0]

    def entropy(self) -> th.Tensor:
        """``[R, B]``: ``Categorical.entropy()`` (log-probabilities clamped at the float minimum)."""
        clamped = th.clamp(self.logp, min=th.finfo(self.logp.dtype).min)
        return -(clamped * self.p).sum(dim=1)

    def dlogits(self, actions: th.Tensor, dlogp: th.Tensor, dentropy: th.Tensor | None = None) -> th.Tensor:
        """The gradient with respect to the logits (``[R, A, B]``) of a loss
        whose gradient is ``dlogp`` (``[R, B]``) with respect to each state's chosen action's
        log-probability, plus ``dentropy`` (``[R, B]``) with respect to each state's entropy.

        ``d log p_a / d z = onehot(a) - p`` and ``d H / d z_j = -p_j (log p_j + H)``.
        """
        grad = self.p * (-dlogp).unsqueeze(1)
        grad.scatter_add_(1, actions.unsqueeze(1), dlogp.unsqueeze(1))
        if dentropy is not None:
            h = self.entropy().unsqueeze(1)
            grad.sub_(self.p * (self.logp + h) * dentropy.unsqueeze(1))
        return grad

    def kl_from(self, old: Policy) -> th.Tensor:
        """``[R, B]``: ``KL(old || self)`` per state (:func:`~morality_gym.baselines.safe.functional.categorical_kl`)."""
        return (old.p * (old.logp - self.logp)).sum(dim=1)


def clipped_surrogate(ratio: th.Tensor, advantages: th.Tensor, clip_range: float) -> tuple[th.Tensor, th.Tensor]:
    """PPO's clipped surrogate loss ``-mean(min(ratio A, clamp(ratio, 1 - eps, 1 + eps) A))`` per
    run (``[R]``) and its gradient with respect to ``ratio`` (``[R, B]``), as autograd takes it:
    where both terms are equal each gets half the gradient; the clamped term passes it only with
    the ratio inside the bounds (bounds included)."""
    lo, hi = 1.0 - clip_range, 1.0 + clip_range
    unclipped = ratio * advantages
    clipped = th.clamp(ratio, lo, hi) * advantages
    loss = -th.min(unclipped, clipped).mean(dim=1)
    share = th.where(unclipped < clipped, 1.0, th.where(unclipped == clipped, 0.5, 0.0))
    inside = (ratio >= lo) & (ratio <= hi)
    weight = share + (1.0 - share) * inside
    grad = advantages * weight * (-1.0 / ratio.shape[1])
    return loss, grad


def mse(pred: th.Tensor, target: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """``mean((pred - target)^2)`` per run (``[R]``) of predictions ``[R, B]`` and its gradient
    with respect to them, shaped as a value head's output (``[R, 1, B]``)."""
    diff = pred - target
    loss = (diff * diff).mean(dim=1)
    return loss, diff.mul_(2.0 / diff.shape[1]).unsqueeze(1)
