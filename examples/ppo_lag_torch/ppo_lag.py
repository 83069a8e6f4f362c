"""PPO-Lagrangian on MoralityGym's device vector env, in one file to read top to bottom.

Every run of the chosen Table 1 cells (one per variant and seed: 12 variants x 3 seeds = 36 runs
for a cell at the paper preset) trains at once, as an independent agent: each run's networks are a
slice of stacked weights ``[runs, in, out]`` (one batched matrix product per layer for all runs),
its copies are one block of a :class:`morality_gym.TorchTrolleyVectorEnv` (any mix of env ids), and
its step-wise moral cost comes from :class:`morality_gym.TorchCostWrapper` (any mix of chains). The
losses are summed over runs, so each run's gradient is its own; Adam is element-wise, and gradients
are clipped per run, so the runs do not share anything numerical (they share one random stream for
action draws and minibatch order).

After training, each run's actor is evaluated by the project's own evaluation (Monte Carlo episodes
at the preset's seeds, and the exact expectation) through ``leaderboard.submit``, which writes the
run files that ``python -m leaderboard.build`` shows beside the baselines.

    python examples/ppo_lag_torch/ppo_lag.py --cells Utility/SwitchStandard --total-steps 200000 --results results
    python examples/ppo_lag_torch/ppo_lag.py --device cuda --num-envs 256 ...   # on a GPU
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import itertools
import math
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch as th
from torch import nn

import morality_gym
from leaderboard.submit import Cell, Submission, build_hint, check_name, preset_facts, select_cells, submit
from morality_gym.baselines.policy_ref import LoadedPolicy
from morality_gym.constants import BETA, MAX_STEPS
from morality_gym.envs.registry import scenario_named
from morality_gym.norms.reward_cost import RewardCostSpec


@dataclass
class Args:
    cells: list[str] = field(default_factory=lambda: ["Utility/SwitchStandard"])  # Table 1 cells, chain/scenario
    variants: list[str] = field(default_factory=list)  # keep only these variants (default: all of each scenario)
    preset: str = "paper"  # seeds (one run per seed) and evaluation episodes, from conf/preset
    protocol: str = "paper"  # the leaderboard group the entry appears in (the evaluation is the same)
    name: str = "PPO-Lag (torch example)"  # the entry's name on the leaderboard
    results: str = "results"  # results directory the run files go to
    device: str = "cpu"  # torch device the runs train on: cpu, cuda, cuda:1
    total_steps: int = 200_000  # environment steps per run, whole updates of num_envs x num_steps (at least one); recorded as the runs' budget
    num_envs: int = 16  # copies per run
    num_steps: int = 128  # rollout length: num_envs * num_steps = 2,048 steps per run per update
    num_minibatches: int = 4  # minibatches per epoch over a run's rollout
    update_epochs: int = 4  # passes over each rollout
    learning_rate: float = 3e-4  # Adam's step size (actor and both critics)
    anneal_lr: bool = True  # anneal the learning rate linearly to 0 over the updates
    gamma: float = 0.99  # discount of rewards and costs
    gae_lambda: float = 0.95  # GAE's lambda
    clip_coef: float = 0.2  # PPO's ratio clip
    ent_coef: float = 0.0  # entropy bonus coefficient
    vf_coef: float = 0.5  # weight of the two critics' losses
    max_grad_norm: float = 0.5  # gradient norm clip, per run
    cost_limit: float = 0.0  # per-episode cost the Lagrangian allows (the paper's: none)
    lagrange_init: float = 0.001  # the Lagrange multiplier's starting value
    lagrange_lr: float = 0.035  # Adam's step size for the multiplier
    reward_scale: float = 300.0  # rewards are divided by it (the paper's r / 300)
    cost_adv_std: bool = True  # standardise the cost advantages too (the paper's PPO-Lag only centres them: see README)
    hidden: int = 64  # width of the two hidden layers of each network
    gif: bool = False  # record one evaluation episode per run for its leaderboard page
    log_every: int = 10  # updates between progress lines
    threads: int = 1  # torch CPU threads: the matrices are small, more threads cost more than they gain
    load: str = ""  # evaluate and submit the weights saved by an earlier run of the same runs instead of training


def field_help() -> dict[str, str]:
    """Each field's comment in :class:`Args`: the one description of a flag, read for ``--help``."""
    lines, _ = inspect.getsourcelines(Args)
    found = (re.match(r"\s+(\w+): .*?  # (.*)$", line) for line in lines)
    return {m[1]: m[2].replace("%", "%%") for m in found if m}  # argparse formats help with %


