"""The Lagrange multiplier of PPO-Lagrangian, learnt by gradient ascent on the dual.

The constrained problem ``max_pi J_r(pi)  s.t.  J_c(pi) <= d`` has the Lagrangian
``L(pi, lambda) = J_r(pi) - lambda * (J_c(pi) - d)`` with ``lambda >= 0``. The policy maximises
``L`` over ``pi``; the multiplier *minimises* it over ``lambda``, i.e. descends on

    loss(lambda) = -lambda * (J_c - d),        d loss / d lambda = -(J_c - d),

so ``lambda`` grows while the constraint is violated (``J_c > d``) and shrinks otherwise. Each
update is one Adam step on that loss followed by the projection ``lambda <- max(lambda, 0)``.
Adam normalises the gradient, so each step moves ``lambda`` by roughly the learning rate (0.035 in
the paper's runs) whatever the cost's scale.

A ``nn.Module`` so that SB3's save/load stores the value (and its optimiser's moments) through
``state_dict`` like any network.
"""

from __future__ import annotations

import torch as th
from torch import nn


class LagrangeMultiplier(nn.Module):
    """A non-negative scalar ``lambda`` with its own Adam optimiser.

    :param initial_value: ``lambda`` before the first update (0.001 in the paper's runs).
    :param learning_rate: Adam learning rate of ``lambda`` (0.035).
    :param upper_bound: optional cap on ``lambda`` (``None``: unbounded, as in the paper's runs).
    """

    def __init__(self, initial_value: float = 0.001, learning_rate: float = 0.035, upper_bound: float | None = None):
        super().__init__()
        if initial_value < 0:
            raise ValueError(f"the Lagrange multiplier must start >= 0, got {initial_value}")
        self.value_param = nn.Parameter(th.tensor(float(initial_value)))
        self.upper_bound = upper_bound
        self.optimizer = th.optim.Adam([self.value_param], lr=learning_rate)

    @property
    def value(self) -> float:
        """The current ``lambda``."""
        return float(self.value_param.detach())

    def update(self, mean_episode_cost: float, cost_limit: float) -> float:
        """One projected Adam step on ``-lambda * (J_c - d)``; returns the new ``lambda``."""
        violation = float(mean_episode_cost) - float(cost_limit)
        self.optimizer.zero_grad()
        loss = -self.value_param * violation
        loss.backward()
        self.optimizer.step()
        with th.no_grad():
            self.value_param.clamp_(min=0.0, max=self.upper_bound)
        return self.value
