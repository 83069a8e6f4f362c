#!/usr/bin/env bash
# The GPU check, prepared to run in one go on a lent GPU machine (about 5 minutes on an H100/H200).
#
# Why one script: a GPU is lent to a session only by chance and for minutes, and CI never has one;
# everything is built and tested on the CPU, and this runs what only a GPU can show:
#   1. the tests that need CUDA (fleets on cuda against the CPU; the device simulator and cost on cuda
#      against the host's, bit for bit), and the meta-device tests;
#   2. the fleet_device benchmark (env steps/s per learner at K = 21..1,512, the simulators alone,
#      Table 1 projected), written to $OUT/BENCHMARKS.md.
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
export PYTHONPATH="$PWD"
if ! python3 -c "import gymnasium, stable_baselines3, sb3_contrib, hydra, submitit" 2>/dev/null; then
  if ! ls wheels/*.whl >/dev/null 2>&1; then
    echo "gpu_check: missing packages and no wheels/ (run 'make gpu-wheels' on a machine with the index, carry wheels/)" >&2
    exit 2
  fi
  python3 -m pip install -q --no-index --no-deps --target /tmp/gpu-site wheels/*.whl
  export PYTHONPATH="/tmp/gpu-site:$PWD"
fi
{ nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
  python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda, torch.cuda.get_device_name(0))"
} 2>&1 | tee "$OUT/device.txt"
echo "== tests (cuda and meta device)" | tee "$OUT/tests.txt"
timeout 150 python3 -m pytest -q -p no:cacheprovider -x \
  tests/test_fleet_device.py tests/test_torch_sim.py "tests/test_fleet.py::test_a_fleet_on_the_gpu_trains_as_on_the_cpu" 2>&1 \
  | tail -15 | tee -a "$OUT/tests.txt"
echo "== benchmark fleet_device" | tee "$OUT/bench.txt"
timeout 420 python3 -m benchmarks.run --only fleet_device --no-progress --output "$OUT/BENCHMARKS.md" 2>&1 | tail -5 | tee -a "$OUT/bench.txt"
sed -n '/^## Fleet engine per device/,/^## /p' "$OUT/BENCHMARKS.md" 2>/dev/null | head -40
