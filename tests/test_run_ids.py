"""The run ids of the built-in learners never change by accident.

A run id is the hash of the resolved run configuration (:mod:`runners.plan.runs`); results on disk are
found by it, so a refactoring of how the configuration is written (Python defaults, YAML files,
typed schemas) must give byte-identical run configs for every built-in algo, protocol and preset.
``tests/data/pinned_run_ids.json`` was recorded at main 11e6230, before the configuration became
typed (issue 12); regenerate it only for a change that is meant to change the numbers, with
``python -m tests.test_run_ids``, and say so in the commit.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

PINNED = Path(__file__).resolve().parent / "data" / "pinned_run_ids.json"
ALGOS = ("random", "ppo", "ppo_shaped", "ppo_lag", "cpo")
PROTOCOLS = ("paper", "corrected")
PRESETS = ("smoke", "quick", "paper")
SCENARIO = "switch_standard"


def current_run_ids(results_dir: Path) -> dict[str, dict[str, list[str]]]:
    """``{"<protocol>/<preset>": {algo: [run ids in plan order]}}`` for one scenario (every variant, the preset's seeds)."""
    from hydra import compose, initialize_config_dir

    from runners.compose.search_path import CONF_DIR
    from runners.compose.sweep_config import validate
    from runners.plan.runs import expand_sweep

    out: dict[str, dict[str, list[str]]] = {}
    for protocol in PROTOCOLS:
        for preset in PRESETS:
            with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
                cfg = compose("config", overrides=[f"algo=[{','.join(ALGOS)}]", "chain=utility", f"scenario=[{SCENARIO}]",
                                                   f"protocol={protocol}", f"preset={preset}", "mlflow=false",
                                                   f"results_dir={results_dir}"])
            by_algo: dict[str, list[str]] = {}
            for run in expand_sweep(validate(cfg)):
                by_algo.setdefault(run.config["algo"]["name"], []).append(run.run_id)
            out[f"{protocol}/{preset}"] = by_algo
    return out


def test_builtin_run_ids_are_pinned(tmp_path: Path) -> None:
    pinned = json.loads(PINNED.read_text())
    current = current_run_ids(tmp_path)
    assert set(current) == set(pinned)
    for key, by_algo in pinned.items():
        assert set(current[key]) == set(ALGOS), key
        for algo, ids in by_algo.items():
            assert current[key][algo] == ids, f"{key} {algo}: run ids changed; results on disk would no longer be found"


if __name__ == "__main__":  # regenerate (only for a change meant to change the numbers)
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        PINNED.write_text(json.dumps(current_run_ids(Path(tmp)), indent=1, sort_keys=True) + "\n")
    print(f"wrote {PINNED}", file=sys.stderr)
