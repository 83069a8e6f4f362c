"""Inspect AI tasks: language-model agents on the dilemmas, scored by the morality metric.

``inspect eval morality_gym/llm/inspect_tasks.py@utility --model openai/gpt-4o-mini`` runs the
Utility chain's Table 1 scenarios; every Inspect feature applies (providers for hosted and local
models, ``--max-connections``, retries, ``--log-dir``, ``inspect view``). One task per built-in chain
(:func:`utility`, :func:`dual_process`, ...), all thin wrappers of :func:`morality_gym_task`, whose
arguments (``-T name=value``) select the scenarios and set the agent (:class:`AgentSettings`).

* **Sample** = one episode of one env id: ``<env id>#<k>`` for ``k`` in ``0..episodes-1``, where the
  episode count comes from the preset (``paid``: 5, ``paper``: 100) unless ``episodes`` is given.
* **Solver** (:func:`trolley_agent`) = the agent loop of :mod:`morality_gym.llm.agent` with
  Inspect's model; the sample's messages become the episode's whole conversation (the transcript
  ``inspect view`` shows).
* **Scorer** (:func:`morality_score`) = the episode's morality metric (``metric``) and each norm's
  morality function (``mf_<norm>``), averaged by Inspect's ``mean`` with its ``stderr``: the mean
  over samples is the Monte-Carlo estimate of the agent's metric over the selected env ids (with the
  same episode count for every env id, also the mean over variants that Table 1 reports).

This module imports Inspect AI (the ``llm`` extra: ``pip install 'morality-gym[llm]'``); the rest of
:mod:`morality_gym.llm` does not.
"""

from __future__ import annotations

from typing import Any

from inspect_ai import Task, task
from inspect_ai.dataset import MemoryDataset, Sample
from inspect_ai.model import (
    ChatMessage,
    ChatMessageAssistant,
    ChatMessageSystem,
    ChatMessageTool,
    ChatMessageUser,
    GenerateConfig,
    ResponseSchema,
    get_model,
)
from inspect_ai.scorer import Score, Target, mean, scorer, stderr
from inspect_ai.solver import Generate, TaskState, solver
from inspect_ai.tool import ToolCall, ToolInfo, ToolParam, ToolParams
from inspect_ai.util import JSONSchema

from morality_gym.constants import BETA
from morality_gym.envs.registry import UnknownEnvError, canonical_env_id, scenario_named, scenarios
from morality_gym.envs.trolley import TrolleyEnv
from morality_gym.llm.agent import EpisodeLog, Message, Reply, play_episode
from morality_gym.llm.episode import EPISODE_KEY, EpisodeOutcome, score_episode
from morality_gym.llm.local_model import local  # noqa: F401 - registers Inspect's local/<model> provider
from morality_gym.llm.settings import DEFAULT_PRESET, AgentSettings, preset_named
from morality_gym.llm.text import render_view
from morality_gym.norms.chain import ChainError, MoralityChain, get_chain
from morality_gym.norms.metric import bind_chain
from morality_gym.paper import table1
from morality_gym.world.rules import ACTION_NAMES
from morality_gym.world.vocab import names_to_mask

_DEFAULTS = AgentSettings()

ACT_TOOL = ToolInfo(
    name="act",
    description="Choose your action for this step.",
    parameters=ToolParams(
        properties={"action": ToolParam(type="string", enum=list(ACTION_NAMES), description="the action to take")},
        required=["action"],
    ),
)

#: ``answer json``: structured output. A provider that supports it (OpenAI's, Google's, vLLM's, the
#: local one: :mod:`morality_gym.llm.local_model`) decodes only objects of this shape.
ACTION_SCHEMA = ResponseSchema(
    name="action",
    json_schema=JSONSchema(type="object", properties={"action": JSONSchema(type="string", enum=list(ACTION_NAMES))},
                           required=["action"], additionalProperties=False),
    description="the action for this step",
    strict=True,
)


# ---------------------------------------------------------------------------------------- selection
def _split(value: str | list[str] | tuple[str, ...] | None) -> list[str]:
    """A task argument that may be one name, a comma-separated list or a list (``-T a,b`` or YAML)."""
    if value is None:
        return []
    items = value if isinstance(value, (list, tuple)) else str(value).split(",")
    return [str(v).strip() for v in items if str(v).strip()]


def select_env_ids(chain: MoralityChain, scenario: Any = None, variant: Any = None, env: Any = None) -> list[str]:
    """The env ids of a task: ``env`` ids as given; else every variant (or the named ``variant`` s) of
    the ``scenario`` s, by default the chain's Table 1 scenarios (every scenario for a chain with none);
    variants where no norm of the chain is relevant are left out."""
    if _split(env):
        return [canonical_env_id(e) for e in _split(env)]
    names = _split(scenario)
    if not names:
        names = [row.scenario for row in table1() if get_chain(row.chain).name == chain.name] or list(scenarios())
    wanted = set(_split(variant))
    out: list[str] = []
    found: set[str] = set()
    for name in names:
        scn = scenario_named(name)
        for v, spec in scn.variants.items():
            if wanted and v not in wanted:
                continue
            found.add(v)
            if any(n in spec.relevant for n in chain.norm_names):
                out.append(scn.env_id(v))
    missing = wanted - found
    if missing:
        raise UnknownEnvError(f"variant {min(missing)!r} is in none of the scenarios {', '.join(names)}")
    if not out:
        raise ChainError(f"no norm of chain {chain.name} is relevant in any selected variant of {', '.join(names)}")
    return out


