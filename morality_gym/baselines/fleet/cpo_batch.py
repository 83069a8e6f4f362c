"""CPO's actor step for every run of a fleet at once: the accelerator path of :mod:`.cpo`.

Why a second path: the per-run actor step of :class:`~.cpo.FleetCPO` is a few hundred small
kernels and a few dozen host reads per run (conjugate gradients, the dual's scalars, every line
search candidate). On a GPU that is launch and synchronisation time, not arithmetic: on an H200 a
fleet of 336 CPO runs spent 15.2 of 17.5 s of two updates there (``benchmarks/gpu_probe.py``).
Here the same quantities are computed for all runs together:

* every run's distinct observations are padded to the fleet's largest count ``U`` (padding rows
  have weight 0 and no transitions, so they add exact zeros to every sum over states);
* ``g`` and ``b`` of every run are the rows ``2k`` and ``2k + 1`` of one back-propagation through
  the runs' actors gathered twice, and their conjugate gradients are one solve of ``2K`` rows,
  each stopping on its own residual (as each run's does on its own);
* the dual's scalars of all runs come to the host in one transfer; the case, the multipliers and
  the step are worked out there per run by the single learner's own functions (a step is always
  ``a v + b w``, so those functions are evaluated on the basis vectors to get ``a`` and ``b``);
* the line search evaluates every run's candidate at once and reads the surrogates and KLs in one
  transfer per candidate; each run's accept/shrink decision is the single learner's rule.

The per-run path stays the default on the CPU: this path sums over padded states and batched rows,
so its floats differ from the per-run path's in the last bits, and on the CPU the per-run path
keeps the release's runs' bits. tests/test_fleet_cpo_batch.py holds the two paths to the same
cases, line-search decisions and parameters within float tolerance, on the CPU.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th

from morality_gym.baselines.fleet.cpo_math import (
    ActorStep,
    FlatActor,
    Operator,
    conjugate_gradient,
    fisher_product,
    judge_candidate,
    new_search,
)
from morality_gym.baselines.fleet.dedup import DistinctStates
from morality_gym.baselines.fleet.losses import Policy
from morality_gym.baselines.fleet.nets import FleetNetworks, Trace
from morality_gym.baselines.safe.cpo_dual import (
    CPOScalars,
    CPOStep,
    exact_direction,
    omnisafe_direction,
)


@dataclass(frozen=True)
class PaddedStates:
    """Every run's distinct observations padded to ``U`` rows: ``obs`` ``[K, U, d]`` (padding rows
    zero), ``weights`` ``[K, U]`` (padding 0), ``inverse`` ``[K, M]`` (each transition's row)."""

    obs: th.Tensor
    weights: th.Tensor
    inverse: th.Tensor

    @classmethod
    def of(cls, states: list[DistinctStates]) -> PaddedStates:
        k, u = len(states), max(s.n for s in states)
        first = states[0].obs
        obs = first.new_zeros(k, u, first.shape[1])
        weights = first.new_zeros(k, u)
        for i, s in enumerate(states):
            obs[i, : s.n] = s.obs
            weights[i, : s.n] = s.weights
        return cls(obs, weights, th.stack([s.inverse for s in states]))

    @property
    def n(self) -> int:
        return int(self.obs.shape[1])


class BatchedActorStep:
    """One CPO actor step of all ``K`` runs (see the module docstring): their stacked actors
    ``nets`` (``theta``: the actors' flat parameter rows ``[K, D]``, which the step moves), the CPO
    ``model`` (hyper-parameters), each run's distinct observations and, per transition (``[K, M]``),
    the action, the rollout's log-probability and the normalised reward and cost advantages."""

    def __init__(
        self, nets: FleetNetworks, model: Any, flat: FlatActor, theta: th.Tensor, states: list[DistinctStates],
        actions: th.Tensor, old_log_prob: th.Tensor, advantages: th.Tensor, cost_advantages: th.Tensor,
    ) -> None:
        self.nets, self.model, self.flat, self.theta = nets, model, flat, theta
        self.states = PaddedStates.of(states)
        self.actions, self.old_log_prob = actions, old_log_prob
        self.advantages, self.cost_advantages = advantages, cost_advantages
        self.k, self.m = int(actions.shape[0]), int(actions.shape[1])
        self.device = actions.device

    # ------------------------------------------------------------------ pieces
    def _cells(self) -> th.Tensor:
        """``[K, M]``: each transition's (action, state) cell in a flattened ``[A, U]`` policy."""
        return self.actions * self.states.n + self.states.inverse

    def _log_prob(self, policy: Policy, cells: th.Tensor) -> th.Tensor:
        return policy.logp.reshape(policy.logp.shape[0], -1).gather(1, cells)

    def _evaluate(self) -> tuple[Policy, th.Tensor, th.Tensor, th.Tensor]:
        """Every run's current actor: its policy, ``L_r`` and ``L_c`` (``[K]``) and whether its log-probabilities are all numbers."""
        policy = Policy.of(self.nets("pi", self.states.obs))
        ratio = th.exp(self._log_prob(policy, self._cells()) - self.old_log_prob)
        valid = ~th.isnan(policy.logp).flatten(1).any(dim=1)
        return policy, (ratio * self.advantages).mean(dim=1), (ratio * self.cost_advantages).mean(dim=1), valid

    def _mean_kl(self, old: Policy, new: Policy) -> th.Tensor:
        return (new.kl_from(old) * self.states.weights).sum(dim=1)

    def _gradients(self, actor2: Trace, policy2: Policy) -> th.Tensor:
        """``[2K, D]``: rows ``2k``, ``2k + 1`` are run ``k``'s ``g`` and ``b`` (:meth:`.cpo.FleetCPO._gradients`)."""
        n_actions, n_states = policy2.p.shape[1], self.states.n
        cells = self._cells().repeat_interleave(2, dim=0)
        ratio = th.exp(self._log_prob(policy2, cells) - self.old_log_prob.repeat_interleave(2, dim=0))
        advantages = th.stack([self.advantages, self.cost_advantages], dim=1).reshape(2 * self.k, self.m)
        coef = ratio * advantages / self.m
        onehot = coef.new_zeros(2 * self.k, n_actions * n_states).scatter_add_(1, cells, coef).view(2 * self.k, n_actions, n_states)
        per_state = coef.new_zeros(2 * self.k, n_states).scatter_add_(1, self.states.inverse.repeat_interleave(2, dim=0), coef)
        dlogits = onehot.sub_(policy2.p * per_state.unsqueeze(1))
        return self.flat.flat(self.nets.backward(actor2, dlogits))

    def _fisher(self, actor: Trace, policy: Policy, weights: th.Tensor) -> Operator:
        return fisher_product(self.nets, self.flat, actor, policy, weights, float(self.model.cg_damping))

    @staticmethod
    def _coefficients(sc: CPOScalars, vhv: float, solution: str) -> tuple[float, float, CPOStep]:
        """``(a, b, step)`` with ``step.direction = a v + b w``: the single learner's step function
        evaluated on the basis vectors (every CPO step is such a combination)."""
        basis_v = th.tensor([1.0, 0.0], dtype=th.float64, device="cpu")  # host arithmetic: the scalars are on the host
        basis_w = th.tensor([0.0, 1.0], dtype=th.float64, device="cpu")
        step = (omnisafe_direction if solution == "omnisafe" else exact_direction)(basis_v, basis_w, sc, vhv)
        a, b = step.direction.tolist()
        return a, b, step

    # ------------------------------------------------------------------ the step
    def _directions(self, c: np.ndarray) -> tuple[th.Tensor, th.Tensor, list[CPOStep], list[CPOScalars], Policy, Any]:
        """Every run's full step ``[K, D]``, ``g`` ``[K, D]``, step records and scalars, its policy at
        ``theta_old`` and the Fisher product of the ``K`` actors."""
        m, nets, k = self.model, self.nets, self.k
        runs2 = th.arange(k, device=self.device).repeat_interleave(2)
        actor2 = nets.trace("pi", self.states.obs.repeat_interleave(2, dim=0), runs2)
        policy2 = Policy.of(actor2.out)
        gb = self._gradients(actor2, policy2)
        fvp2 = self._fisher(actor2, policy2, self.states.weights.repeat_interleave(2, dim=0))
        vw = conjugate_gradient(fvp2, gb, int(m.cg_max_steps), float(m.cg_eps), float(m.cg_residual_tol))
        g, b, v, w = gb[0::2], gb[1::2], vw[0::2], vw[1::2]
        actor = nets.trace("pi", self.states.obs)
        policy = Policy.of(actor.out)
        fvp = self._fisher(actor, policy, self.states.weights)
        scalars = th.stack([(v * fvp(v)).sum(dim=1), (g * w).sum(dim=1), (b * w).sum(dim=1), (b * b).sum(dim=1)]).cpu().tolist()
        steps, records, coefs = [], [], []
        for i in range(k):
            vhv, r, s, bb = (float(x[i]) for x in scalars)
            sc = CPOScalars(q=vhv, r=r, s=s, c=float(c[i]), delta=float(m.target_kl), bb=bb)
            a_v, a_w, step = self._coefficients(sc, vhv, str(m.dual_solution))
            steps.append(step)
            records.append(sc)
            coefs.append((a_v, a_w))
        cv = th.tensor(coefs, dtype=v.dtype, device=self.device)
        direction = cv[:, :1] * v + cv[:, 1:] * w
        if m.trust_region_rescale:
            quad = (direction * fvp(direction)).sum(dim=1)
            rescale = (direction.abs().sum(dim=1) > 0) & (quad > 2 * float(m.target_kl))
            scale = th.where(rescale, th.sqrt(2 * float(m.target_kl) / quad), th.ones_like(quad))
            direction = direction * scale.unsqueeze(1)
        return direction, g, steps, records, policy, fvp

    def _line_search(self, direction: th.Tensor, g: th.Tensor, steps: list[CPOStep], c: np.ndarray, old: Policy) -> list[dict[str, float]]:
        """Every run's backtracking line search (:meth:`.cpo.FleetCPO._line_search`), candidates
        evaluated together; leaves each run's actor at its accepted point or unchanged."""
        m, theta = self.model, self.theta
        theta_old = theta.clone()
        _, start_r, start_c, _ = self._evaluate()
        start = th.stack([start_r, start_c]).double().cpu().numpy()
        expected = (g * direction).sum(dim=1).double().cpu().numpy()
        results = [new_search() for _ in range(self.k)]
        fraction = np.ones(self.k)
        searching = np.ones(self.k, dtype=bool)
        for j in range(int(m.line_search_max_iter)):
            if not searching.any():
                break
            live = th.from_numpy(searching).to(self.device).unsqueeze(1)
            frac = th.from_numpy(fraction.astype(np.float32)).to(self.device).unsqueeze(1)
            theta.copy_(th.where(live, theta_old + frac * direction, theta))
            policy, reward, cost, valid = self._evaluate()
            kl = self._mean_kl(old, policy)
            read = th.stack([reward.double(), cost.double(), kl.double(), valid.double()]).cpu().numpy()
            for i in np.flatnonzero(searching):
                reward, cost, kl, valid = read[:, i]
                accepted, fraction[i] = judge_candidate(
                    self.model, steps[i], results[i], j, float(fraction[i]), bool(valid), float(kl),
                    float(reward - start[0, i]), float(cost - start[1, i]), float(c[i]), float(expected[i]))
                searching[i] = not accepted
        accepted = th.from_numpy(np.array([r["accept_step"] > 0 for r in results])).to(self.device).unsqueeze(1)
        chosen = th.from_numpy(np.array([r["fraction"] for r in results], dtype=np.float32)).to(self.device).unsqueeze(1)
        theta.copy_(th.where(accepted, theta_old + chosen * direction, theta_old))
        for r in results:
            if not r["accept_step"]:
                r.update(d_reward=0.0, d_cost=0.0)
        return results

    def run(self, c: np.ndarray) -> list[ActorStep]:
        """Every run's actor step: its record for the diagnostics rows, the actors moved."""
        direction, g, steps, records, old, _ = self._directions(c)
        searches = self._line_search(direction, g, steps, c, old)
        kl_mean = self._mean_kl(old, self._evaluate()[0])
        taken = th.tensor([s["fraction"] for s in searches], dtype=direction.dtype, device=self.device).unsqueeze(1) * direction
        numbers = th.stack([kl_mean, direction.norm(dim=1), taken.norm(dim=1), (g * taken).sum(dim=1)]).cpu().tolist()
        return [
            ActorStep(steps[i], records[i], searches[i], numbers[0][i], numbers[1][i], numbers[2][i], numbers[3][i])
            for i in range(self.k)
        ]


__all__ = ["BatchedActorStep", "PaddedStates"]