def steps_per_update(args: Args) -> int:
    return args.num_envs * args.num_steps


def parse_args(argv: list[str] | None = None) -> Args:
    """``--flag value`` for every field of :class:`Args` (lists take several values), each described
    by the field's comment with its default; a budget under one update is refused, not raised."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    described = field_help()
    for f in dataclasses.fields(Args):
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        flag = "--" + f.name.replace("_", "-")
        text = f"{described[f.name]} (default: %(default)s)"
        if isinstance(default, bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=default, help=described[f.name])
        elif isinstance(default, list):
            parser.add_argument(flag, nargs="*", default=default, help=text)
        else:
            parser.add_argument(flag, type=type(default), default=default, help=text)
    args = Args(**vars(parser.parse_args(argv)))
    if args.total_steps < steps_per_update(args) and not args.load:
        parser.exit(2, f"error: --total-steps {args.total_steps:,} is less than one update ({args.num_envs} copies x "
                       f"{args.num_steps} steps = {steps_per_update(args):,} steps per run); ask at least that\n")
    return args


# ------------------------------------------------------------------------------------ networks
class StackedMLP(nn.Module):
    """``runs`` independent tanh MLPs as one module: input ``[runs, batch, in]``, output ``[runs, batch, out]``.

    Each run's weights are drawn with its own generator (CleanRL's orthogonal init), so a run starts
    from the same weights whichever runs train beside it.
    """

    def __init__(self, sizes: list[int], out_gain: float, generators: list[th.Generator]) -> None:
        super().__init__()
        self.weights, self.biases = nn.ParameterList(), nn.ParameterList()
        for i, (n_in, n_out) in enumerate(itertools.pairwise(sizes)):
            gain = out_gain if i == len(sizes) - 2 else math.sqrt(2)
            w = th.empty(len(generators), n_out, n_in)
            for run, gen in enumerate(generators):
                nn.init.orthogonal_(w[run], gain, generator=gen)
            self.weights.append(nn.Parameter(w.transpose(1, 2).contiguous()))
            self.biases.append(nn.Parameter(th.zeros(len(generators), 1, n_out)))

    def forward(self, x: th.Tensor) -> th.Tensor:
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            x = th.baddbmm(b, x, w)
            x = th.tanh(x) if i < len(self.weights) - 1 else x
        return x


def clip_grad_per_run(params: list[nn.Parameter], max_norm: float) -> None:
    """``clip_grad_norm_`` for each run separately (dimension 0 of every parameter is the run)."""
    sq = sum(p.grad.pow(2).flatten(1).sum(1) for p in params)
    scale = (max_norm / (sq.sqrt() + 1e-6)).clamp(max=1.0)
    for p in params:
        p.grad.mul_(scale.view(-1, *[1] * (p.dim() - 1)))


class Policy:
    """One run's actor as the callable ``obs -> 6 probabilities`` the project's evaluators take (numpy, float64)."""

    def __init__(self, actor: StackedMLP, run: int, obs_dim: int) -> None:
        self.layers = [(w[run].detach().cpu().double().numpy(), b[run, 0].detach().cpu().double().numpy())
                       for w, b in zip(actor.weights, actor.biases)]
        self.obs_dim = obs_dim

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        x = np.zeros(self.obs_dim)
        x[: len(obs)] = obs  # padded as the vector env padded it in training
        for i, (w, b) in enumerate(self.layers):
            x = x @ w + b
            x = np.tanh(x) if i < len(self.layers) - 1 else x
        p = np.exp(x - x.max())
        return p / p.sum()


# ------------------------------------------------------------------------------------ training
def train(args: Args, runs: list[tuple[Cell, str, int]]) -> tuple[StackedMLP, int, dict[str, float]]:
    """Train one agent per run (cell, env id, seed) for ``args.total_steps`` steps each."""
    device = th.device(args.device)
    K, n, T = len(runs), args.num_envs, args.num_steps
    env = morality_gym.TorchTrolleyVectorEnv([e for _, e, _ in runs], copies_per_env=n, device=device, check_actions=False)
    env = morality_gym.TorchCostWrapper(env, [c.chain for c, _, _ in runs], reward_cost=RewardCostSpec(cost_reset="per_episode"))
    D = env.unwrapped.obs_dim
    th.manual_seed(runs[0][2])  # the shared stream: action draws and minibatch order
    gens = [th.Generator().manual_seed(seed) for _, _, seed in runs]
    actor = StackedMLP([D, args.hidden, args.hidden, 6], 0.01, gens).to(device)
    critic = StackedMLP([D, args.hidden, args.hidden, 1], 1.0, gens).to(device)
    cost_critic = StackedMLP([D, args.hidden, args.hidden, 1], 1.0, gens).to(device)
    params = [*actor.parameters(), *critic.parameters(), *cost_critic.parameters()]
    optimizer = th.optim.Adam(params, lr=args.learning_rate, eps=1e-5)
    lagrange = th.full((K,), args.lagrange_init, device=device, requires_grad=True)
    lagrange_opt = th.optim.Adam([lagrange], lr=args.lagrange_lr)

    # Rollout storage, [step, run, copy]; a run's copies are one block of the env's copies.
    obs_buf = th.zeros((T, K, n, D), device=device)
    act_buf = th.zeros((T, K, n), dtype=th.int64, device=device)
    logp_buf, rew_buf, cost_buf, done_buf, val_buf, cval_buf = (th.zeros((T, K, n), device=device) for _ in range(6))
    ep_ret, ep_cost = th.zeros((K, n), device=device), th.zeros((K, n), device=device)
    jc = th.zeros(K, device=device)  # mean episode cost of each run's last rollout (J_c)
    last = {"return": float("nan"), "cost": float("nan")}

    obs = env.reset(seed=runs[0][2])[0].view(K, n, D)
    num_updates = args.total_steps // (n * T)  # at least one: parse_args refuses less
    start, cpu_start = time.perf_counter(), time.process_time()
    for update in range(1, num_updates + 1):
        if args.anneal_lr:
            optimizer.param_groups[0]["lr"] = args.learning_rate * (1.0 - (update - 1) / num_updates)
        done_ret, done_cost, done_n = th.zeros(K, device=device), th.zeros(K, device=device), th.zeros(K, device=device)
        for t in range(T):
            with th.no_grad():
                logp_all = th.log_softmax(actor(obs), -1)
                action = th.multinomial(logp_all.exp().view(K * n, 6), 1).view(K, n)
                obs_buf[t], act_buf[t], logp_buf[t] = obs, action, logp_all.gather(-1, action.unsqueeze(-1)).squeeze(-1)
                val_buf[t], cval_buf[t] = critic(obs).squeeze(-1), cost_critic(obs).squeeze(-1)
            next_obs, reward, term, trunc, infos = env.step(action.view(K * n))
            reward, cost = reward.view(K, n), infos["cost"].view(K, n).float()
            term, trunc = term.view(K, n), trunc.view(K, n)
            ended = term | trunc
            ep_ret, ep_cost = ep_ret + reward, ep_cost + cost
            done_ret += (ep_ret * ended).sum(1)
            done_cost += (ep_cost * ended).sum(1)
            done_n += ended.sum(1)
            ep_ret, ep_cost = ep_ret * ~ended, ep_cost * ~ended
            rew_buf[t], cost_buf[t] = reward / args.reward_scale, cost
            with th.no_grad():  # a truncated episode goes on: bootstrap with the critics' value of its last observation
                final = infos["final_obs"].view(K, n, D)
                cut = (trunc & ~term).float()
                rew_buf[t] += args.gamma * critic(final).squeeze(-1) * cut
                cost_buf[t] += args.gamma * cost_critic(final).squeeze(-1) * cut
            done_buf[t] = ended.float()
            obs = next_obs.view(K, n, D)

        # Generalised advantage estimates of reward and cost; done_buf[t] = the episode ended at step t.
        with th.no_grad():
            adv, cadv = th.zeros_like(rew_buf), th.zeros_like(cost_buf)
            next_val, next_cval = critic(obs).squeeze(-1), cost_critic(obs).squeeze(-1)
            gae, cgae = th.zeros((K, n), device=device), th.zeros((K, n), device=device)
            for t in reversed(range(T)):
                live = 1.0 - done_buf[t]
                gae = rew_buf[t] + args.gamma * next_val * live - val_buf[t] + args.gamma * args.gae_lambda * live * gae
                cgae = cost_buf[t] + args.gamma * next_cval * live - cval_buf[t] + args.gamma * args.gae_lambda * live * cgae
                adv[t], cadv[t] = gae, cgae
                next_val, next_cval = val_buf[t], cval_buf[t]
            ret, cret = adv + val_buf, cadv + cval_buf

        # The Lagrange multiplier: gradient ascent on lambda * (J_c - limit), lambda >= 0, per run.
        jc = th.where(done_n > 0, done_cost / done_n.clamp(min=1), jc)
        lagrange_opt.zero_grad()
        (-(lagrange * (jc - args.cost_limit)).sum()).backward()
        lagrange_opt.step()
        with th.no_grad():
            lagrange.clamp_(min=0.0)
        lam = lagrange.detach().view(K, 1)

        # Per run over the rollout: advantages standardised (costs' only centred with --no-cost-adv-std), then combined.
        def b(x: th.Tensor) -> th.Tensor:  # [T, K, n, ...] -> [K, T * n, ...]: a run's rollout in one row
            return x.transpose(0, 1).reshape(K, T * n, *x.shape[3:])

        b_obs, b_act, b_logp, b_ret, b_cret = b(obs_buf), b(act_buf), b(logp_buf), b(ret), b(cret)
        b_adv, b_cadv = b(adv), b(cadv)
        b_adv = (b_adv - b_adv.mean(1, keepdim=True)) / (b_adv.std(1, keepdim=True) + 1e-8)
        b_cadv = b_cadv - b_cadv.mean(1, keepdim=True)
        b_cadv = b_cadv / (b_cadv.std(1, keepdim=True) + 1e-8) if args.cost_adv_std else b_cadv
        b_adv = (b_adv - lam * b_cadv) / (1.0 + lam)

        mb = T * n // args.num_minibatches
        for _ in range(args.update_epochs):
            order = th.randperm(T * n, device=device)
            for i in range(0, T * n, mb):
                idx = order[i : i + mb]
                logp_all = th.log_softmax(actor(b_obs[:, idx]), -1)
                logp = logp_all.gather(-1, b_act[:, idx].unsqueeze(-1)).squeeze(-1)
                ratio = (logp - b_logp[:, idx]).exp()
                a = b_adv[:, idx]
                pg_loss = th.max(-a * ratio, -a * ratio.clamp(1 - args.clip_coef, 1 + args.clip_coef)).mean(1)
                v_loss = 0.5 * (critic(b_obs[:, idx]).squeeze(-1) - b_ret[:, idx]).pow(2).mean(1)
                vc_loss = 0.5 * (cost_critic(b_obs[:, idx]).squeeze(-1) - b_cret[:, idx]).pow(2).mean(1)
                loss = pg_loss + args.vf_coef * (v_loss + vc_loss) + args.ent_coef * (logp_all.exp() * logp_all).sum(-1).mean(1)
                optimizer.zero_grad()
                loss.sum().backward()  # a sum over runs: each run's gradient is that of its own loss
                clip_grad_per_run(params, args.max_grad_norm)
                optimizer.step()

        if done_n.sum() > 0:
            last = {"return": float(done_ret.sum() / done_n.sum()), "cost": float(done_cost.sum() / done_n.sum())}
        if update % args.log_every == 0 or update == num_updates:
            steps = update * n * T
            sps = K * steps / (time.perf_counter() - start)
            print(f"update {update}/{num_updates}: {steps:,} steps per run, {sps:,.0f} env steps/s ({sps / K:,.0f} per run), "
                  f"episode return {last['return']:.1f}, cost {last['cost']:.3f}, lambda {float(lagrange.detach().mean()):.3f}", flush=True)
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    steps = num_updates * n * T
    return actor, D, {"runs": K, "steps_per_run": steps, "seconds": seconds, "env_steps_per_s": K * steps / seconds,
                      "env_steps_per_cpu_s": K * steps / cpu_seconds}


# ------------------------------------------------------------------------------------ evaluation
def save_actor(args: Args, runs: list[tuple[Cell, str, int]], actor: StackedMLP) -> Path:
    """The trained weights, beside the run files (their bytes are part of each run's identity)."""
    out = Path(args.results)
    out.mkdir(parents=True, exist_ok=True)
    weights = out / "ppo_lag_torch_actor.pt"
    th.save({"runs": [(c.chain.name, e, s) for c, e, s in runs], "actor": actor.state_dict(), "args": dataclasses.asdict(args)}, weights)
    return weights


def evaluate_and_submit(args: Args, runs: list[tuple[Cell, str, int]], actor: StackedMLP, obs_dim: int, weights: Path,
                        trained: Args | None = None) -> None:
    """Each run's policy, evaluated as every trained run of a sweep is, written as run files that
    record the budget it trained for (``trained``: the flags it trained with, when not ``args``), so
    that a 2,048-step entry is marked not comparable beside 1M-step baselines."""
    trained = args if trained is None else trained
    steps = trained.total_steps // steps_per_update(trained) * steps_per_update(trained)
    out = Path(args.results)
    out.mkdir(parents=True, exist_ok=True)
    _, episodes = preset_facts(args.preset)
    for k, (cell, env_id, seed) in enumerate(runs):
        # The run files' identity hashes these files: retrained weights make new runs (the old ones superseded).
        loaded = LoadedPolicy(ref=f"{Path(__file__).name}:Policy", kind="callable",  # one ref: one configuration
                              policy=Policy(actor, k, obs_dim), files=(Path(__file__).resolve(), weights.resolve()))
        sub = Submission(name=check_name(args.name), loaded=loaded, sha256=loaded.sha256(), submitter=os.environ.get("USER") or "unknown",
                         protocol=args.protocol, preset=args.preset, seeds=(seed,), eval_episodes=episodes,
                         beta=BETA, max_steps=MAX_STEPS, gif=args.gif, budget=trained.total_steps, trained_steps=steps)
        variant = env_id.split("-")[1]
        submit(sub, [Cell(cell.chain, cell.scenario, (variant,))], out, say=lambda line: print(line) if line.startswith("  ") else None)
    print(f"wrote the runs to {out / 'runs'}; now: {build_hint(out)}")


def load_actor(path: str, runs: list[tuple[Cell, str, int]]) -> tuple[StackedMLP, int, Path, Args]:
    """The actor saved by :func:`evaluate_and_submit` for exactly these runs (e.g. trained on a GPU machine)."""
    saved = th.load(path, map_location="cpu")
    if [tuple(r) for r in saved["runs"]] != [(c.chain.name, e, s) for c, e, s in runs]:
        raise SystemExit(f"{path} holds the weights of other runs; give the same --cells, --variants and --preset")
    shapes = [w.shape for name, w in saved["actor"].items() if name.startswith("weights.")]
    actor = StackedMLP([shapes[0][1], *(s[2] for s in shapes)], 1.0, [th.Generator() for _ in runs])
    actor.load_state_dict(saved["actor"])
    known = {f.name for f in dataclasses.fields(Args)}
    return actor, shapes[0][1], Path(path), Args(**{k: v for k, v in saved["args"].items() if k in known})


def main(argv: list[str] | None = None) -> dict[str, float]:
    args = parse_args(argv)
    th.set_num_threads(args.threads)
    pairs = [c.split("/") for c in args.cells]
    cells = [cell for chain, scenario in pairs for cell in select_cells([chain], [scenario], args.variants)]
    seeds, _ = preset_facts(args.preset)
    runs = [(cell, scenario_named(cell.scenario).env_id(v), seed) for cell in cells for v in cell.variants for seed in seeds]
    if args.load:
        evaluate_and_submit(args, runs, *load_actor(args.load, runs))
        return {}
    steps = args.total_steps // steps_per_update(args) * steps_per_update(args)
    rounded = "" if steps == args.total_steps else f" (--total-steps {args.total_steps:,} rounded down to whole updates of {steps_per_update(args):,})"
    print(f"training {len(runs)} runs ({len(cells)} cell(s) x variants x {len(seeds)} seed(s)) on {args.device}, "
          f"{steps:,} steps each{rounded}, {th.get_num_threads()} torch thread(s)", flush=True)
    actor, obs_dim, speed = train(args, runs)
    print(f"trained in {speed['seconds']:.1f} s: {speed['env_steps_per_s']:,.0f} env steps/s, "
          f"{speed['env_steps_per_s'] / len(runs):,.0f} per run ({speed['env_steps_per_cpu_s']:,.0f} per CPU-second)", flush=True)
    evaluate_and_submit(args, runs, actor, obs_dim, save_actor(args, runs, actor))
    return speed


if __name__ == "__main__":
    main()
