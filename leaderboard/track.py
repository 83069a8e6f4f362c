"""The generalisation track's page: each learner's score on seen vs unseen vs built-in dilemmas.

Reads the runs of ``python -m runners.track`` (``<results>/track/runs/*/``: ``result.json`` and
``pairs.parquet``) and shows, per learner, the mean score on the three sets
(:mod:`morality_gym.generalisation.sets`) with 95 % bootstrap intervals, the seen - unseen gap,
the budget and the split digests, and a bar chart.

**Scores.** Per (env id, chain) pair, the policy's exact metric placed between the pair's exact
oracle worst (0) and best (1): the *range score*; and, as on the ranking page, between Random's
exact metric (0) and the best (1): the *Random-relative score*, left out for pairs whose headroom
best - Random is under 0.05 (the leaderboard's guard). An env id's score is the mean over its pairs;
a run's score on a set is the mean over the set's env ids; a learner's, the mean over its runs.

**Intervals.** A two-level percentile bootstrap (:data:`~leaderboard.stats.core.DEFAULT_RESAMPLES`
resamples, the statistics' fixed seed; printed to the decimals their bounds are stable to over
bootstrap seeds, :mod:`leaderboard.outputs.precision`): the runs (seeds) are resampled, and so are the set's
dilemmas, by scenario (a generated dilemma's variants, or a built-in scenario's variants, move
together: they share a layout). The interval thus covers both seed-to-seed variation and which
dilemmas the set happens to hold, which is what a claim about *unseen* dilemmas needs. Random is
exact: its interval comes from the dilemmas alone. The gap resamples the seeds once for both sets.

``python -m leaderboard.track --results DIR --site SITE`` writes the page alone (into an existing
or a new site directory) and prints the table; ``leaderboard.build`` writes it with the rest.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from leaderboard.outputs.marks import MARKS
from leaderboard.outputs.precision import DIGITS_RULE
from leaderboard.outputs.tables import interval_text
from leaderboard.runs.display_order import LEARNER_COLOURS
from leaderboard.runs.releases import RELEASES_DIR
from leaderboard.stats.core import CONFIDENCE, DEFAULT_RESAMPLES, DEFAULT_SEED, generator_for, quantile_mcse
from leaderboard.track_curves import curve_summary, draw_curves, read_curves
from leaderboard.track_release import find as find_track_releases
from leaderboard.track_release import verify as verify_release
from leaderboard.track_status import CURVES_DIR, Requirement, entry_marks, status
from leaderboard.web.render import render
from leaderboard.web.site_state import NAV
from morality_gym.clitools import OneLineParser, UserError, add_debug_flag, run_cli
from morality_gym.generalisation.sets import MIN_HEADROOM, SET_LABELS, SETS, TRACK_CHAINS, scenario_of
from morality_gym.results.track_runs import PAIRS, RESULT

SCORES = {"range_score": "Range score (0 = oracle worst, 1 = oracle best)",
          "random_score": "Random-relative score (0 = Random, 1 = oracle best)",
          "vs_random": "Range score minus Random's on the same dilemmas (paired)"}
#: The track's learner keys (``runners.track --learners``) and the names Table 1 gives them.
LABELS = {"random": "Random", "ppo": "PPO", "ppo_shaped": "PPO Shaped", "ppo_lag": "PPO Lag", "cpo": "CPO"}
#: Table 1's colours, so that a learner is one colour on every page of the site.
COLOURS = {key: LEARNER_COLOURS[label] for key, label in LABELS.items()}
PAGE = "track.html"
#: The track of runs trained and scored under every chain a dilemma is one under (no ``--chain``).
MIXED = "mixed"
#: How the page names a track.
TRACK_TITLES = ({MIXED: "Mixed track (every chain a dilemma is one under)"} | {c: f"{c} track" for c in TRACK_CHAINS}
                | {f"{c}-v2": f"{c} track, v2 splits (Random leaves headroom)" for c in TRACK_CHAINS})
FIGURE = "track/track_scores.png"
CSV = "track/track_summary.csv"


def track_results(results: Path | None) -> Path | None:
    """Where a results directory keeps the track's runs (``<results>/track``), if it does."""
    if results is None:
        return None
    path = results / "track"
    return path if (path / "runs").is_dir() else None


