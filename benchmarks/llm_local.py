"""What a small local model costs and reads: ``python -m benchmarks.llm_local [--formats N]``.

Three tables for docs/llm-agents.md (issue 49), measured with SmolLM2-135M-Instruct
(``local/smollm2-135m``) on this machine's CPU:

* **prompt tokens per step**, by prompt mode and window, per chain: the oracle's best episode of
  every Table 1 variant of the chain is played (its actions, not the model's), and every call's
  prompt is counted with the model's own tokenizer and chat template. This is the prompt a model
  reads when it plays well; one that wanders reads the longest prompt of the window at every step.
* **answer formats**: the parse rate (answers an action can be read from, over calls) of each
  answer mode, the model playing ``--steps`` + 1 steps of ``--formats`` Table 1 variants (every
  21st pair), compact prompt, no retries (so the rate is the first answer's); ``json`` is decoded
  under its response schema (structured output), the others freely (``word`` up to 48 tokens,
  ``bare`` and ``number`` up to 8);
* **seconds per call** of those runs, wall and CPU (greedy, one torch thread, prompts answered
  before not reused; the wall time depends on what else the machine runs, the CPU time much less).

Not part of ``make bench``: it needs the ``local`` extra and the model wheel, and takes minutes.
"""

from __future__ import annotations

import argparse
import asyncio
import functools
import statistics
import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from morality_gym.evaluation.oracle import oracle
from morality_gym.llm.agent import Message, Reply, play_episode
from morality_gym.llm.inspect_tasks import ACTION_SCHEMA
from morality_gym.llm.local_model import answer, load_local, model_file, schema_choices
from morality_gym.llm.settings import AgentSettings
from morality_gym.norms.chain import get_chain
from morality_gym.paper import table1_pairs
from morality_gym.world.rules import ACTION_NAMES

MODEL = "smollm2-135m"
PROMPTS: tuple[tuple[str, AgentSettings], ...] = (
    ("transcript, window 8 (the default)", AgentSettings(window=8)),
    ("transcript, window 3", AgentSettings(window=3)),
    ("transcript, window 1", AgentSettings(window=1)),
    ("compact, 3 earlier steps", AgentSettings(prompt="compact", recent=3, answer="json")),
)


def _chat_of(messages: list[Message]) -> list[dict[str, str]]:
    return [{"role": m.role if m.role != "tool" else "user", "content": m.content} for m in messages]


@functools.cache
def _tokenizer() -> Any:
    """The model's tokenizer alone (the prompt sizes need no weights: a fifth of the loading time)."""
    from transformers import AutoTokenizer  # the local extra, as morality_gym.llm.local_model loads it

    path = model_file(MODEL)
    return AutoTokenizer.from_pretrained(str(path.parent), gguf_file=path.name, local_files_only=True)


def prompt_tokens(settings: AgentSettings) -> dict[str, list[int]]:
    """Per chain, the prompt tokens of every call of the oracle's best episodes of its Table 1 variants."""
    tokenizer = _tokenizer()
    out: dict[str, list[int]] = {}
    for chain_name, env_id in table1_pairs():
        chain = get_chain(chain_name)
        actions = [ACTION_NAMES[a] for a in oracle(env_id, chain).best.actions]
        sizes = out.setdefault(chain.name, [])

        calls: list[int] = []  # max_retries 0: call k plays the oracle's action k

        async def chat(messages: list[Message], _actions: list[str] = actions, _sizes: list[int] = sizes,
                       _calls: list[int] = calls) -> Reply:
            ids = tokenizer.apply_chat_template(_chat_of(messages), add_generation_prompt=True, return_dict=True)
            _sizes.append(len(ids["input_ids"]))
            _calls.append(1)
            return Reply(_actions[min(len(_calls) - 1, len(_actions) - 1)], input_tokens=_sizes[-1])

        asyncio.run(play_episode(env_id, chat, replace(settings, max_retries=0), chain))
    return out


def format_runs(modes: Sequence[str], n_envs: int, steps: int) -> list[dict[str, float]]:
    """Each answer mode played by the model for ``steps`` + 1 steps on ``n_envs`` Table 1 pairs."""
    loaded = load_local(MODEL)
    pairs = table1_pairs()[::21][:n_envs]
    rows = []
    for mode in modes:
        settings = AgentSettings(prompt="compact", recent=3, answer=mode, max_steps=steps, max_retries=0,
                                 max_tokens=48 if mode == "word" else 8)
        choices = schema_choices(ACTION_SCHEMA.json_schema) if mode == "json" else None
        calls = unreadable = out_tokens = 0
        seconds = cpu = 0.0
        for chain_name, env_id in pairs:
            loaded.answers.clear()  # time every answer, none from memory

            async def chat(messages: list[Message], _s: AgentSettings = settings,
                           _choices: tuple[str, ...] | None = choices) -> Reply:
                text, n_in, n_out = await asyncio.to_thread(answer, loaded, _chat_of(messages), _s.max_tokens or 512,
                                                            _choices)
                return Reply(text, input_tokens=n_in, output_tokens=n_out)

            started, cpu_started = time.perf_counter(), time.process_time()
            log = asyncio.run(play_episode(env_id, chat, settings, get_chain(chain_name)))
            seconds += time.perf_counter() - started
            cpu += time.process_time() - cpu_started
            calls += log.calls
            unreadable += log.unreadable
            out_tokens += log.output_tokens
        rows.append({"mode": mode, "calls": calls, "parse_rate": 1 - unreadable / calls,
                     "s_per_call": seconds / calls, "cpu_s_per_call": cpu / calls,
                     "out_tokens_per_call": out_tokens / calls})
    return rows


def _prompt_table() -> None:
    print("| prompt | Utility | UtilityAgentHarm | DualProcess | DualProcessAgentHarm | all: mean / largest |")
    print("|---|---|---|---|---|---|")
    for label, settings in PROMPTS:
        sizes = prompt_tokens(settings)
        every = [n for v in sizes.values() for n in v]
        cells = [f"{statistics.mean(sizes[c]):.0f}" for c in ("Utility", "UtilityAgentHarm", "DualProcess",
                                                               "DualProcessAgentHarm")]
        print(f"| {label} | " + " | ".join(cells) + f" | {statistics.mean(every):.0f} / {max(every)} |", flush=True)


def _format_table(modes: Sequence[str], n_envs: int, steps: int) -> None:
    print("\n| answer | calls | parse rate | output tokens per call | seconds per call (wall / CPU) |")
    print("|---|---|---|---|---|")
    for r in format_runs(modes, n_envs, steps):
        print(f"| {r['mode']} | {r['calls']} | {r['parse_rate']:.3f} | {r['out_tokens_per_call']:.1f} | "
              f"{r['s_per_call']:.1f} / {r['cpu_s_per_call']:.1f} |", flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--formats", type=int, default=6, help="variants the answer formats are measured on (0: skip)")
    parser.add_argument("--steps", type=int, default=0, help="steps played per variant for the formats, after the first")
    parser.add_argument("--modes", default="word,bare,number,json")
    parser.add_argument("--skip-prompts", action="store_true", help="only the answer formats")
    args = parser.parse_args(argv)
    if not args.skip_prompts:
        _prompt_table()
    if args.formats:
        _format_table(args.modes.split(","), args.formats, args.steps)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
