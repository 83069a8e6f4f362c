#!/usr/bin/env bash
# The generalisation track's fleets on a lent GPU, in one go (at most 4 minutes; issue 44, item 3).
#
# Why: `runners.track --device cuda` trains a chain's fleets' networks on the GPU while the mixture
# (its tables: hundreds of dilemmas' state graphs) is stepped on the host. Only a GPU can show
#   1. that it runs: the track's CUDA test (tests/test_track_fleet.py -k gpu: PPO and CPO fleets
#      through `runners.track --device cuda`, results written);
#   2. what it gains: benchmarks/bench_track_fleet.py's rates (env steps per wall second after one
#      untimed warm-up update) on cuda at the release's fleet of 5 runs and at 15, and on one CPU
#      thread of the same machine for the ratio, on the Utility v2 pool's first 50 dilemmas (a quick
#      build; a step's cost does not depend on the pool's size).
# The splits come from $MORALITY_GYM_CACHE (carry a copy: the first generation takes minutes).
#
# Usage (repository root, packages as for gpu_check.sh):  OUT=/tmp/gpu bash benchmarks/gpu_track_check.sh
# DRY=1 runs the same steps on the CPU (a check that the script and its Python parts work).
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-/tmp/gpu-track}
PYTHON=${PYTHON:-python3}
mkdir -p "$OUT"
export PYTHONPATH="${PYTHONPATH:-$PWD}" PYTHONUNBUFFERED=1 MORALITY_GYM_CACHE="${MORALITY_GYM_CACHE:-$PWD/.gpu-cache}"
if [ -d /tmp/gpu-site ]; then export PYTHONPATH="/tmp/gpu-site:$PYTHONPATH"; fi
DEVICE=cuda
if [ "${DRY:-0}" = 1 ]; then DEVICE=cpu; fi
start=$(date +%s)
echo "== track test (cuda)"
timeout 60 "$PYTHON" -m pytest -q -p no:cacheprovider tests/test_track_fleet.py -k "gpu or device" 2>&1 | tail -4 \
  | tee "$OUT/track-tests.txt"
for runs in 5 15; do
  echo "== track fleets on $DEVICE, K=$runs"
  timeout $(( 40 + 3 * runs )) "$PYTHON" -m benchmarks.bench_track_fleet --device "$DEVICE" --learners ppo cpo --runs "$runs" --pool 50 \
    --json "$OUT/track-fleet.jsonl"
done
echo "== track fleets on one CPU thread, K=5"
timeout 40 "$PYTHON" -m benchmarks.bench_track_fleet --device cpu --learners ppo cpo --runs 5 --pool 50 \
  --json "$OUT/track-fleet.jsonl"
echo "gpu_track_check: $(( $(date +%s) - start )) s"
