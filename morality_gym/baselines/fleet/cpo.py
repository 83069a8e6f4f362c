"""CPO for a fleet: :class:`~morality_gym.baselines.safe.cpo.CPO`'s update, K runs at once.

Per run, as the single learner: the reward and cost surrogate gradients ``g`` and ``b``, conjugate
gradients on Fisher-vector products for ``v = H^-1 g`` and ``w = H^-1 b``, the case and full step
of :mod:`~morality_gym.baselines.safe.cpo_dual` (``dual_solution``), the backtracking line search
with its acceptance rule, then the critics' regression.

Batched: the Fisher-vector products of all runs are one forward-mode and one backward pass
(:meth:`FleetCPO._fisher_vector_product`; the runs' parameters are disjoint slices, so each slice
of the gradient is its run's own);
conjugate gradients run for all runs together and each run stops on its own residual (a stopped
run's solution is frozen); every line-search candidate is evaluated for all runs still searching in
one forward pass, each run with its own step fraction, acceptance and bookkeeping. The case logic
and the dual solutions are the single learner's functions, called per run.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch as th

from morality_gym.baselines.fleet.base import categorical
from morality_gym.baselines.fleet.cost_base import FleetCostTrainer
from morality_gym.baselines.fleet.nets import forward
from morality_gym.baselines.safe.cpo_dual import CPOCase, CPOScalars, CPOStep, exact_direction, omnisafe_direction
from morality_gym.baselines.safe.functional import categorical_kl
from morality_gym.baselines.specs import CPO


class FleetCPO(FleetCostTrainer):
    algorithm = CPO
    #: Runs per conjugate-gradient batch (see :meth:`_step_directions`).
    CG_CHUNK = 4

    # ------------------------------------------------------------------ flat actor vectors
    def _flat(self, tensors: list[th.Tensor] | tuple[th.Tensor, ...]) -> th.Tensor:
        """``[K, D]`` (or one row per run of a chunk): each run's slices of the actor tensors, concatenated."""
        return th.cat([t.reshape(t.shape[0], -1) for t in tensors], dim=1)

    @th.no_grad()
    def _set_actor(self, flat: th.Tensor) -> None:
        start = 0
        for p in self.actor_params:
            n = p[0].numel()
            p.copy_(flat[:, start : start + n].reshape(p.shape))
            start += n

    # ------------------------------------------------------------------ step direction
    def _step_directions(
        self, obs: th.Tensor, actions: th.Tensor, old_log_prob: th.Tensor, adv: th.Tensor, cadv: th.Tensor,
        old_logits: th.Tensor, c: np.ndarray,
    ) -> tuple[list[CPOStep], th.Tensor, list[CPOScalars], th.Tensor]:
        """Every run's ``(step, g, scalars)`` of ``CPO._step_direction``; also the ``[K, D]`` directions.

        Runs are taken :attr:`CG_CHUNK` at a time: each run's conjugate gradients already work on
        whole ``[n_steps * n_envs, 64]`` matrices, so more runs per product gain nothing, while
        smaller operands stay in cache (measured: K = 36 in one chunk ran slower per run than 12)."""
        m = self.model
        steps: list[CPOStep] = []
        scalars: list[CPOScalars] = []
        gs, directions = [], []
        for start in range(0, self.n_runs, self.CG_CHUNK):
            runs = th.arange(start, min(start + self.CG_CHUNK, self.n_runs))
            # The chunk's actor as fresh leaves: gradients come out for the chunk's runs only.
            layers = [(w[runs].detach().requires_grad_(), b[runs].detach().requires_grad_()) for w, b in self.nets.heads["pi"]]
            params = [t for layer in layers for t in layer]
            raw = forward(layers, obs[runs], self.nets.activation)
            norm, probs = categorical(raw)
            log_prob = norm.gather(-1, actions[runs].unsqueeze(-1))[..., 0]
            ratio = th.exp(log_prob - old_log_prob[runs])
            g = self._flat(th.autograd.grad((ratio * adv[runs]).mean(dim=1).sum(), params, retain_graph=True))
            b = self._flat(th.autograd.grad((ratio * cadv[runs]).mean(dim=1).sum(), params, retain_graph=True))
            fvp = self._fisher_vector_product(obs[runs], layers, raw, probs.detach(), float(m.cg_damping))
            v = self._conjugate_gradient(fvp, g)
            vhv = (v * fvp(v)).sum(dim=1)
            w = self._conjugate_gradient(fvp, b)
            r, s, bb = (g * w).sum(dim=1), (b * w).sum(dim=1), (b * b).sum(dim=1)
            direction_of = omnisafe_direction if m.dual_solution == "omnisafe" else exact_direction
            chunk_steps = []
            for i, k in enumerate(runs.tolist()):
                sc = CPOScalars(q=vhv[i].item(), r=r[i].item(), s=s[i].item(), c=float(c[k]), delta=float(m.target_kl), bb=bb[i].item())
                chunk_steps.append(direction_of(v[i], w[i], sc, vhv[i].item()))
                scalars.append(sc)
            chunk_dirs = th.stack([st.direction.to(th.float32) for st in chunk_steps])
            if m.trust_region_rescale:
                quad = (chunk_dirs * fvp(chunk_dirs)).sum(dim=1)
                for i, st in enumerate(chunk_steps):
                    if st.direction.abs().sum() > 0 and quad[i].item() > 2 * m.target_kl:
                        scaled = st.direction * math.sqrt(2 * m.target_kl / quad[i].item())
                        chunk_steps[i] = CPOStep(scaled, st.case, st.lam, st.nu, st.A, st.B)
                chunk_dirs = th.stack([st.direction.to(th.float32) for st in chunk_steps])
            steps += chunk_steps
            gs.append(g.detach())
            directions.append(chunk_dirs)
        return steps, th.cat(gs), scalars, th.cat(directions)

    def _fisher_vector_product(
        self, obs: th.Tensor, layers: list[tuple[th.Tensor, th.Tensor]], raw_logits: th.Tensor, probs: th.Tensor, damping: float
    ) -> Any:
        """``v -> H v + damping * v`` for every run, ``H`` the Hessian of the mean KL at the current actor.

        The single learner differentiates the KL's gradient a second time. At the current actor
        (where ``pi_old = pi_theta``) that Hessian is the Fisher matrix ``J^T M J / N``, ``J`` the
        Jacobian of the logits and ``M = diag(p) - p p^T`` per state, which is computed here as a
        forward-mode product ``J v`` through the stacked MLP, ``M`` per state, and one backward pass
        through the logits' graph: the same matrix, at about a third of the cost; the two differ
        by float rounding only (tested against the single learner).
        """
        relu = self.nets.activation is th.relu
        with th.no_grad():
            inputs = [obs]
            for w, b in layers[:-1]:
                inputs.append(self.nets.activation(th.baddbmm(b, inputs[-1], w)))
        params = [t for layer in layers for t in layer]
        shapes = [p.shape for p in params]
        sizes = [p[0].numel() for p in params]
        n_states = obs.shape[1]

        def fvp(vector: th.Tensor) -> th.Tensor:
            with th.no_grad():
                parts = [t.reshape(shape) for t, shape in zip(th.split(vector, sizes, dim=1), shapes)]
                dh: th.Tensor | None = None
                for i, (w, _) in enumerate(layers):
                    dw, db = parts[2 * i], parts[2 * i + 1]
                    dz = th.baddbmm(db, inputs[i], dw)
                    if dh is not None:
                        dz = dz + th.bmm(dh, w)
                    if i < len(layers) - 1:
                        h = inputs[i + 1]
                        dh = dz * (h > 0) if relu else dz * (1 - h * h)
                pdl = probs * dz
                u = (pdl - probs * pdl.sum(dim=-1, keepdim=True)) / n_states
            hv = th.autograd.grad(raw_logits, params, grad_outputs=u, retain_graph=True)
            return self._flat(hv) + damping * vector

        return fvp

    def _conjugate_gradient(self, fvp: Any, b: th.Tensor) -> th.Tensor:
        """:func:`~morality_gym.baselines.safe.functional.conjugate_gradient` for every run, each
        stopping on its own residual."""
        m = self.model
        eps, tol = float(m.cg_eps), float(m.cg_residual_tol)
        x = th.zeros_like(b)
        residual = b.clone()
        direction = residual.clone()
        rdotr = (residual * residual).sum(dim=1)
        done = th.zeros(b.shape[0], dtype=th.bool)
        for _ in range(int(m.cg_max_steps)):
            h_direction = fvp(direction)
            alpha = (rdotr / ((direction * h_direction).sum(dim=1) + eps)).unsqueeze(1)
            live = (~done).unsqueeze(1)
            x = th.where(live, x + alpha * direction, x)
            residual = th.where(live, residual - alpha * h_direction, residual)
            new_rdotr = (residual * residual).sum(dim=1)
            converged = th.sqrt(new_rdotr) < tol
            go_on = ~done & ~converged
            direction = th.where(go_on.unsqueeze(1), residual + (new_rdotr / (rdotr + eps)).unsqueeze(1) * direction, direction)
            rdotr = th.where(go_on, new_rdotr, rdotr)
            done = done | converged
            if bool(done.all()):
                break
        return x

    # ------------------------------------------------------------------ line search
    @th.no_grad()
    def _surrogates(self, obs: th.Tensor, actions: th.Tensor, old_log_prob: th.Tensor, adv: th.Tensor, cadv: th.Tensor) -> tuple[th.Tensor, np.ndarray, np.ndarray, np.ndarray]:
        """``(logits, L_r, L_c, valid)`` of every run's current actor (``valid``: its distribution
        can be built, i.e. no NaN logits, where the single learner gets a ``ValueError``)."""
        norm, _ = categorical(self.nets("pi", obs))
        ratio = th.exp(norm.gather(-1, actions.unsqueeze(-1))[..., 0] - old_log_prob)
        valid = ~th.isnan(norm).reshape(self.n_runs, -1).any(dim=1)
        return norm, (ratio * adv).mean(dim=1).double().numpy(), (ratio * cadv).mean(dim=1).double().numpy(), valid.numpy()

    def _accepts(self, step: CPOStep, d_reward: float, d_cost: float, kl: float, c: float, expected: float) -> bool:
        m = self.model
        if kl > m.target_kl or d_cost > max(-c, 0.0):
            return False
        if m.line_search_accept == "omnisafe":
            return not (step.case > CPOCase.FEASIBLE_RECOVERY and d_reward < 0)
        if step.case == CPOCase.INFEASIBLE:
            return d_cost < 0
        return d_reward > 0 if expected > 0 else d_cost < 0

    def _line_search(self, data: list[th.Tensor], old_logits: th.Tensor, steps: list[CPOStep], directions: th.Tensor, g: th.Tensor, c: np.ndarray) -> list[dict[str, Any]]:
        """``CPO._line_search`` for every run; leaves each run's actor at its accepted point (or unchanged)."""
        m, k_runs = self.model, self.n_runs
        theta_old = self._flat([p.detach() for p in self.actor_params]).clone()
        _, reward_old, cost_old, _ = self._surrogates(*data)
        expected = (g * directions).sum(dim=1).double().numpy()
        results = [{"accept_step": 0, "fraction": 0.0, "kl": math.nan, "tried": 0, "d_reward": 0.0, "d_cost": 0.0} for _ in range(k_runs)]
        fraction = np.ones(k_runs)
        searching = np.ones(k_runs, dtype=bool)
        shrink = float(m.line_search_shrinking_factor)
        for j in range(int(m.line_search_max_iter)):
            if not searching.any():
                break
            # Runs that are done sit at fraction 0 (their old point) while the others are tried.
            frac32 = th.as_tensor(np.where(searching, fraction, 0.0), dtype=th.float32).unsqueeze(1)
            self._set_actor(theta_old + frac32 * directions)
            logits, reward_new, cost_new, valid = self._surrogates(*data)
            kls = categorical_kl(old_logits, logits).mean(dim=1).double().numpy()
            for k in np.flatnonzero(searching):
                res = results[k]
                res["tried"] = j + 1
                if not valid[k]:
                    fraction[k] *= shrink
                    continue
                kl, d_reward, d_cost = float(kls[k]), float(reward_new[k] - reward_old[k]), float(cost_new[k] - cost_old[k])
                res.update(kl=kl, d_reward=d_reward, d_cost=d_cost)
                if not math.isfinite(kl):
                    if m.line_search_accept != "omnisafe":
                        fraction[k] *= shrink
                    continue
                if self._accepts(steps[k], d_reward, d_cost, kl, float(c[k]), float(expected[k])):
                    res.update(accept_step=j + 1, fraction=float(fraction[k]))
                    searching[k] = False
                    continue
                fraction[k] *= shrink
        for k in np.flatnonzero(searching):
            results[k].update(d_reward=0.0, d_cost=0.0)
        accepted = th.as_tensor([r["fraction"] for r in results], dtype=th.float32).unsqueeze(1)
        self._set_actor(theta_old + accepted * directions)
        return results

    # ------------------------------------------------------------------ update
    def _train(self) -> None:
        m = self.model
        _, critic_lr = self._learning_rates(actor=False)
        mean_ep_costs = self.mean_episode_costs()
        c = mean_ep_costs - float(m.cost_limit)
        self._normalize_advantages()
        data = self._full_batch("obs", "actions", "log_probs", "advantages", "cost_advantages")
        with th.no_grad():
            old_logits = self._logits(data[0])
        steps, g, scalars, directions = self._step_directions(*data, old_logits, c)
        search = self._line_search(data, old_logits, steps, directions, g, c)
        with th.no_grad():
            kl_mean = categorical_kl(old_logits, self._logits(data[0])).mean(dim=1).double().numpy()
        value_loss, cost_value_loss = self._train_critics()
        for k in range(self.n_runs):
            step, sc, res = steps[k], scalars[k], search[k]
            taken = res["fraction"] * directions[k]
            self._row(
                k, mean_ep_costs[k], None, critic_lr,
                kl=res["kl"],
                kl_mean=float(kl_mean[k]),
                cpo_case=int(step.case),
                accept_step=int(res["accept_step"]),
                line_search_tried=int(res["tried"]),
                step_fraction=res["fraction"],
                lambda_star=step.lam,
                nu_star=step.nu,
                A=step.A,
                B=step.B,
                q=sc.q,
                r=sc.r,
                s=sc.s,
                c=float(c[k]),
                b_norm=math.sqrt(max(sc.bb, 0.0)),
                full_step_norm=directions[k].norm().item(),
                step_norm=taken.norm().item(),
                expected_reward_change=(g[k] @ taken).item(),
                surrogate_reward_change=res["d_reward"],
                surrogate_cost_change=res["d_cost"],
                value_loss=float(value_loss[k]),
                cost_value_loss=float(cost_value_loss[k]),
            )
