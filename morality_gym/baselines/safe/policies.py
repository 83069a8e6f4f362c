"""Actor-critic policy with a second critic for the cost stream.

Three separate networks, none sharing a layer: the categorical actor, the reward critic ``V`` and
the cost critic ``V_c`` (each [64, 64] tanh by default, as in the paper's PPO-Lag and CPO runs).
Separate networks matter here: CPO moves the actor by a natural-gradient step and the critics by
Adam, and PPO-Lag clips actor and critic gradients separately, so the parameter sets must not
overlap. Two optimisers are built: ``optimizer`` (actor) and ``critic_optimizer`` (both critics;
Adam keeps per-parameter state, so one Adam over both critics steps each exactly as two would).

Initialisation (``weight_init``): ``kaiming_uniform`` is what OmniSafe, which ran the paper's
PPO-Lag and CPO, does: every linear layer's weight is drawn by ``kaiming_uniform_(a=sqrt(5))``
(uniform in ``+-1/sqrt(fan_in)``), biases keep PyTorch's default, the output layers included.
``orthogonal`` is SB3's (gain sqrt(2) hidden, 0.01 for the action head, 1 for values), which starts
from an almost uniform policy; OmniSafe's does not (docs/protocols.md#network-initialisation-and-optimiser).
"""

from __future__ import annotations

import math
from typing import Any, Literal

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import create_mlp
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn

DEFAULT_HIDDEN = [64, 64]
WeightInit = Literal["kaiming_uniform", "orthogonal"]
WEIGHT_INITS: tuple[str, ...] = ("kaiming_uniform", "orthogonal")


class CostActorCriticPolicy(ActorCriticPolicy):
    """SB3 ``ActorCriticPolicy`` plus a cost-value network.

    :param net_arch: ``dict(pi=..., vf=..., cf=...)``: hidden layers of the actor, the reward critic
        and the cost critic (``cf`` is optional and defaults to ``vf``); a list means the same layers
        for all three. Default ``[64, 64]`` each.
    :param cost_net_arch: hidden layers of the cost critic; overrides ``net_arch["cf"]``.
    :param share_features_extractor: defaults to ``False`` here. With the default
        ``FlattenExtractor`` (no parameters) it makes no difference; a shared extractor *with*
        parameters is refused because the actor and critic updates must touch disjoint parameters.
    :param weight_init: ``orthogonal`` (SB3's, the default for a plain policy) or
        ``kaiming_uniform`` (OmniSafe's; SB3's ``ortho_init`` is then off). See the module docstring.

    All other parameters are SB3's; ``activation_fn`` defaults to ``nn.Tanh``.
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        activation_fn: type[nn.Module] = nn.Tanh,
        *args: Any,
        cost_net_arch: list[int] | None = None,
        share_features_extractor: bool = False,
        weight_init: WeightInit = "orthogonal",
        **kwargs: Any,
    ):
        if weight_init not in WEIGHT_INITS:
            raise ValueError(f"weight_init={weight_init!r} is not one of {', '.join(WEIGHT_INITS)}")
        self.weight_init = weight_init
        if weight_init == "kaiming_uniform":
            kwargs["ortho_init"] = False
        if net_arch is None:
            net_arch = {"pi": list(DEFAULT_HIDDEN), "vf": list(DEFAULT_HIDDEN)}
        if cost_net_arch is None:
            if isinstance(net_arch, dict):
                cost_net_arch = list(net_arch.get("cf", net_arch.get("vf", [])))
            else:
                cost_net_arch = list(net_arch)
        self.cost_net_arch = cost_net_arch
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            net_arch,
            activation_fn,
            *args,
            share_features_extractor=share_features_extractor,
            **kwargs,
        )

    def _build(self, lr_schedule: Schedule) -> None:
        super()._build(lr_schedule)
        if self.share_features_extractor and any(True for _ in self.features_extractor.parameters()):
            raise ValueError(
                "CostActorCriticPolicy needs disjoint actor and critic parameters: "
                "use share_features_extractor=False with a features extractor that has parameters"
            )
        # The cost critic reads the critic's features, like the reward critic.
        self.cost_net = nn.Sequential(*create_mlp(self.features_dim, 1, self.cost_net_arch, self.activation_fn)).to(
            self.device
        )
        if self.ortho_init:
            layers = [m for m in self.cost_net if isinstance(m, nn.Linear)]
            for layer in layers[:-1]:
                self.init_weights(layer, gain=2**0.5)
            self.init_weights(layers[-1], gain=1.0)
        if self.weight_init == "kaiming_uniform":
            for module in (self.mlp_extractor.policy_net, self.action_net, *self._critic_modules()):
                for layer in module.modules():
                    if isinstance(layer, nn.Linear):
                        nn.init.kaiming_uniform_(layer.weight, a=math.sqrt(5))
        # Replace SB3's single optimiser (built over every parameter) by one per side.
        lr = lr_schedule(1)
        self.optimizer = self.optimizer_class(self.actor_parameters(), lr=lr, **self.optimizer_kwargs)  # type: ignore[call-arg]
        self.critic_optimizer = self.optimizer_class(self.critic_parameters(), lr=lr, **self.optimizer_kwargs)  # type: ignore[call-arg]

    def actor_parameters(self) -> list[nn.Parameter]:
        """Parameters of ``pi(a|s)``: the order is fixed, so flat vectors over them are stable."""
        modules: list[nn.Module] = [self.pi_features_extractor, self.mlp_extractor.policy_net, self.action_net]
        return [p for m in modules for p in m.parameters()]

    def _critic_modules(self) -> list[nn.Module]:
        return [self.mlp_extractor.value_net, self.value_net, self.cost_net]

    def reward_critic_parameters(self) -> list[nn.Parameter]:
        """Parameters of ``V`` (with the critics' features extractor, if it has any)."""
        modules: list[nn.Module] = [self.mlp_extractor.value_net, self.value_net]
        if not self.share_features_extractor:
            modules.insert(0, self.vf_features_extractor)
        return [p for m in modules for p in m.parameters()]

    def cost_critic_parameters(self) -> list[nn.Parameter]:
        """Parameters of ``V_c``."""
        return list(self.cost_net.parameters())

    def critic_parameters(self) -> list[nn.Parameter]:
        """Parameters of ``V`` and ``V_c`` (the ones the L2 penalty and ``critic_optimizer`` act on)."""
        return self.reward_critic_parameters() + self.cost_critic_parameters()

    def predict_cost_values(self, obs: PyTorchObs) -> th.Tensor:
        """``V_c(s)``, shape ``(batch, 1)``: expected discounted future cost under this policy."""
        features = super(ActorCriticPolicy, self).extract_features(obs, self.vf_features_extractor)
        return self.cost_net(features)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            cost_net_arch=self.cost_net_arch,
            share_features_extractor=self.share_features_extractor,
            weight_init=self.weight_init,
        )
        return data


#: SB3-style alias, so ``policy="MlpPolicy"`` resolves to the cost-aware policy.
MlpPolicy = CostActorCriticPolicy
