#!/usr/bin/env bash
# The compiled update engine on a lent GPU, in one go (at most 5 minutes; issue 47, item 6).
#
# Why a script of its own: benchmarks/gpu_check.sh measures the eager engine; this one runs what only a
# GPU can show of update=compiled (inductor's Triton kernels, CUDA graphs via mode="reduce-overhead"):
#   1. the CUDA tests: a compiled fleet on cuda against the eager one (tests/test_fleet_compiled.py; 120 s:
#      at 45 s the compiles let one of three finish, 2026-11-28);
#   2. the compiled learner rates of PPO and CPO at K=336, one process (its warm-up pays the compile:
#      warmup_s) and eight processes sharing the card (benchmarks/gpu_probe.py --update compiled); the
#      eager engine's are in benchmarks/gpu_runs/2026-11-27-h200.jsonl (rerun them with --update eager
#      on the same card before comparing);
#   3. one learner column of the paper Table 1 end to end (benchmarks/gpu_table1_column.sh) with what
#      is left of the 5 minutes: a column does not finish in that (a rerun resumes it). The sweep
#      runs the eager engine: the sweep setting for the compiled one is not built yet.
# Compiled kernels are cached under $OUT/inductor-cache, so the 8 processes compile once between them.
#
# Usage (repository root, packages as for gpu_check.sh):  OUT=/tmp/gpu bash benchmarks/gpu_compiled_check.sh
# BUDGET=<seconds> (default 300): the column gets what is left of it.
# DRY=1 runs the same steps on the CPU with tiny sizes (a check that the script and its Python parts work).
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-/tmp/gpu-check}
PYTHON=${PYTHON:-python3}  # DRY=1 PYTHON=.venv/bin/python: the CPU check at home
mkdir -p "$OUT"
export PYTHONPATH="${PYTHONPATH:-$PWD}" PYTHONUNBUFFERED=1 TORCHINDUCTOR_CACHE_DIR="$OUT/inductor-cache"
if [ -d /tmp/gpu-site ]; then export PYTHONPATH="/tmp/gpu-site:$PYTHONPATH"; fi
start=$(date +%s)
if [ "${DRY:-0}" = 1 ]; then
  DEVICE=cpu K=2 PROCS=2 LEARNERS="cpo" TEST_LIMIT=30 PROBE_LIMIT=240 PROCS_LIMIT=240 COLUMN=0
else
  DEVICE=cuda K=336 PROCS=8 LEARNERS="ppo cpo" TEST_LIMIT=120 PROBE_LIMIT=50 PROCS_LIMIT=75 COLUMN=1
fi
echo "== test (cuda)"
timeout "$TEST_LIMIT" "$PYTHON" -m pytest -q -p no:cacheprovider tests/test_fleet_compiled.py -k gpu 2>&1 | tail -4 | tee "$OUT/compiled-tests.txt"
for learner in $LEARNERS; do
  echo "== $learner K=$K update=compiled: one process, then $PROCS"
  timeout "$PROBE_LIMIT" "$PYTHON" -m benchmarks.gpu_probe --device "$DEVICE" --learners "$learner" --sizes "$K" --updates 1 \
    --update compiled --json "$OUT/compiled-probe.jsonl"
  timeout "$PROCS_LIMIT" "$PYTHON" -m benchmarks.gpu_probe --device "$DEVICE" --learners "$learner" --sizes "$K" --updates 1 \
    --procs "$PROCS" --update compiled --json "$OUT/compiled-probe.jsonl"
done
left=$(( ${BUDGET:-300} - ($(date +%s) - start) ))
if [ "$COLUMN" = 1 ] && [ "$left" -gt 30 ]; then
  echo "== one column of the paper Table 1 (${left} s left)"
  LIMIT=$left OUT="$OUT" ALGO=${ALGO:-ppo} WORKERS=$PROCS bash benchmarks/gpu_table1_column.sh
fi
echo "gpu_compiled_check: $(( $(date +%s) - start )) s"
