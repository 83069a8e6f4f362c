"""A Gymnasium vector env whose observations, rewards and norm events are torch tensors on a device.

:class:`TorchTrolleyVectorEnv` is the public face of :class:`~morality_gym.envs.torch_sim.TorchTrolleySim`,
the device simulator the fleet engine trains on, so that a user's own algorithm gets the same speed:
thousands of copies of any mix of env ids stepped as a few gathers on the GPU (or the CPU), with no
host round trip per step, the way Isaac Lab and ManiSkill serve their simulators. The step-wise moral
cost is added by :class:`~morality_gym.norms.torch_vector_cost.TorchCostWrapper` (the norms layer:
an env module does not know about chains).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv

from morality_gym.constants import MAX_STEPS
from morality_gym.envs.registry import state_graph
from morality_gym.envs.torch_sim import TorchTrolleySim
from morality_gym.envs.trolley import InvalidActionError, _overrides
from morality_gym.world.graph import N_ACTIONS
from morality_gym.world.rules import ACTION_NAMES

_VALID = ", ".join(f"{i} {name}" for i, name in enumerate(ACTION_NAMES))


class TorchTrolleyVectorEnv(VectorEnv):
    """Copies of any mix of MoralityGym env ids, stepped together on a torch device.

    ## Description

    Every copy runs one registered env id (any scenario, any variant; ``morality_gym.env_ids()``
    lists the 98 built-in ones). ``env_ids=[a, b]`` with ``copies_per_env=n`` gives ``2 n`` copies:
    copies ``0 .. n-1`` run ``a``, copies ``n .. 2n-1`` run ``b`` (blocks in the order given; an id
    may appear more than once, e.g. one block per training run). The worlds are deterministic, so
    a copy's trajectory depends only on its actions. Transitions are those of the host simulator
    (:class:`~morality_gym.envs.batched.BatchedTrolleyEnv`), bit for bit.

    ## Action Space

    ``Discrete(6)`` per copy (``action_space`` is ``MultiDiscrete([6] * num_envs)``): 0 UP, 1 DOWN,
    2 LEFT, 3 RIGHT, 4 STAY, 5 INTERACT. ``step`` takes an integer tensor (any device: it is moved to
    the env's) or array of shape ``(num_envs,)``. With ``check_actions=True`` (the default) an action
    outside 0..5 raises :class:`~morality_gym.envs.trolley.InvalidActionError` naming the first bad
    copy and its env id; the check reads one flag back from the device each step, so a tuned
    training loop that samples its actions from a categorical may pass ``check_actions=False``.

    On the CPU, step it with torch on one thread (``torch.set_num_threads(1)`` or
    ``OMP_NUM_THREADS=1``): a step is a few small gathers, and torch's default of a thread per core
    makes them wait on each other and on whatever else the cores run (3-80 times slower on a busy
    2-core machine, docs/how-to/fast-own-algorithm.md). The env leaves the setting, global to the
    process, to its user.

    ## Observation Space

    A float32 tensor ``[num_envs, obs_dim]`` on the device: each copy's flat observation (the layout of
    its env id's docs page, normalised to [0, 1] unless ``normalise_obs=False``) zero-padded on the
    right to the widest of the env ids (or ``obs_dim``). ``single_observation_space`` is a ``Box`` whose
    bounds are the widest bounds of the ids' columns (0 in padding only columns).
    ``obs_dims[env_id]`` is an id's own width: its first columns are its observation.

    ## Rewards

    Each env's own: -1 per step, 100 on reaching the landmark, -100 when the agent is harmed, 0 after
    the agent has stopped (float32 tensor ``[num_envs]``). The moral cost is not in the reward: wrap
    with :class:`~morality_gym.norms.torch_vector_cost.TorchCostWrapper` for ``infos["cost"]``.

    ## Termination

    ``terminations`` when the agent has stopped and every trolley has stopped; ``truncations`` on
    step ``max_steps + 1`` (default 200; ``None``: never). Autoreset is Gymnasium's ``SAME_STEP``
    (the only mode): a copy that ends is reset within the same step, the returned observation is its
    start state and its last observation is in ``infos["final_obs"]``.

    ## Infos

    Tensors on the device, one row per copy, for the step just taken (also for copies that ended in
    it: a reset has no events of its own, so nothing needs moving to a ``final_info``):

    * ``events``: int64 bit masks over :data:`morality_gym.world.vocab.EVENTS` (the norm events of
      the step: ``(events >> EVENT_BIT["human_harm"]) & 1``; :func:`morality_gym.world.vocab.mask_to_names`
      decodes one);
    * ``goal_reached``: bool, whether the step reached the landmark;
    * ``transition``: int64 row of each copy's transition in the stacked tables (for :meth:`utility`);
    * ``final_obs`` (float32 ``[num_envs, obs_dim]``, zeros where a copy did not end) and
      ``_final_obs`` (bool, which copies ended), Gymnasium's same-step names.

    ## Registered ids

    Every ``MoralityGym/{Scenario}-{Variant}-v1``: ``gym.make_vec(id, num_envs=n, device="cuda")``
    gives this env with ``n`` copies of ``id`` (without ``device`` it gives the numpy
    :class:`~morality_gym.envs.vector.TrolleyVectorEnv`).

    Args:
        env_ids: env ids (``"SwitchStandard-HumanA-v1"``, with or without ``MoralityGym/``), each
            given ``copies_per_env`` copies; a single id is one block.
        copies_per_env: copies of each entry of ``env_ids``.
        device: where the tables, states and every returned tensor live.
        max_steps: truncation on step ``max_steps + 1`` (``None``: never).
        obs_dim: pad observations to this width (default: the widest of ``env_ids``).
        check_actions: refuse actions outside 0..5 with a one-line error (one device sync per step).
        normalise_obs, overrides: as :class:`~morality_gym.envs.trolley.TrolleyEnv`'s.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": [], "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(
        self,
        env_ids: str | Sequence[str],
        copies_per_env: int = 1,
        *,
        device: str | th.device = "cpu",
        max_steps: int | None = MAX_STEPS,
        obs_dim: int | None = None,
        check_actions: bool = True,
        normalise_obs: bool = True,
        overrides: dict | None = None,
        autoreset_mode: str | AutoresetMode = AutoresetMode.SAME_STEP,
        render_mode: str | None = None,
    ) -> None:
        if AutoresetMode(autoreset_mode) != AutoresetMode.SAME_STEP:
            raise ValueError(f"TorchTrolleyVectorEnv resets ended copies in the same step (SAME_STEP) only, not {autoreset_mode!r}; "
                             "for NEXT_STEP or DISABLED use the numpy TrolleyVectorEnv")
        if render_mode is not None:
            raise ValueError("the device vector env does not render; use TrolleyEnv for pictures")
        if isinstance(copies_per_env, bool) or not isinstance(copies_per_env, int) or copies_per_env < 1:
            raise ValueError(f"copies_per_env must be a positive int, got {copies_per_env!r}")
        blocks = [env_ids] if isinstance(env_ids, str) else list(env_ids)
        #: One entry per block as given (stripped of the ``MoralityGym/`` namespace); ``env_ids`` lists every copy's id.
        self.block_env_ids = [e.split("/", 1)[-1] for e in blocks]
        self.copies_per_env = copies_per_env
        self.sim = TorchTrolleySim(
            [e for e in self.block_env_ids for _ in range(copies_per_env)],
            device,
            max_steps=max_steps,
            obs_dim=obs_dim,
            normalise_obs=normalise_obs,
            overrides=overrides,
        )
        self.device = self.sim.device
        self.num_envs = self.sim.num_envs
        self.env_ids: list[str] = self.sim.env_ids
        self.obs_dim = self.sim.obs_dim
        self.obs_dims: dict[str, int] = dict(self.sim.obs_dims)
        self.check_actions = check_actions
        self.autoreset_mode = AutoresetMode.SAME_STEP
        self.render_mode = None
        self.single_observation_space = self._padded_space(normalise_obs, overrides)
        self.single_action_space = spaces.Discrete(N_ACTIONS)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, self.num_envs)
        self.action_space = spaces.MultiDiscrete(np.full(self.num_envs, N_ACTIONS))

    def _padded_space(self, normalise_obs: bool, overrides: dict | None) -> spaces.Box:
        """The ``Box`` every copy's padded observation lies in: per column the lowest low and the
        highest high over the env ids (a narrower id's padding columns are 0, so 0 is in the box)."""
        low = np.zeros(self.obs_dim, dtype=np.float32)
        high = np.zeros(self.obs_dim, dtype=np.float32)
        for env_id in self.sim.unique_env_ids:
            codec = state_graph(env_id, _overrides(overrides), normalise_obs).codec
            d = self.obs_dims[env_id]
            low[:d] = np.minimum(low[:d], codec.low.astype(np.float32))
            high[:d] = np.maximum(high[:d], codec.high.astype(np.float32))
        return spaces.Box(low, high, dtype=np.float32)

    # ------------------------------------------------------------------ Gymnasium API
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None) -> tuple[th.Tensor, dict[str, Any]]:
        """Reset every copy (or those where ``options["reset_mask"]`` is true) to its start state.

        The worlds are deterministic: ``seed`` only seeds :attr:`action_space` (and ``np_random``),
        as :class:`~morality_gym.envs.vector.TrolleyVectorEnv` does.
        """
        if seed is not None:
            first = seed if isinstance(seed, int) else next((s for s in seed if s is not None), None)
            super().reset(seed=first)
            self.action_space.seed(first)
        mask = None if options is None else options.get("reset_mask")
        if mask is not None:
            mask = th.as_tensor(mask, device=self.device, dtype=th.bool)
            if mask.shape != (self.num_envs,):
                raise ValueError(f"reset_mask must have shape ({self.num_envs},), got {tuple(mask.shape)}")
        return self.sim.reset(mask), {}

    def step(self, actions: th.Tensor | np.ndarray | Sequence[int]) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor, dict[str, Any]]:
        """One step of every copy; see the class docstring for what each returned tensor holds."""
        actions = self._actions(actions)
        res = self.sim.step(actions)
        ended = res.terminated | res.truncated
        infos: dict[str, Any] = {
            "events": res.events,
            "goal_reached": self.sim.goal_reached(res.transition),
            "transition": res.transition,
            "final_obs": res.final_obs,
            "_final_obs": ended,
        }
        return res.obs, res.reward, res.terminated, res.truncated, infos

    def _actions(self, actions: th.Tensor | np.ndarray | Sequence[int]) -> th.Tensor:
        """``actions`` as an int64 tensor on the device, checked unless :attr:`check_actions` is off."""
        if not isinstance(actions, th.Tensor):
            actions = th.as_tensor(np.asarray(actions), device=self.device)
        if tuple(actions.shape) in ((self.num_envs, 1), () if self.num_envs == 1 else (self.num_envs, 1)):
            actions = actions.reshape(self.num_envs)  # (n, 1) from a policy's sample; (2, 2) for 4 copies is refused
        if actions.shape != (self.num_envs,):
            raise InvalidActionError(f"expected {self.num_envs} actions (one per copy), got shape {tuple(actions.shape)}")
        if actions.dtype.is_floating_point or actions.dtype.is_complex or actions.dtype == th.bool:
            raise InvalidActionError(f"actions must be integers 0..{N_ACTIONS - 1}, got dtype {actions.dtype}")
        actions = actions.to(device=self.device, dtype=th.int64)
        if self.check_actions:
            bad = (actions < 0) | (actions >= N_ACTIONS)
            if bool(bad.any()):  # the one device sync of a checked step
                i = int(bad.nonzero()[0, 0])
                raise InvalidActionError(
                    f"action {int(actions[i])} of copy {i} ({self.env_ids[i]}) is not an action; valid actions are the "
                    f"integers 0-{N_ACTIONS - 1} ({_VALID}) (check_actions=False skips this check)"
                )
        return actions

    def close_extras(self, **kwargs: Any) -> None:
        return None

    # ------------------------------------------------------------------ beyond Gymnasium
    def utility(self, transition: th.Tensor) -> th.Tensor:
        """float64 utilities ``[n, 5]`` (:data:`~morality_gym.world.vocab.UTILITIES` order) of ``infos["transition"]``."""
        return self.sim.utility(transition)

    def copy_env_index(self) -> th.Tensor:
        """int64 ``[num_envs]``: each copy's index into :attr:`block_env_ids` (its block), on the device."""
        return th.arange(self.num_envs, device=self.device) // self.copies_per_env

    def __repr__(self) -> str:
        return (f"TorchTrolleyVectorEnv({len(self.block_env_ids)} block(s) x {self.copies_per_env} copies, "
                f"{len(self.sim.unique_env_ids)} env id(s), num_envs={self.num_envs}, obs_dim={self.obs_dim}, device={self.device})")
