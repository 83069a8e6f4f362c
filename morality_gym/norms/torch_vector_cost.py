"""The step-wise moral cost of a :class:`~morality_gym.envs.torch_vector.TorchTrolleyVectorEnv`, as tensors.

:class:`TorchCostWrapper` is the device counterpart of :class:`~morality_gym.norms.wrappers.VecMoralityWrapper`'s
cost: each copy is scored by its own chain bound to its own env id (any mix of chains over any mix
of env ids), with the one step-wise cost, :class:`~morality_gym.norms.cost.StackedCost`, on the env's
device (the same code and bits as on the host). It lives in the norms layer because
the env does not know about chains (the layering is world -> envs -> norms).

It adds ``infos["cost"]`` and leaves the reward as the env gives it: how reward and cost are combined
(``r / 300``, a Lagrangian, shaping) is the algorithm's business, and
:meth:`~morality_gym.norms.reward_cost.RewardCostSpec.transform` applies to tensors as it does to arrays.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch as th
from gymnasium.vector import VectorEnv, VectorWrapper

from morality_gym.constants import BETA
from morality_gym.envs.registry import canonical_env_id
from morality_gym.envs.torch_vector import TorchTrolleyVectorEnv
from morality_gym.norms.chain import MoralityChain
from morality_gym.norms.cost import StackedCost
from morality_gym.norms.metric import BoundChain, bind_chain
from morality_gym.norms.reward_cost import RewardCostSpec

ChainRef = str | MoralityChain | BoundChain
#: The paper's cost: all chain norms, scenario-wide bounds ("minimal"), scale 1, memory cleared per episode.
DEFAULT_SPEC = RewardCostSpec()


class TorchCostWrapper(VectorWrapper):
    """Adds ``infos["cost"]`` (float64 ``[num_envs]`` on the env's device) to a :class:`TorchTrolleyVectorEnv`.

    Args:
        env: the device vector env (possibly wrapped; its ``unwrapped`` must be a ``TorchTrolleyVectorEnv``).
        chains: one chain for every copy (a name such as ``"DualProcess"``, a file, a
            :class:`~morality_gym.norms.chain.MoralityChain`), or a sequence with one entry per
            *block* (``env.block_env_ids``) or one per *copy*. An entry may also be a
            :class:`~morality_gym.norms.metric.BoundChain` of the copy's env id (to set its
            ``relevant`` norms).
        beta: the lexicographic resolution of the chains bound here (0.1 in every run of the paper).
        reward_cost: the cost's ``cost_mode``, ``cost_scale`` and ``cost_reset`` (the reward settings
            are not applied here).

    Event norms are charged on a copy's first violation; the memory is cleared when the copy's
    episode ends (``cost_reset="per_episode"``) or never (``"never"``, what the paper's PPO-Lag and
    CPO runs did). :attr:`bounds` holds each copy's bound chain.
    """

    def __init__(
        self,
        env: VectorEnv,
        chains: ChainRef | Sequence[ChainRef],
        *,
        beta: float = BETA,
        reward_cost: RewardCostSpec = DEFAULT_SPEC,
    ) -> None:
        super().__init__(env)
        base = env.unwrapped
        if not isinstance(base, TorchTrolleyVectorEnv):
            raise TypeError(f"TorchCostWrapper needs a TorchTrolleyVectorEnv, got {type(base).__name__}; "
                            "for the numpy vector envs use morality_gym.norms.wrappers.VecMoralityWrapper")
        self.base = base
        self.reward_cost = reward_cost
        self.bounds: list[BoundChain] = per_copy_bounds(base, chains, beta)
        self.cost = StackedCost.for_copies(self.bounds, reward_cost, base.device)

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        """Reset the env; under ``cost_reset="per_episode"`` also the reset copies' first-violation memory."""
        obs, infos = self.env.reset(seed=seed, options=options)
        if self.reward_cost.cost_reset == "per_episode":
            mask = None if options is None else options.get("reset_mask")
            self.cost.reset(None if mask is None else th.as_tensor(mask, dtype=th.bool, device=self.base.device))
        return obs, infos

    def step(self, actions: Any) -> tuple[Any, th.Tensor, th.Tensor, th.Tensor, dict[str, Any]]:
        obs, reward, terminated, truncated, infos = self.env.step(actions)
        utility = self.base.utility(infos["transition"])
        infos["cost"] = self.cost(infos["events"], utility, terminated | truncated)
        return obs, reward, terminated, truncated, infos


def per_copy_bounds(env: TorchTrolleyVectorEnv, chains: ChainRef | Sequence[ChainRef], beta: float = BETA) -> list[BoundChain]:
    """Each copy's chain bound to its env id; binding is done once per (chain, env id)."""
    entries: Sequence[ChainRef]
    if isinstance(chains, (str, MoralityChain, BoundChain)):
        entries = [chains] * env.num_envs
    elif len(chains) == env.num_envs:
        entries = chains
    elif len(chains) == len(env.block_env_ids):
        entries = [c for c in chains for _ in range(env.copies_per_env)]
    else:
        raise ValueError(f"chains: give one chain, one per block ({len(env.block_env_ids)}) or one per copy ({env.num_envs}), "
                         f"not {len(chains)}")
    bound: dict[tuple[int, str], BoundChain] = {}
    out = []
    for entry, env_id in zip(entries, env.env_ids):
        key = (id(entry), env_id)
        if key not in bound:
            bound[key] = _bind(entry, env_id, beta)
        out.append(bound[key])
    return out


def _bind(entry: ChainRef, env_id: str, beta: float) -> BoundChain:
    """``entry`` bound to ``env_id``; a bound chain must already be bound to that env id."""
    if isinstance(entry, BoundChain):
        if canonical_env_id(entry.env_id.split("/", 1)[-1]) != env_id:
            raise ValueError(f"a BoundChain of {entry.env_id} was given for a copy of {env_id}")
        return entry
    return bind_chain(entry, env_id, beta)