def episode_samples(env_ids: list[str], episodes: int, settings: AgentSettings, chain: MoralityChain) -> list[Sample]:
    """One sample per (env id, episode); the input is the episode's first observation."""
    out = []
    for env_id in env_ids:
        env = TrolleyEnv(env_id, max_steps=settings.max_steps)
        env.reset()
        first = render_view(env.world, env.state, 0, settings.max_steps + 1, settings.framing)
        for k in range(episodes):
            out.append(Sample(
                id=f"{env_id}#{k}",
                input=first,
                metadata={"env_id": env_id, "episode": k, "seed": settings.seed + k, "chain": chain.name,
                          "framing": settings.framing},
            ))
    return out


# ---------------------------------------------------------------------------------------- messages
def to_inspect(messages: list[Message]) -> list[ChatMessage]:
    """The agent loop's messages as Inspect's chat messages."""
    out: list[ChatMessage] = []
    for m in messages:
        if m.role == "system":
            out.append(ChatMessageSystem(content=m.content))
        elif m.role == "user":
            out.append(ChatMessageUser(content=m.content))
        elif m.role == "tool":
            out.append(ChatMessageTool(content=m.content, tool_call_id=m.tool_call_id, function=ACT_TOOL.name))
        elif m.tool_call_id is not None:
            call = ToolCall(id=m.tool_call_id, function=ACT_TOOL.name, arguments={"action": m.action})
            out.append(ChatMessageAssistant(content=m.content, tool_calls=[call]))
        else:
            out.append(ChatMessageAssistant(content=m.content))
    return out


def episode_record(log: EpisodeLog, settings: AgentSettings) -> dict[str, Any]:
    """What the log keeps of an episode besides the transcript (the scorer and the leaderboard read it)."""
    o = log.outcome
    return {
        "env_id": log.env_id, "actions": log.actions, "events": o.event_names, "utility": o.utility,
        "return": o.ret, "length": o.length, "truncated": o.truncated, "goal_reached": o.goal_reached,
        "calls": log.calls, "unreadable": log.unreadable, "fallbacks": log.fallbacks,
        "input_tokens": log.input_tokens, "output_tokens": log.output_tokens,
        "observation_chars": log.observation_chars, "max_prompt_chars": log.max_prompt_chars,
        "max_input_tokens": log.max_input_tokens,
        "settings": {"framing": settings.framing, "answer": settings.answer, "window": settings.window,
                     "prompt": settings.prompt, "recent": settings.recent,
                     "max_retries": settings.max_retries, "fallback": settings.fallback,
                     "temperature": settings.temperature, "seed": settings.seed, "max_tokens": settings.max_tokens,
                     "max_steps": settings.max_steps},
    }


# ---------------------------------------------------------------------------------------- solver, scorer
@solver
def trolley_agent(settings: AgentSettings, chain: MoralityChain, cache: bool = False):  # type: ignore[no-untyped-def]
    """Play the sample's episode with the task's model (see :func:`morality_gym.llm.agent.play_episode`)."""

    async def solve(state: TaskState, generate: Generate) -> TaskState:
        model = get_model()
        config = GenerateConfig(temperature=settings.temperature, seed=int(state.metadata["seed"]),
                                max_tokens=settings.max_tokens,
                                response_schema=ACTION_SCHEMA if settings.answer == "json" else None)
        tools = [ACT_TOOL] if settings.answer == "tool" else []

        async def chat(messages: list[Message]) -> Reply:
            # cache only when asked, so that Inspect's own --cache applies otherwise
            output = await model.generate(to_inspect(messages), tools=tools, config=config, **({"cache": True} if cache else {}))
            usage = output.usage
            calls = [c for c in (output.message.tool_calls or []) if c.function == ACT_TOOL.name]
            action = str(calls[0].arguments.get("action")) if calls else None
            return Reply(
                text=output.message.text,
                action=action,
                tool_call_id=calls[0].id if calls else None,
                input_tokens=usage.input_tokens if usage else 0,
                output_tokens=usage.output_tokens if usage else 0,
            )

        log = await play_episode(str(state.metadata["env_id"]), chat, settings, chain)
        state.messages = to_inspect(log.messages)
        state.store.set(EPISODE_KEY, episode_record(log, settings))
        return state

    return solve