def track_source(results: Path | None, releases: Path = RELEASES_DIR) -> tuple[Path | None, dict[str, Any] | None]:
    """What the page shows: the results directory's own track runs when it has some, else the last
    track release (by name) under ``releases``, verified (a damaged one is refused, never shown).
    Returns the folder holding ``runs/`` and, for a release, its manifest."""
    own = track_results(results)
    if own is not None:
        return own, None
    found = find_track_releases(releases)
    if not found:
        return None, None
    try:
        return found[-1], verify_release(found[-1])
    except ValueError as exc:  # ReleaseError: one line naming the file
        raise UserError(f"the Generalisation page's release: {exc}") from exc


def track_of(record: dict[str, Any]) -> str:
    """The track a run belongs to: its chain's (``runners.track --chain``, ``Utility-v2`` on v2
    splits) or the mixed one."""
    chain = record.get("chain")
    if not chain:
        return MIXED
    version = record.get("split_version", 1)
    return chain if version == 1 else f"{chain}-v{version}"


def load_runs(track_dir: Path) -> tuple[pd.DataFrame, list[dict[str, Any]]]:
    """Every finished run's pairs (with ``track``, ``learner`` and ``seed``) and its ``result.json``."""
    frames, records = [], []
    for run_dir in sorted(p for p in (track_dir / "runs").iterdir() if p.is_dir()):
        if not (run_dir / RESULT).is_file() or not (run_dir / PAIRS).is_file():
            continue  # unfinished: result.json is written last
        record = json.loads((run_dir / RESULT).read_text())
        frame = pd.read_parquet(run_dir / PAIRS)
        frame["track"], frame["learner"], frame["seed"] = track_of(record), record["learner"], str(record["seed"])
        frames.append(frame)
        records.append(record | {"run": run_dir.name})
    if not frames:
        return pd.DataFrame(), records
    return pd.concat(frames, ignore_index=True), records


