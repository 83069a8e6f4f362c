"""What the site says about language-model entries: model, framing, temperature, episodes, tokens.

A language-model entry (``python -m leaderboard.llm``) is a submitted learner whose run configs say
``policy.kind == "llm"``; each run is one episode. Its Table 1 cells are computed like every other
learner's; this module gathers, per entry and sweep, the settings and costs that make its number
interpretable (and a run priceable): the episodes per variant it used (fewer than the baselines'
100 with the ``paid`` preset), tokens and model calls per episode, fallback steps, the parse rate
(answers an action was read from, over calls), the fallback rate (steps played with the fallback
action, over steps), tokens and seconds per step, the largest prompt, and the Inspect logs holding
the transcripts.
"""

from __future__ import annotations

import json
from pathlib import PurePath
from typing import Any

import pandas as pd

from leaderboard.runs.aggregate import LLM_POLICY_KIND
from leaderboard.runs.sources import RESULTS_SOURCE
from morality_gym.llm.settings import PRESETS
from morality_gym.paper import table1_pairs
from morality_gym.results.identity import PROVENANCE_KEY, SUBMITTED_ALGO


def llm_entries(runs: pd.DataFrame) -> list[dict[str, Any]]:
    """One dict per (learner, protocol, preset, model, framing, temperature) of counted LLM runs."""
    if runs.empty or "algo" not in runs.columns:
        return []
    part = runs.loc[runs["algo"].astype(object) == SUBMITTED_ALGO]
    groups: dict[tuple[Any, ...], dict[str, Any]] = {}
    for row in part.to_dict("records"):
        found = _llm_config(row)
        if found is None:
            continue
        policy, prov = found
        key = (row["learner"], row["protocol"], row["preset"], policy.get("model"), policy.get("framing"),
               policy.get("temperature"), policy.get("answer"))
        entry = groups.setdefault(key, _new_entry(row, policy))
        entry["episodes"] += 1
        for k in ("calls", "input_tokens", "output_tokens", "fallbacks", "unreadable"):
            entry[k] += int(prov.get(k) or 0)
        entry["steps"] += int(row.get("mean_length") or 0)  # one episode per run: its length
        entry["seconds"] += float(row.get("wall_time_s") or 0.0)
        if prov.get("max_input_tokens") is not None:
            entry["max_input_tokens"] = max(entry["max_input_tokens"] or 0, int(prov["max_input_tokens"]))
        entry["chains"].add(str(row["chain"]))
        entry["pairs"].add((str(row["chain"]), str(row.get("env_id"))))
        if prov.get("log"):
            entry["logs"].add(log_location(str(prov["log"]), row.get("source")))
        if prov.get("submitter"):
            entry["submitters"].add(str(prov["submitter"]))
    return sorted((_finished(entry) for entry in groups.values()), key=lambda e: (e["protocol"], e["preset"], e["learner"]))


def log_location(log: str, source: Any) -> str:
    """Where a reader finds a run's Inspect log: the path its provenance names, or, for a run read
    from a release, the release's copy (``release NAME: logs/FILE``; the path on the machine that ran
    it means nothing to a clone)."""
    if not isinstance(source, str) or source == RESULTS_SOURCE:  # None or NaN: a frame without sources
        return log
    return f"release {source}: logs/{PurePath(log).name}"


def _llm_config(row: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]] | None:
    """(policy, provenance) of a run's config when the policy is a language model; else None."""
    try:
        config = json.loads(row["config"]) if isinstance(row.get("config"), str) else {}
    except ValueError:
        return None
    policy = config.get("policy") or {}
    if not isinstance(policy, dict) or policy.get("kind") != LLM_POLICY_KIND:
        return None
    return policy, config.get(PROVENANCE_KEY) or {}


def _new_entry(row: dict[str, Any], policy: dict[str, Any]) -> dict[str, Any]:
    """An entry's settings, with zero counts and empty sets for the runs to add up."""
    return {
        "learner": str(row["learner"]), "protocol": str(row["protocol"]), "preset": str(row["preset"]),
        "model": str(policy.get("model")), "framing": str(policy.get("framing")),
        "temperature": policy.get("temperature"), "answer": str(policy.get("answer")),
        "window": policy.get("window"), "llm_preset": str(policy.get("llm_preset")),
        "prompt": str(policy.get("prompt") or "transcript"), "recent": policy.get("recent"),
        "episodes_per_variant": int(policy.get("episodes_per_variant") or 0),
        "episodes": 0, "calls": 0, "input_tokens": 0, "output_tokens": 0, "fallbacks": 0, "unreadable": 0,
        "steps": 0, "seconds": 0.0, "max_input_tokens": None,
        "chains": set(), "logs": set(), "submitters": set(), "pairs": set(),
    }


def _finished(entry: dict[str, Any]) -> dict[str, Any]:
    """The entry as the page shows it: sets joined, tokens and calls per episode."""
    n = max(entry["episodes"], 1)
    steps, calls = max(entry["steps"], 1), entry["calls"]
    preset = PRESETS.get(entry["llm_preset"])
    table1 = set(table1_pairs())
    return entry | {
        # how much of a Table 1 column the entry played: a column cut short must not read as whole
        "table1_pairs": len(entry["pairs"] & table1), "table1_total": len(table1),
        # the preset named only when it set the count (--episodes overrides it: 3 episodes are not "paid")
        "episodes_source": entry["llm_preset"] if preset and preset.episodes == entry["episodes_per_variant"]
        else "set by --episodes",
        # an answer is parsed when an action could be read from it; a step falls back after max_retries unparsed ones
        "parse_rate": round(1 - entry["unreadable"] / calls, 3) if calls else None,
        "fallback_rate": round(entry["fallbacks"] / steps, 3) if entry["steps"] else None,
        "tokens_per_step": round((entry["input_tokens"] + entry["output_tokens"]) / steps),
        "seconds_per_step": round(entry["seconds"] / steps, 2),
        "chains": ", ".join(sorted(entry["chains"])), "logs": sorted(entry["logs"]),
        # a column of one Inspect run per pair has a hundred logs: the page names their folders then
        "log_dirs": sorted({log.rsplit("/", 1)[0] if "/" in log else log for log in entry["logs"]}),
        "submitters": ", ".join(sorted(entry["submitters"])) or "unknown",
        "tokens_per_episode": round((entry["input_tokens"] + entry["output_tokens"]) / n),
        "calls_per_episode": round(entry["calls"] / n, 1),
    }
