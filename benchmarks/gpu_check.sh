#!/usr/bin/env bash
# The GPU check, prepared to run in one go on a lent GPU machine (about 6 minutes on an H100/H200).
#
# Why one script: a GPU is lent to a session only by chance and for minutes, and CI never has one;
# everything is built and tested on the CPU, and this runs what only a GPU can show:
#   1. the tests that need CUDA (fleets on cuda against the CPU, CPO's batched actor step among
#      them; the device simulator and cost on cuda against the host's, bit for bit);
#   2. where a fleet's time goes (benchmarks/gpu_probe.py: rollout vs update) for CPO at K=336;
#   3. what 8 processes sharing the GPU add up to (PPO and CPO fleets of 336), for the sweep's workers;
#   4. the fleet_device benchmark's cuda rows at K = 336 and 1,512 (the CPU rows are measured at
#      home), written to $OUT/BENCHMARKS.md, with Table 1 projected from them.
#
# The GPU machine has CUDA torch but no package index: `make gpu-wheels` here downloads the few wheels
# it lacks into wheels/ (shared/recipes/gpu-offline.md); carry wheels/ with the working tree. The
# checkout goes on PYTHONPATH rather than being installed (its torch pin would replace CUDA torch).
#
# Usage (repository root):  OUT=/tmp/gpu bash benchmarks/gpu_check.sh
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-/tmp/gpu-check}
mkdir -p "$OUT"
export PYTHONPATH="$PWD" PYTHONUNBUFFERED=1
if ! python3 -c "import gymnasium, stable_baselines3, sb3_contrib, hydra, submitit" 2>/dev/null; then
  if ! ls wheels/*.whl >/dev/null 2>&1; then
    echo "gpu_check: missing packages and no wheels/ (run 'make gpu-wheels' on a machine with the index, carry wheels/)" >&2
    exit 2
  fi
  python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/gpu-site wheels/*.whl || exit 2
  export PYTHONPATH="/tmp/gpu-site:$PWD"
fi
{ nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
  python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda, torch.cuda.get_device_name(0))"
} 2>&1 | tee "$OUT/device.txt"
echo "== tests (cuda)"
timeout 120 python3 -m pytest -q -p no:cacheprovider -k "cuda or gpu" \
  tests/test_torch_sim.py "tests/test_fleet.py::test_a_fleet_on_the_gpu_trains_as_on_the_cpu" 2>&1 | tail -8 | tee "$OUT/tests.txt"
echo "== CPO phases at K=336 (batched actor step)"
timeout 60 python3 -m benchmarks.gpu_probe --learners cpo --sizes 336 --json "$OUT/probe.jsonl"
echo "== 8 processes on one GPU"
timeout 110 python3 -m benchmarks.gpu_probe --learners ppo --sizes 336 --procs 8 --updates 1 --json "$OUT/probe.jsonl"
timeout 70 python3 -m benchmarks.gpu_probe --learners cpo --sizes 336 --procs 8 --json "$OUT/probe.jsonl"
echo "== benchmark fleet_device (cuda rows)"
MORALITY_GYM_BENCH_DEVICES=cuda MORALITY_GYM_BENCH_SIZES=${SIZES:-336,1512} timeout "${BENCH_LIMIT:-240}" \
  python3 -m benchmarks.run --only fleet_device --no-progress --output "$OUT/BENCHMARKS.md" 2>&1 | tail -5
sed -n '/^## Fleet engine per device/,/^## /p' "$OUT/BENCHMARKS.md" 2>/dev/null | head -40