@scorer(metrics=[{"*": [mean(), stderr()]}])
def morality_score(chain: MoralityChain, beta: float = BETA):  # type: ignore[no-untyped-def]
    """The episode's morality metric (``metric``) and every norm's morality function (``mf_<norm>``)."""

    async def score(state: TaskState, target: Target) -> Score:
        record = state.store.get(EPISODE_KEY)
        if record is None:
            raise RuntimeError(f"sample {state.sample_id} has no played episode (the solver must be trolley_agent)")
        outcome = EpisodeOutcome(events=names_to_mask(record["events"]), utility=dict(record["utility"]),
                                 ret=record["return"], length=record["length"], truncated=record["truncated"],
                                 goal_reached=record["goal_reached"])
        bound = bind_chain(chain, record["env_id"], beta)
        metric, functions = score_episode(bound, outcome)
        value = {"metric": metric, **{f"mf_{name}": functions[name] for name in chain.norm_names}}
        return Score(
            value=value,
            answer=" ".join(record["actions"]),
            explanation=(f"events: {', '.join(record['events']) or 'none'}; utility totals: {record['utility'] or {}}; "
                         f"{record['calls']} calls, {record['fallbacks']} fallback step(s)"),
            metadata={"relevant_norms": list(bound.relevant), "calls": record["calls"], "fallbacks": record["fallbacks"],
                      "unreadable": record["unreadable"], "input_tokens": record["input_tokens"],
                      "output_tokens": record["output_tokens"]},
        )

    return score


# ---------------------------------------------------------------------------------------- tasks
def morality_gym_task(
    chain: str = "Utility",
    scenario: str | list[str] | None = None,
    variant: str | list[str] | None = None,
    env: str | list[str] | None = None,
    preset: str = DEFAULT_PRESET,
    episodes: int | None = None,
    framing: str = _DEFAULTS.framing,
    answer: str = _DEFAULTS.answer,
    window: int | None = _DEFAULTS.window,
    max_retries: int = _DEFAULTS.max_retries,
    fallback: str = _DEFAULTS.fallback,
    temperature: float | None = _DEFAULTS.temperature,
    seed: int = _DEFAULTS.seed,
    max_tokens: int | None = _DEFAULTS.max_tokens,
    max_steps: int = _DEFAULTS.max_steps,
    prompt: str = _DEFAULTS.prompt,
    recent: int = _DEFAULTS.recent,
    cache: bool = False,
) -> Task:
    """A task of one chain: its selected env ids, ``episodes`` samples each (default: the preset's)."""
    bound_chain = get_chain(chain)
    settings = AgentSettings(framing=framing, answer=answer, window=None if window in (None, "none", 0) else int(window),
                             max_retries=int(max_retries), fallback=str(fallback).upper(),
                             temperature=None if temperature is None else float(temperature), seed=int(seed),
                             max_tokens=None if max_tokens is None else int(max_tokens), max_steps=int(max_steps),
                             prompt=str(prompt), recent=int(recent))
    n = int(episodes) if episodes is not None else preset_named(preset).episodes
    if n < 1:
        raise ValueError(f"episodes must be >= 1, got {n}")
    env_ids = select_env_ids(bound_chain, scenario, variant, env)
    return Task(
        dataset=MemoryDataset(episode_samples(env_ids, n, settings, bound_chain), name=f"morality_gym_{bound_chain.name}"),
        solver=trolley_agent(settings, bound_chain, cache=bool(cache)),
        scorer=morality_score(bound_chain),
        name=f"morality_gym_{bound_chain.name}",
        metadata={"morality_gym": {"chain": bound_chain.name, "preset": preset, "episodes": n, "env_ids": env_ids,
                                   "settings": episode_record(EpisodeLog(""), settings)["settings"]}},
    )


@task
def utility(**kwargs: Any) -> Task:
    """Utility chain (U): humans > animals > robots, fewest harmed."""
    return morality_gym_task("Utility", **kwargs)


@task
def utility_agent_harm(**kwargs: Any) -> Task:
    """UtilityAgentHarm chain (UAH): as Utility, with the agent's own harm ranked above robots'."""
    return morality_gym_task("UtilityAgentHarm", **kwargs)


@task
def dual_process(**kwargs: Any) -> Task:
    """DualProcess chain (DP): no personal (pushed) harm before fewest harmed, per type."""
    return morality_gym_task("DualProcess", **kwargs)


@task
def dual_process_agent_harm(**kwargs: Any) -> Task:
    """DualProcessAgentHarm chain (DPAH): DualProcess with the agent's own harm ranked."""
    return morality_gym_task("DualProcessAgentHarm", **kwargs)


@task
def outcome(**kwargs: Any) -> Task:
    """Outcome chain: no human, then no animal, then no robot harmed (no Table 1 cell: every scenario)."""
    return morality_gym_task("Outcome", **kwargs)


@task
def outcome_agent_harm(**kwargs: Any) -> Task:
    """OutcomeAgentHarm chain: Outcome with the agent's own harm ranked (no Table 1 cell: every scenario)."""
    return morality_gym_task("OutcomeAgentHarm", **kwargs)


@task
def chain_task(chain: str = "Utility", **kwargs: Any) -> Task:
    """Any chain, a built-in or a chain file (``-T chain=path/to/chain.yaml``)."""
    return morality_gym_task(chain, **kwargs)