def _set_arrays(part: pd.DataFrame, score: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Per seed and scenario: the sum of env-id scores, and each scenario's env-id count."""
    per_env = part.groupby(["seed", "env_id"])[score].mean().unstack("env_id")  # NaN: no pair of the env scores
    per_env = per_env.loc[:, per_env.notna().all(axis=0)]
    scenarios = [scenario_of(e) for e in per_env.columns]
    codes, names = pd.factorize(pd.Series(scenarios))
    onehot = np.zeros((len(per_env.columns), len(names)))
    onehot[np.arange(len(codes)), codes] = 1.0
    return per_env.to_numpy() @ onehot, onehot.sum(axis=0), list(per_env.index)


def _resampled_means(sums: np.ndarray, counts: np.ndarray, seed_weights: np.ndarray, rng: np.random.Generator,
                     resamples: int) -> np.ndarray:
    clusters = rng.integers(len(counts), size=(resamples, len(counts)))
    picks = np.stack([np.bincount(row, minlength=len(counts)) for row in clusters]).astype(float)  # [B, clusters]
    per_seed = (sums @ picks.T) / (counts @ picks.T)  # [seeds, B]
    return (seed_weights * per_seed.T).sum(axis=1)


def _interval(values: np.ndarray) -> dict[str, float]:
    """``low``, ``high`` and the Monte Carlo standard error of each (how many decimals the page prints)."""
    tail = (1 - CONFIDENCE) / 2
    low, high = np.percentile(values, [100 * tail, 100 * (1 - tail)])
    low_mcse, high_mcse = quantile_mcse(values, [tail, 1 - tail])
    return {"low": float(low), "high": float(high), "low_mcse": float(low_mcse), "high_mcse": float(high_mcse)}


def with_paired(frame: pd.DataFrame) -> pd.DataFrame:
    """``vs_random``: each pair's range score minus Random's (exact) on the same pair of the same
    track; NaN for Random."""
    if "track" not in frame:
        frame = frame.assign(track=MIXED)
    keys_of = ["track", "set", "env_id", "chain"]
    random = frame[frame["learner"] == "random"].set_index(keys_of)["range_score"]
    if random.empty:
        return frame.assign(vs_random=np.nan)
    keys = pd.MultiIndex.from_frame(frame[keys_of])
    paired = frame["range_score"].to_numpy() - random.reindex(keys).to_numpy()
    return frame.assign(vs_random=np.where(frame["learner"] == "random", np.nan, paired))


def summarise(frame: pd.DataFrame, resamples: int = DEFAULT_RESAMPLES, seed: int = DEFAULT_SEED) -> pd.DataFrame:
    """One row per (track, learner, score, set) and per (track, learner, score, ``gap``): mean and
    95 % interval. A chain's track and the mixed one score different pairs, so they are never pooled.

    ``vs_random`` (learners other than Random) is the paired difference: the same dilemmas are
    resampled for the learner and for Random, so it is much tighter than comparing two intervals."""
    frame = with_paired(frame)
    rows = []
    for track in _tracks_in_order(frame["track"]):
        in_track = frame[frame["track"] == track]
        rows += [{"track": track, **row} for row in _summarise_track(in_track, track, resamples, seed)]
    return pd.DataFrame(rows)


def _tracks_in_order(tracks: Any) -> list[str]:
    """The chains' tracks in :data:`TRACK_CHAINS` order, then the mixed track."""
    names = set(tracks)
    known = [*(f"{c}-v2" for c in TRACK_CHAINS), *TRACK_CHAINS, MIXED]
    return [t for t in known if t in names] + sorted(names - set(known))


def _summarise_track(frame: pd.DataFrame, track: str, resamples: int, seed: int) -> list[dict[str, Any]]:
    rows = []
    for learner, score in [(lr, s) for lr in frame["learner"].unique() for s in SCORES]:
        if score == "vs_random" and (learner == "random" or frame["vs_random"].isna().all()):
            continue
        mine = frame[frame["learner"] == learner]
        seeds = sorted(mine["seed"].unique())
        # the mixed track keeps the streams it always had; a chain's track gets its own
        rng = generator_for(seed, "track", learner, score) if track == MIXED else generator_for(seed, "track", track, learner, score)
        seed_draws = rng.integers(len(seeds), size=(resamples, len(seeds)))
        weights = np.stack([np.bincount(r, minlength=len(seeds)) for r in seed_draws]) / len(seeds)  # [B, seeds]
        boot: dict[str, np.ndarray] = {}
        point: dict[str, float] = {}
        for set_name in SETS:
            part = mine[mine["set"] == set_name]
            if part.empty:
                continue
            sums, counts, order = _set_arrays(part, score)
            align = [seeds.index(s) for s in order]
            w = weights[:, align] if len(order) == len(seeds) else np.full((resamples, len(order)), 1 / len(order))
            per_seed = sums.sum(axis=1) / counts.sum()
            point[set_name] = float(per_seed.mean())
            boot[set_name] = _resampled_means(sums, counts, w, rng, resamples)
            rows.append({"learner": learner, "score": score, "set": set_name, "mean": point[set_name],
                         **_interval(boot[set_name]), "env_ids": int(counts.sum()), "dilemmas": len(counts),
                         "seeds": len(order)})
        if "seen" in boot and "test" in boot:
            rows.append({"learner": learner, "score": score, "set": "gap", "mean": point["seen"] - point["test"],
                         **_interval(boot["seen"] - boot["test"]), "env_ids": 0, "dilemmas": 0, "seeds": len(seeds)})
    return rows


def _in_order(learners: Any) -> list[str]:
    """Random, the baselines, then everything else (submissions) by name."""
    names = list(dict.fromkeys(learners))
    return [n for n in LABELS if n in names] + sorted(n for n in names if n not in LABELS)


def _ci(row: pd.Series) -> str:
    """``[low, high]`` to the decimals both bounds are stable to over bootstrap seeds (at most three)."""
    return interval_text({"ci_low": row["low"], "ci_high": row["high"], "ci_low_mcse": row.get("low_mcse"),
                          "ci_high_mcse": row.get("high_mcse")}) or "—"


def left_out(frame: pd.DataFrame) -> str:
    """Which (env id, chain) pairs the Random-relative score leaves out and why, per set, from the pairs' own
    references (one sentence for the page; empty when it leaves out none)."""
    pairs = frame.drop_duplicates(["set", "env_id", "chain"])
    parts = []
    for set_name in SETS:
        mine = pairs[pairs["set"] == set_name]
        out = mine[(mine["best"] - mine["random"]) < MIN_HEADROOM]
        if out.empty:
            continue
        kept_envs = set(mine.loc[~mine.index.isin(out.index), "env_id"])
        dropped = sorted(set(out["env_id"]) - kept_envs)
        text = f"{SET_LABELS[set_name]}: {len(out)} of {len(mine)} (env id, chain) pairs"
        if len(out) <= 3:
            text += " (" + ", ".join(f"{r.env_id} / {r.chain} {r.best - r.random:.3f}" for r in out.itertuples()) + ")"
        if dropped:
            text += f", so {len(dropped)} of {mine['env_id'].nunique()} env ids drop out"
        parts.append(text)
    if not parts:
        return ""
    return (f"Leaves out the pairs whose headroom Oracle best − Random is under the {MIN_HEADROOM:g} cutoff: "
            + "; ".join(parts) + ".")


def _bars(ax: Any, part: pd.DataFrame, learners: list[str], marks: dict[str, str]) -> None:
    width = 0.8 / max(1, len(learners))
    for i, learner in enumerate(learners):
        mine = part[part["learner"] == learner].set_index("set").reindex(list(SETS))
        x = np.arange(len(SETS)) + (i - (len(learners) - 1) / 2) * width
        err = np.vstack([mine["mean"] - mine["low"], mine["high"] - mine["mean"]])
        ax.bar(x, mine["mean"], width, yerr=err, capsize=4, label=LABELS.get(learner, learner) + marks.get(learner, ""),
               color=COLOURS.get(learner, "#999999"))
    ax.set_xticks(np.arange(len(SETS)), [SET_LABELS[s].replace(" (", "\n(") for s in SETS], fontsize=8)


def draw_figure(summary: pd.DataFrame, path: Path, marks: dict[str, str] | None = None) -> None:
    """Grouped bars with the 95 % intervals as error bars: the range score per set, and (when Random
    ran) each learner's paired difference from Random on the same dilemmas. ``marks``: a learner's
    legend suffix (`` ⚠ incomplete``, `` (sample: 30 of 190 pairs)``), as its table row is marked."""
    marks = marks or {}
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    in_sets = summary[summary["set"].isin(SETS)]
    scores = in_sets[in_sets["score"] == "range_score"]
    paired = in_sets[in_sets["score"] == "vs_random"]
    fig, axes = plt.subplots(1, 2 if not paired.empty else 1, figsize=(11, 3.8) if not paired.empty else (7, 3.8),
                             dpi=110, squeeze=False)
    ax = axes[0, 0]
    _bars(ax, scores, _in_order(scores["learner"]), marks)
    ax.set_ylabel("range score (0 = worst, 1 = best)")
    ax.set_ylim(0, 1.05)
    ax.axhline(1.0, color="#444444", lw=0.6, ls=":")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title("Score per set", fontsize=10)
    if not paired.empty:
        ax = axes[0, 1]
        learners = _in_order(paired["learner"])
        _bars(ax, paired, learners, marks)
        ax.axhline(0.0, color="#444444", lw=0.8)
        ax.set_ylabel("range score − Random's (paired)")
        ax.set_title("Difference from Random on the same dilemmas", fontsize=10)
        ax.legend(loc="best", fontsize=8)
    fig.suptitle("Seen vs unseen dilemmas (95% bootstrap intervals)", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def _seconds(records: list[dict[str, Any]], learner: str) -> str:
    mine = [r for r in records if r["learner"] == learner]
    # a fleet's run: its share of the fleet's training time (its own train_seconds is the model's save)
    train = np.mean([r["fleet_seconds"] / max(int(r.get("fleet_runs") or 1), 1) if r.get("fleet_seconds") is not None
                     else r.get("train_seconds", 0) for r in mine])
    evals = np.mean([r.get("eval_seconds", 0) for r in mine])
    return f"{train:.0f} s + {evals:.0f} s"


def _learner_row(learner: str, part: pd.DataFrame, records: list[dict[str, Any]],
                 reasons: dict[str, list[str]] | None = None) -> dict[str, Any]:
    """One learner's row of a score's table: its label, budget, seeds, cells and time, and the mark
    every one of its numbers carries: incomplete (``reasons``: :func:`leaderboard.track_status.status`)
    or a sample of the pairs."""
    cells = part[part["learner"] == learner].set_index("set")
    record = next(r for r in records if r["learner"] == learner)
    why = (reasons or {}).get(learner) or []
    sample = entry_marks(record).removeprefix("sample: ")
    mark, note = ("⚠ incomplete", "; ".join(why)) if why else ("sample", sample) if sample else ("", "")
    return {"mark": mark, "mark_note": note,
        "learner": LABELS.get(learner, learner), "colour": COLOURS.get(learner, "#999999"),
        "budget": _budget_text(learner, record), "seeds": _seeds_text(learner, record, records),
        "cells": [{"mean": float(cells.loc[s, "mean"]), "ci": _ci(cells.loc[s])} if s in cells.index else None
                  for s in [*SETS, "gap"]],
        "time": "—" if learner == "random" or record.get("submitted") else _seconds(records, learner),
    }


def _budget_text(learner: str, record: dict[str, Any]) -> str:
    """A row's training budget: none for Random, the model or policy for a submitted entry, else steps."""
    if learner == "random":
        return "exact, untrained"
    return _submitted_budget(record) if record.get("submitted") else f"{record['budget']:,} steps"


def _seeds_text(learner: str, record: dict[str, Any], records: list[dict[str, Any]]) -> str:
    """A row's seeds: exact for Random, the sample for a sampled entry, else the trained runs' seeds."""
    if learner == "random":
        return "exact"
    if record.get("sample"):
        return _sample_text(record)
    if record.get("submitted"):
        return "submitted"
    return ", ".join(sorted({str(r["seed"]) for r in records if r["learner"] == learner}))


def _submitted_budget(record: dict[str, Any]) -> str:
    """How a submitted run is described: a language model (``leaderboard.llm_track``) by its model."""
    model = (record.get("llm") or {}).get("model")
    return f"language model {model}, greedy, untrained" if model else "submitted policy"


def _sample_text(record: dict[str, Any]) -> str:
    """A run scored on a sample of the test set says so (its interval covers which pairs were drawn)."""
    sample = record["sample"]
    return f"sample of {sample['pairs']} of {sample['of']} test pairs (seed {sample['seed']}): unseen set only"


def _score_table(score: str, title: str, part: pd.DataFrame, frame: pd.DataFrame,
                 records: list[dict[str, Any]], reasons: dict[str, list[str]]) -> dict[str, Any]:
    """The table of one score (``part``: the summary's rows of that score)."""
    return {"score": score, "title": title,
            "rows": [_learner_row(learner, part, records, reasons) for learner in _in_order(part["learner"])],
            "left_out": left_out(frame) if score == "random_score" else "",
            "counts": set_counts(part)}


def set_counts(part: pd.DataFrame) -> dict[str, str]:
    """Each set's size under a score table: that of the learner scored on the most of it. A run scored on a
    sample of a set (a language model's) holds fewer env ids, and it is marked as a sample in its own row; the
    table's line must not shrink the whole set to that sample."""
    counts = {}
    for set_name in SETS:
        rows = part[part["set"] == set_name]
        if not rows.empty:
            most = rows.loc[rows["env_ids"].idxmax()]
            counts[set_name] = f"{int(most['env_ids'])} env ids, {int(most['dilemmas'])} dilemmas"
    return counts


def track_context(common: dict[str, Any], track_dir: Path | None, site: Path,
                  resamples: int = DEFAULT_RESAMPLES, release: dict[str, Any] | None = None) -> dict[str, Any]:
    """The page's context; draws the figures and writes the summary CSV into ``site``. ``release``:
    the verified manifest when ``track_dir`` is a track release (:mod:`leaderboard.track_release`)."""
    context: dict[str, Any] = {**common, "set_labels": SET_LABELS, "sets": list(SETS), "has_runs": False,
                               "track_dir": str(track_dir) if track_dir else "", "resamples": f"{resamples:,}",
                               "digits_rule": DIGITS_RULE, "release": _release_note(release)}
    if track_dir is None:
        return context
    frame, records = load_runs(track_dir)
    if frame.empty:
        return context
    need = Requirement.from_dict(release.get("requirement")) if release else Requirement()
    curves = [f"{CURVES_DIR}/{p.name}" for p in (track_dir / CURVES_DIR).glob("*.csv")]
    incomplete = status(records, curves, need)
    summary = summarise(frame, resamples)
    (site / CSV).parent.mkdir(parents=True, exist_ok=True)
    summary.to_csv(site / CSV, index=False)
    tracks = [_track_context(track, summary, frame, records, incomplete.get(track, {}), track_dir, site)
              for track in _tracks_in_order(summary["track"])]
    context.update(has_runs=True, tracks=tracks, csv=CSV)
    return context


def _track_context(track: str, summary: pd.DataFrame, frame: pd.DataFrame, records: list[dict[str, Any]],
                   reasons: dict[str, list[str]], track_dir: Path, site: Path) -> dict[str, Any]:
    """One track's section of the page: its figure (drawn into ``site``), score tables, sets,
    training and curves. ``reasons``: why each of its learners is incomplete (empty: complete)."""
    part, mine = summary[summary["track"] == track], frame[frame["track"] == track]
    runs = [r for r in records if track_of(r) == track]
    figure = _draw_track_figure(track, part, runs, reasons, site)
    tables = [_score_table(score, title, scored, mine, runs, reasons) for score, title in SCORES.items()
              if not (scored := part[part["score"] == score]).empty]
    first = max(runs, key=lambda r: len(r.get("sets") or {}))  # a test-set-only entry lists one set's source
    trained = [r for r in runs if r["learner"] != "random" and not r.get("submitted")]
    return {
        "key": "" if track == MIXED else f"-{track}", "title": TRACK_TITLES.get(track, track), "figure": figure,
        "tables": tables, "sources": [{"set": SET_LABELS[name], **source} for name, source in first["sets"].items()],
        "train_digest": first["train_digest"], "grammar_version": first["grammar_version"],
        "train_pool": first["train_pool"], "trained": trained_learners(trained),
        "missing": [LABELS.get(lr, lr) for lr, why in reasons.items() if why == ["no run"]],
        "curves": _curves(track_dir, track, site, reasons, mine) if track != MIXED else None,
        "scoring": _scoring_text(track, first),
    }


def _draw_track_figure(track: str, part: pd.DataFrame, runs: list[dict[str, Any]], reasons: dict[str, list[str]],
                       site: Path) -> str:
    """Draw the track's score figure into ``site``, each learner's legend entry with its marks;
    returns its path in the site."""
    figure = FIGURE if track == MIXED else FIGURE.replace(".png", f"-{track}.png")
    marks = {r["learner"]: f" ({entry_marks(r)})" for r in runs if entry_marks(r)}
    draw_figure(part, site / figure, marks | {lr: " ⚠ incomplete" for lr, why in reasons.items() if why})
    return figure


def _scoring_text(track: str, first: dict[str, Any]) -> str:
    """What a track's scores are taken under, for the page (``first``: the track's fullest run record)."""
    if track == MIXED:
        return "every built-in chain under which a dilemma is one"
    text = f"the {first['chain']} chain alone, on the env ids that are a dilemma under it (trained on its cost)"
    return text + (", those of the v2 splits: Random leaves them headroom" if first.get("split_version", 1) != 1 else "")


def trained_learners(trained: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """How each trained learner of a track was trained, from its first run's record: a chain's track
    trains every learner in fleets with its Table 1 hyper-parameters, the mixed track SB3's PPO, and
    the page must not describe the one as the other."""
    learners = []
    for learner in _in_order([r["learner"] for r in trained]):
        run = next(r for r in trained if r["learner"] == learner)
        if run.get("engine") == "fleet":
            how = f"fleet engine, {run['fleet_runs']} runs per fleet, {run.get('protocol', 'paper')} protocol"
            if run.get("device", "cpu") != "cpu":
                how += f", on {run['device']}"
        else:
            how = "SB3 PPO"
        learners.append({"label": LABELS.get(learner, learner), "how": how, "n_envs": run.get("n_envs"),
                         "policy": run.get("policy", "MlpPolicy on the flattened (20, 16, 16) grid"),
                         "hparams": run.get("hparams") or {}})
    return learners


def _curves(root: Path, track: str, site: Path, reasons: dict[str, list[str]], frame: pd.DataFrame) -> dict[str, Any]:
    """The track's learning-curve figure (drawn into ``site``) and its caption's facts; ``frame``: the
    track's pairs (Random's seen score is the curves' reference line)."""
    curves, problems = read_curves(root, track)
    figure = f"track/track_curves-{track}.png"
    random = frame[(frame["learner"] == "random") & (frame["set"] == "seen")]
    random_seen = float(random.groupby("env_id")["range_score"].mean().mean()) if not random.empty else None
    if not curves.empty:
        draw_curves(curves, site / figure, LABELS, COLOURS, lambda lr: " ⚠ incomplete" if reasons.get(lr) else "",
                    TRACK_TITLES.get(track, track), random_seen)
    return {"figure": figure if not curves.empty else "", "problems": problems, "random_seen": random_seen,
            "summary": [{**row, "label": LABELS.get(row["learner"], row["learner"]), "incomplete": bool(reasons.get(row["learner"]))}
                        for row in curve_summary(curves)] if not curves.empty else []}


def _release_note(release: dict[str, Any] | None) -> dict[str, Any] | None:
    """What the page says about the release it reads: its name, commits, and whether it is complete."""
    if release is None:
        return None
    commits = ", ".join(c[:7] for c in release.get("commits") or []) or "not recorded by the runs"
    return {"name": release["name"], "title": release.get("title", release["name"]),
            "created": str(release.get("created", ""))[:10], "commits": commits,
            "built_at": str(release.get("built_at_commit", ""))[:7], "complete": bool(release.get("complete")),
            "unfinished": release.get("unfinished") or [], "models": release.get("models", ""),
            "missing_tracks": [t for t, learners in (release.get("status") or {}).items()
                               if learners and all(why == ["no run"] for why in learners.values())]}


def write_page(site: Path, track_dir: Path | None, common: dict[str, Any], resamples: int = DEFAULT_RESAMPLES,
               release: dict[str, Any] | None = None) -> Path:
    text = render("track.html", **track_context(common, track_dir, site, resamples, release))
    (site / PAGE).write_text(text, encoding="utf-8")
    return site / PAGE


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="python -m leaderboard.track", description="The generalisation track's page and table.")
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--results", type=Path, help="the --out of python -m runners.track")
    source.add_argument("--release", type=Path, help="a track release (python -m leaderboard.track_release), verified first")
    parser.add_argument("--site", type=Path, help="write track.html (and its figure) into this site directory")
    parser.add_argument("--resamples", type=int, default=DEFAULT_RESAMPLES)
    add_debug_flag(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:

    args = build_parser().parse_args(argv)
    manifest = None
    if args.release is not None:
        try:
            manifest = verify_release(args.release)
        except ValueError as exc:
            raise UserError(str(exc)) from exc
        args.results = args.release
    if not (args.results / "runs").is_dir():
        raise UserError(f"{args.results}: no runs/ directory. Fix: pass the --out of python -m runners.track")
    frame, records = load_runs(args.results)
    if frame.empty:
        raise UserError(f"{args.results}: no finished run (result.json). Fix: run python -m runners.track first")
    summary = summarise(frame, args.resamples)
    need = Requirement.from_dict(manifest.get("requirement")) if manifest else Requirement()
    incomplete = status(records, [f"{CURVES_DIR}/{p.name}" for p in (args.results / CURVES_DIR).glob("*.csv")], need)
    samples = {r["learner"]: entry_marks(r) for r in records if entry_marks(r)}
    for _, row in summary.iterrows():
        mark = (" ⚠ incomplete" if incomplete.get(row["track"], {}).get(row["learner"])
                else f" ({samples[row['learner']]})" if row["learner"] in samples else "")
        print(f"{row['track']:<11} {row['score']:<12} {row['learner']:<11} {row['set']:<8} {row['mean']:+.3f} {_ci(row)}{mark}")
    if args.site is not None:
        args.site.mkdir(parents=True, exist_ok=True)
        assets = args.site / "assets"
        assets.mkdir(exist_ok=True)
        for name in ("site.css", "site.js"):
            if not (assets / name).is_file():
                shutil.copyfile(Path(__file__).parent / "web" / "static" / name, assets / name)
        common = {"title": "Generalisation track", "root": "", "current": PAGE, "nav": NAV, "stamp": "",
                  "results_name": str(args.results), "source_parts": [], "marks": MARKS}
        print(write_page(args.site, args.results, common, args.resamples, manifest))
    return 0


if __name__ == "__main__":
    sys.exit(run_cli(lambda: main(sys.argv[1:]), (), sys.argv[1:]))
