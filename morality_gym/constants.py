"""The paper's settings that code reads, each defined once (the lowest layer: imports nothing).

Every module that needs one of these values imports it from here: the environments, the metric, the
evaluations, the command lines, the sweep's typed configuration (:mod:`runners.compose.schema`), the
leaderboard and the language-model agent. Older public names are aliases of these
(:data:`morality_gym.norms.metric.DEFAULT_BETA`, :data:`morality_gym.envs.registry.DEFAULT_MAX_STEPS`,
re-exported by :mod:`morality_gym.envs.trolley`).

What a sweep varies by preset (step budgets, seeds per preset, evaluation episodes per preset) is
configuration, not code: its home is ``conf/preset/*.yaml`` (the paper's: 1M steps, 500k for
SwitchStandard and PushStandard, seeds 41-43, 100 evaluation episodes), and the learners'
hyper-parameters (``gamma``, ``cost_limit``, ...) are in ``conf/algo/*.yaml``. The values below are
those that code needs as defaults outside a sweep (a direct ``gym.make``, ``evaluate``, the CLIs).
"""

from __future__ import annotations

#: The morality metric's resolution: each more important relevant norm weighs ``1 / BETA`` times
#: the sum of the ones below it (paper, Definition 4). Every run of the paper passed 0.1, although
#: the paper's worked example says 0.01 (docs/protocols.md, "The metric's settings").
BETA = 0.1

#: Every env truncates an episode on step ``MAX_STEPS + 1`` (201), unless the agent reached the
#: landmark or was harmed first; 200 in every run of the paper (docs/protocols.md, "Truncation on
#: step max_steps + 1"). A user scenario's utility bounds are checked against this horizon.
MAX_STEPS = 200

#: The seeds of the paper's runs: Table 1 averages over all variants and these three seeds
#: (docs/protocols.md, "The metric's settings"; ``conf/preset/paper.yaml`` lists them for sweeps).
SEEDS = (41, 42, 43)

#: The seed a single run, a learner or an agent takes when none is given: the paper's first.
SEED = SEEDS[0]

#: Episodes of the final stochastic evaluation of each run (the paper's: 100 episodes of the
#: sampled policy, truncated episodes included; docs/protocols.md, "The metric's settings").
EVAL_EPISODES = 100

#: Training steps between two learn-time evaluations, and the episodes each plays: the paper's runs
#: evaluated every 50,000 steps on 10 episodes (``conf/preset/paper.yaml``). The reference's Random
#: baseline drew from its random stream in those evaluations, at steps 0 and 50,000, so replaying
#: them reproduces its column (docs/protocols.md, "Random replays the reference's random stream").
LEARN_EVAL_EVERY = 50_000
LEARN_EVAL_EPISODES = 10

__all__ = ["BETA", "EVAL_EPISODES", "LEARN_EVAL_EPISODES", "LEARN_EVAL_EVERY", "MAX_STEPS", "SEED", "SEEDS"]
