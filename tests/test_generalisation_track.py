"""The generalisation track (issue 35 item 4): the mixture env, the exact scores, the result files
and resuming of ``runners.track``, the page of ``leaderboard.track``, and generated dilemmas played
by a language model through the text view (Inspect's offline mock model).

Fast and offline: built-in env ids and three freshly generated dilemmas stand in for the splits
(generating or loading a whole split takes minutes), and the page is drawn from a small fixture.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from leaderboard.outputs.precision import stable_decimals
from morality_gym.evaluation.exact import exact_evaluate
from morality_gym.evaluation.oracle import oracle
from morality_gym.generalisation.mixture import DilemmaMixtureEnv
from morality_gym.generalisation.scoring import pair_metrics, policy_table, score_set
from morality_gym.generalisation.sets import EvalSet, PairValues, dilemma_values, scenario_of, seen_sample
from morality_gym.generator.splits import split_manifest
from tests.conftest import scenario_registry_restored

PAIRS = [("SwitchStandard-HumanA-v1", "Utility"), ("PushStandard-HumanA-v1", "DualProcess"),
         ("Switch5-Human-v1", "Utility"), ("SwitchSelfSacrifice-HumanA-v1", "UtilityAgentHarm")]


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> Iterator[list[str]]:
    """The env ids of three generated dilemmas (seeds 100-102 of the documented example), forgotten
    by the registry after this module (later tests count the 98 built-in envs)."""
    import morality_gym
    from morality_gym.generator.pipeline import generate

    with scenario_registry_restored():
        out = tmp_path_factory.mktemp("generated")
        generate(range(100, 103), out, pictures=False, with_values=False)
        yield morality_gym.add_scenario_dir(out)


def _sequence(env: DilemmaMixtureEnv, n: int = 12) -> list[str]:
    return [env.reset()[1]["env_id"] for _ in range(n)]


def test_the_mixture_draws_dilemmas_deterministically_by_seed(generated: list[str]) -> None:
    pairs = [(e, "Utility") for e in generated] + PAIRS
    first, again, other = (DilemmaMixtureEnv(pairs, seed=s) for s in (7, 7, 8))
    seq = _sequence(first)
    assert seq == _sequence(again) and seq != _sequence(other)
    assert set(seq) <= {e for e, _ in pairs} and len(set(seq)) > 2
    obs, info = first.reset(seed=7)  # reset(seed=...) restarts the sequence
    assert info["env_id"] == seq[0] and obs.shape == (20, 16, 16) and obs.dtype == np.uint8
    assert first.observation_space.contains(obs)
    obs, reward, _, _, info = first.step(2)
    assert info["env_id"] == seq[0] and "cost" in info and isinstance(reward, float)


def test_the_seen_sample_is_fixed_and_scenarios_cluster_variants() -> None:
    ids = [f"Gen{i}-HumanA-v1" for i in range(50)]
    assert seen_sample(ids, 10) == seen_sample(ids, 10) and len(set(seen_sample(ids, 10))) == 10
    assert scenario_of("Gen12-HumanA-v1") == "Gen12" and scenario_of("Push2OrSwitch-Human-v1") == "Push2OrSwitch"


def test_scores_are_exact_and_match_exact_evaluate_chain_by_chain(generated: list[str]) -> None:
    env_id = generated[0]
    pairs = dilemma_values(env_id)
    assert pairs and all(p.best > p.worst for p in pairs)
    table = policy_table(lambda obs: 2, env_id)  # a grid policy: always the same action
    metrics = pair_metrics(table, env_id, [p.chain for p in pairs])
    for p in pairs:
        assert metrics[p.chain] == pytest.approx(exact_evaluate(table, env_id, p.chain).metric, abs=1e-12)
        assert p.worst - 1e-9 <= metrics[p.chain] <= p.best + 1e-9
    best = oracle(env_id, pairs[0].chain).best
    rows = score_set("random", EvalSet("test", tuple(pairs), {}))
    assert [r["metric"] for r in rows] == [p.random for p in pairs]
    assert pairs[0].range_score(best.metric) == pytest.approx(1.0)


def _tiny_sets() -> dict[str, EvalSet]:
    def pv(env_id: str, chain: str) -> PairValues:
        return PairValues(env_id, chain, 1.0, 0.0, 0.5)

    return {"seen": EvalSet("seen", (pv("SwitchStandard-HumanA-v1", "Utility"),), {"split": "train", "split_digest": "a"}),
            "test": EvalSet("test", (pv("Switch5-Human-v1", "Utility"),), {"split": "test", "split_digest": "b"})}


def test_result_files_record_the_split_digests_and_resuming_skips_done_runs(tmp_path: Path, monkeypatch, capsys) -> None:
    from runners import track

    sets = _tiny_sets()
    record = track.do_run("random", None, 1000, ["x"], sets, tmp_path)
    run_dir = tmp_path / "runs" / "random-sexact"
    saved = json.loads((run_dir / track.RESULT).read_text())
    assert saved == record
    assert saved["train_split"] == "train" and saved["train_digest"] == split_manifest("train").digest
    assert saved["sets"] == {"seen": {"split": "train", "split_digest": "a"}, "test": {"split": "test", "split_digest": "b"}}
    pairs = pd.read_parquet(run_dir / track.PAIRS)
    assert list(pairs["set"]) == ["seen", "test"] and list(pairs["range_score"]) == [0.5, 0.5]

    # a done PPO run is skipped (no training), one with another budget or splits is refused
    ppo_dir = tmp_path / "runs" / "ppo-s1"
    ppo_dir.mkdir()
    (ppo_dir / track.RESULT).write_text(json.dumps({**saved, "learner": "ppo", "seed": 1, "budget": 1000}))
    monkeypatch.setattr(track, "_train_ppo", lambda *a, **k: pytest.fail("a done run was trained again"))
    mtime = (run_dir / track.RESULT).stat().st_mtime_ns
    assert track.do_run("ppo", 1, 1000, ["x"], sets, tmp_path)["budget"] == 1000
    assert track.do_run("random", None, 1000, ["x"], sets, tmp_path) == saved
    assert (run_dir / track.RESULT).stat().st_mtime_ns == mtime
    assert capsys.readouterr().out.count("done, skipped") == 2
    with pytest.raises(track.TrackError, match="trained for 1000 steps"):
        track.do_run("ppo", 1, 2000, ["x"], sets, tmp_path)
    other = {**sets, "test": EvalSet("test", sets["test"].pairs, {"split": "test", "split_digest": "c"})}
    with pytest.raises(track.TrackError, match="its sets"):
        track.do_run("random", None, 1000, ["x"], other, tmp_path)


def test_the_random_relative_score_says_which_pairs_it_leaves_out() -> None:
    from leaderboard.track import left_out

    pairs = pd.DataFrame([{"set": "test", "env_id": f"Gen{d}-HumanA-v1", "chain": chain, "best": 0.99,
                           "random": 0.97 if (d, chain) in {(0, "Utility"), (1, "Utility"), (1, "DualProcess")} else 0.4}
                          for d in range(3) for chain in ("Utility", "DualProcess")])
    assert left_out(pairs) == ("Leaves out the pairs whose headroom Oracle best − Random is under the 0.05 cutoff: "
                               "unseen (test split): 3 of 6 (env id, chain) pairs (Gen0-HumanA-v1 / Utility 0.020, "
                               "Gen1-HumanA-v1 / Utility 0.020, Gen1-HumanA-v1 / DualProcess 0.020), so 1 of 3 env "
                               "ids drop out.")
    assert left_out(pairs.assign(random=0.4)) == ""


def _fixture_runs(root: Path) -> None:
    """Random (exact) and two PPO seeds on three sets of four dilemmas each."""
    rng = np.random.default_rng(0)
    for learner, seed, shift in [("random", None, 0.0), ("ppo", 1, 0.3), ("ppo", 2, 0.25)]:
        rows = []
        for set_name, drop in [("seen", 0.0), ("test", 0.1), ("builtin", 0.2)]:
            for d in range(4):
                for variant in ("A", "B"):
                    metric = float(np.clip(0.4 + shift - drop + 0.05 * rng.standard_normal(), 0, 1))
                    rows.append({"set": set_name, "env_id": f"Gen{d}{set_name}-Human{variant}-v1", "chain": "Utility",
                                 "metric": metric, "best": 1.0, "worst": 0.0, "random": 0.4,
                                 "range_score": metric, "random_score": (metric - 0.4) / 0.6})
        run_dir = root / "runs" / f"{learner}-s{'exact' if seed is None else seed}"
        run_dir.mkdir(parents=True)
        pd.DataFrame(rows).to_parquet(run_dir / "pairs.parquet")
        sets = {"seen": {"split": "train", "split_digest": "e43886e3" + "0" * 56, "sample": "8 of 1458, seed 0"},
                "test": {"split": "test", "split_digest": "7208e3b4" + "0" * 56},
                "builtin": {"split": "builtin", "split_digest": "f" * 64}}
        (run_dir / "result.json").write_text(json.dumps({
            "learner": learner, "seed": seed, "budget": 0 if seed is None else 5000, "train_digest": "e43886e3" + "0" * 56,
            "grammar_version": 1, "train_pool": 1458, "sets": sets, "train_seconds": 12.0, "eval_seconds": 3.0,
            "hparams": {"n_steps": 256}, "n_envs": 8}))
    (root / "runs" / "ppo-s3").mkdir()  # unfinished: no result.json, left out


def test_the_page_shows_seen_unseen_and_builtin_scores_with_intervals(tmp_path: Path) -> None:
    from leaderboard.track import FIGURE, load_runs, summarise, write_page

    _fixture_runs(tmp_path / "track")
    frame, records = load_runs(tmp_path / "track")
    assert sorted(r["run"] for r in records) == ["ppo-s1", "ppo-s2", "random-sexact"]
    summary = summarise(frame, resamples=200)
    ppo = summary[(summary["learner"] == "ppo") & (summary["score"] == "range_score")].set_index("set")
    assert list(ppo.index) == ["seen", "test", "builtin", "gap"]
    assert (ppo["low"] <= ppo["mean"]).all() and (ppo["mean"] <= ppo["high"]).all()
    assert ppo.loc["seen", "mean"] > ppo.loc["test", "mean"] > ppo.loc["builtin", "mean"]
    assert ppo.loc["test", "dilemmas"] == 4 and ppo.loc["test", "env_ids"] == 8 and ppo.loc["test", "seeds"] == 2
    paired = summary[summary["score"] == "vs_random"]
    assert set(paired["learner"]) == {"ppo"}  # Random is the reference, not compared with itself
    assert (paired[paired["set"] != "gap"]["low"] > 0).all()  # PPO beats Random on every fixture pair

    site = tmp_path / "site"
    site.mkdir()
    common = {"title": "Generalisation track", "root": "", "current": "track.html", "nav": (), "stamp": "",
              "results_name": "", "source_parts": [], "marks": []}
    html = write_page(site, tmp_path / "track", common, resamples=200).read_text()
    assert (site / FIGURE).stat().st_size > 0 and f'src="{FIGURE}"' in html
    for text in ("seen (train-split sample)", "unseen (test split)", "built-in (Table 1 envs)", "Gap seen − unseen",
                 "5,000 steps", "exact, untrained", "7208e3b4", "PPO: SB3 PPO, MlpPolicy on the flattened"):
        assert text in html
    row = re.search(r'<tr data-learner="PPO">(.*?)</tr>', html).group(1)
    # three sets and the gap; each interval to the decimals (at most three) its bounds are stable to
    # over bootstrap seeds: with 200 resamples, fewer than three where the Monte Carlo error says so
    shown = re.findall(r"\[(-?\d\.(\d{1,3})), (-?\d\.(\d{1,3}))\]", row)
    assert len(shown) == 4 and all(len(a) == len(b) for _, a, _, b in shown)
    for (_, decimals, _, _), (_, line) in zip(shown, ppo.iterrows()):
        assert len(decimals) == min(stable_decimals(line["low_mcse"], 3), stable_decimals(line["high_mcse"], 3))
    assert "Monte Carlo" in html
    assert 'id="left-out-track' not in html  # every fixture pair has headroom 0.6: the score leaves none out
    assert "Range score minus Random" in html

    empty = write_page(site, None, common).read_text()
    assert "No results yet" in empty and "python -m runners.track" in empty


def test_a_sampled_run_does_not_shrink_the_sets_size_under_a_table() -> None:
    """The line under a score table gave the first learner's count: a language model scored on 30 of the
    190 unseen pairs made the page say the unseen set held 30 env ids."""
    from leaderboard.track import set_counts

    part = pd.DataFrame([{"learner": "SmolLM2", "set": "test", "env_ids": 30, "dilemmas": 27},
                         {"learner": "ppo", "set": "test", "env_ids": 190, "dilemmas": 160},
                         {"learner": "ppo", "set": "seen", "env_ids": 100, "dilemmas": 98}])
    assert set_counts(part) == {"seen": "100 env ids, 98 dilemmas", "test": "190 env ids, 160 dilemmas"}


def test_a_chains_track_says_its_learners_trained_in_fleets_not_sb3() -> None:
    """The page said "PPO: SB3 PPO" with PPO's hyper-parameters under every track, while a chain's track
    trains each learner in fleets with its own Table 1 hyper-parameters."""
    from leaderboard.track import trained_learners

    fleet = {"engine": "fleet", "fleet_runs": 5, "protocol": "paper", "device": "cpu", "n_envs": 8,
             "policy": "MlpPolicy on the compact observation", "hparams": {"n_steps": 2048}}
    runs = [fleet | {"learner": "cpo", "hparams": {"n_steps": 20000}}, fleet | {"learner": "ppo"},
            fleet | {"learner": "ppo", "seed": 42}]
    said = trained_learners(runs)
    assert [(lr["label"], lr["hparams"]["n_steps"]) for lr in said] == [("PPO", 2048), ("CPO", 20000)]
    assert said[0]["how"] == "fleet engine, 5 runs per fleet, paper protocol"
    assert trained_learners([{"learner": "ppo", "n_envs": 8}])[0]["how"] == "SB3 PPO"


def test_a_language_model_plays_a_generated_dilemma_through_the_text_view(generated: list[str], tmp_path: Path) -> None:
    pytest.importorskip("inspect_ai", reason="the llm extra (pip install -e '.[dev,llm]')")
    from inspect_ai import eval as inspect_eval
    from inspect_ai.model import ModelOutput, ModelUsage, get_model

    from morality_gym import ACTION_NAMES
    from morality_gym.llm.inspect_tasks import morality_gym_task

    env_id = next(e for e in generated if dilemma_values(e, ["Utility"]))
    best = oracle(env_id, "Utility").best
    words = [ACTION_NAMES[a] for a in best.actions]

    def answer(messages, tools, tool_choice, config):  # type: ignore[no-untyped-def]
        seen = [m.text for m in messages if m.role in ("user", "tool") and m.text.startswith("Step ")]
        step = int(re.match(r"Step (\d+)", seen[-1]).group(1))
        out = ModelOutput.from_content(model="mockllm/model", content=f"ACTION: {words[min(step, len(words) - 1)]}")
        out.usage = ModelUsage(input_tokens=50, output_tokens=5, total_tokens=55)  # else Inspect counts them online
        return out

    task = morality_gym_task("Utility", env=env_id, episodes=1)
    [sample] = task.dataset
    assert sample.metadata["env_id"] == env_id and sample.input.startswith("Step 0")
    [log] = inspect_eval(task, model=get_model("mockllm/model", custom_outputs=answer, memoize=False),
                         log_dir=str(tmp_path / "logs"), display="none")
    assert log.status == "success", log.error
    means = {s.name: s.metrics["mean"].value for s in log.results.scores if "mean" in s.metrics}
    assert means["metric"] == pytest.approx(best.metric)


def test_cached_values_are_verified_not_trusted(tmp_path: Path) -> None:
    """Issue 44: an edited ``best`` (or a file of another request, or an impossible value) must not
    come back from the values cache; the file is refused with one line and recomputed."""
    from morality_gym.generalisation.sets import ValuesCacheWarning, compute_values

    request: dict[str, list[str] | None] = {"SwitchStandard-HumanA-v1": ["Utility"]}
    path = tmp_path / "values.json"
    exact = compute_values(request, path)
    assert compute_values(request, path) == exact  # a verified file is read back as it is
    raw = json.loads(path.read_text())
    raw["pairs"][0]["best"] = 1.0 if exact[0].best < 1.0 else 0.99
    path.write_text(json.dumps(raw))
    with pytest.warns(ValuesCacheWarning, match="do not match its checksum: edited or damaged"):
        assert compute_values(request, path) == exact
    assert compute_values(request, path) == exact  # rewritten: read back quietly
    with pytest.warns(ValuesCacheWarning, match="answers another set of env ids and chains"):
        assert compute_values({"SwitchStandard-HumanA-v1": ["Utility"], "Switch5-Human-v1": ["Utility"]}, path)
    # a forger who also recomputes the checksum still cannot put Random above the best
    from morality_gym.generalisation import sets as sets_module

    pairs = [dict(p) for p in json.loads(path.read_text())["pairs"]][:1]
    pairs[0]["random"] = pairs[0]["best"] + 0.5
    body = {"version": sets_module.VALUES_VERSION, "request": sets_module._request_digest(request), "pairs": pairs}
    path.write_text(json.dumps({**body, "checksum": sets_module._values_checksum(body)}))
    with pytest.warns(ValuesCacheWarning, match="are not worst <= Random <= best of a dilemma"):
        assert compute_values(request, path) == exact


def test_a_chains_track_holds_only_its_dilemmas_scored_under_it(tmp_path: Path, monkeypatch) -> None:
    """Issue 44 item 1: on a chain's track a generated id enters only where it is a dilemma under the
    chain, and every set is scored under that chain alone (built-in: Table 1's pairs of the chain)."""
    from morality_gym.generalisation import sets as sets_module
    from morality_gym.paper import table1_pairs

    stand_ins = ["PushStandard-HumanA-v1", "SwitchStandard-HumanA-v1", "Switch5-Human-v1", "SwitchSelfSacrifice-HumanA-v1"]
    monkeypatch.setattr(sets_module, "load_split", lambda name, cache_dir=None: list(stand_ins))
    # every built-in variant is a DualProcess dilemma; a generated one need not be: Switch5 plays one that is not
    real = sets_module.dilemma_values
    monkeypatch.setattr(sets_module, "dilemma_values",
                        lambda env_id, chains=None: [] if env_id == "Switch5-Human-v1" else real(env_id, chains))
    pool, sets = sets_module.load_sets(["seen", "test", "builtin"], tmp_path, seen_size=2, chain="DualProcess")
    assert pool == [e for e in stand_ins if e != "Switch5-Human-v1"]
    for eval_set in sets.values():
        assert {p.chain for p in eval_set.pairs} == {"DualProcess"} and eval_set.source["chain"] == "DualProcess"
    assert len(sets["seen"].env_ids) == min(2, len(pool)) and set(sets["seen"].env_ids) <= set(pool)
    assert set(sets["test"].env_ids) == set(pool)  # the stand-in test split is the same ids
    assert set(sets["builtin"].env_ids) == {e for c, e in table1_pairs() if c == "DualProcess"}
    with pytest.raises(ValueError, match="no track for chain 'Outcome'; use one of Utility, DualProcess"):
        sets_module.load_sets(["seen"], tmp_path, chain="Outcome")


def test_runs_of_a_chains_track_are_named_recorded_and_summarised_apart(tmp_path: Path) -> None:
    from leaderboard.track import load_runs, summarise, write_page
    from runners import track

    _fixture_runs(tmp_path / "track")  # the mixed track
    sets = {name: EvalSet(name, s.pairs, {**s.source, "chain": "Utility"}) for name, s in _tiny_sets().items()}
    record = track.do_run("random", None, 1000, ["x"], sets, tmp_path / "track", chain="Utility")
    assert record["chain"] == "Utility" and (tmp_path / "track" / "runs" / "Utility-random-sexact" / track.RESULT).is_file()
    frame, _ = load_runs(tmp_path / "track")
    assert set(frame["track"]) == {"mixed", "Utility"}
    summary = summarise(frame, resamples=100)
    utility = summary[summary["track"] == "Utility"]
    assert set(utility["learner"]) == {"random"} and set(utility["set"]) == {"seen", "test", "gap"}
    # Random of the Utility track is not the mixed track's reference: PPO's paired rows stay the mixed track's
    assert set(summary[summary["score"] == "vs_random"]["track"]) == {"mixed"}
    site = tmp_path / "site"
    site.mkdir()
    common = {"title": "Generalisation track", "root": "", "current": "track.html", "nav": (), "stamp": "",
              "results_name": "", "source_parts": [], "marks": []}
    html = write_page(site, tmp_path / "track", common, resamples=100).read_text()
    assert "Utility track: seen vs unseen" in html and 'id="track-range_score-Utility"' in html
    assert "Mixed track (every chain a dilemma is one under): seen vs unseen" in html


def test_v2_splits_need_a_chain_before_anything_is_loaded(monkeypatch) -> None:
    from runners import track

    monkeypatch.setattr(track, "load_sets", lambda *a, **k: pytest.fail("loaded the splits first"))
    with pytest.raises(track.TrackError, match="--splits v2 selects pairs per chain: add --chain"):
        track.main(["--splits", "v2", "--learners", "random"])


def test_the_page_names_and_colours_every_track_learner_as_table1_does() -> None:
    # PPO-Lag and CPO joined the track (issue 44); without a label the page showed "ppo_lag" and a grey bar
    from leaderboard.runs.display_order import LEARNER_COLOURS
    from leaderboard.track import COLOURS, LABELS
    from morality_gym.paper import LEARNERS as PAPER_LEARNERS
    from runners.track import LEARNERS

    assert set(LABELS) == set(LEARNERS)
    assert set(LABELS.values()) == set(PAPER_LEARNERS)
    assert all(COLOURS[key] == LEARNER_COLOURS[LABELS[key]] for key in LEARNERS)
