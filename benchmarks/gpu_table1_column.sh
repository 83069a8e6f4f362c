#!/usr/bin/env bash
# One learner column of the paper Table 1 (paper preset, paper protocol) end to end on a GPU.
#
# Why: the fleet_device benchmark projects Table 1 from rates; this runs one whole column through the
# sweep (plan, fleets, evaluations, result files) as `make reproduce-table1 DEVICE=cuda` would, so
# the projection can be checked against a wall clock. A column is 378 runs and 342M env steps.
# Results stay under $OUT (bring them home with the device tool's $OUT and compare them with the
# release: python -m leaderboard.engines releases/paper-table1-v1 $OUT/column).
#
# Usage (repository root, after benchmarks/gpu_check.sh set up the packages):
#   OUT=/tmp/gpu ALGO=ppo_lag WORKERS=8 bash benchmarks/gpu_table1_column.sh
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-/tmp/gpu-check}
ALGO=${ALGO:-ppo_lag}
WORKERS=${WORKERS:-8}
LIMIT=${LIMIT:-540}
export PYTHONPATH="${PYTHONPATH:-/tmp/gpu-site:$PWD}"
mkdir -p "$OUT"
start=$(date +%s)
timeout "$LIMIT" python3 -m runners.sweep experiment=table1 protocol=paper "algo=[$ALGO]" preset=paper device=cuda \
  launcher.workers="$WORKERS" mlflow=false gif=false results_dir="$OUT/column" 2>&1 | tail -25 | tee "$OUT/column.txt"
echo "wall: $(( $(date +%s) - start )) s for algo=$ALGO with $WORKERS workers (limit $LIMIT s; a rerun resumes)" | tee -a "$OUT/column.txt"
