#!/usr/bin/env bash
# Everything a session lent a GPU measures, in one command of at most about 9 minutes (timeout_s=590).
#
# Why one command: a lent machine starts bare (a minute or more, counted against the session's 15
# minutes of device time) and goes back 30 s after a call, so the checks run back to back:
#   benchmarks/gpu_track_check.sh (issue 44: the track's fleets on CUDA, at most 4 minutes), then
#   benchmarks/gpu_compiled_check.sh (issue 47: the compiled update on CUDA; its Table 1 column
#   gets what is left of about 8.5 minutes in all).
# The wheels the machine lacks travel in wheels/ (`make gpu-wheels`), the splits the track needs in
# .gpu-cache/ (a copy of a generated $MORALITY_GYM_CACHE). What comes back is at most 8 files, so the
# logs and tables are gathered into $OUT at the end (the inductor cache stays on the machine).
#
# Usage (repository root, on the device tool):  bash benchmarks/gpu_session.sh   (writes into $OUT)
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-/tmp/gpu-session}
WORK=/tmp/gpu-work
mkdir -p "$OUT" "$WORK"
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/gpu-site wheels/*.whl || exit 2
export PYTHONPATH="/tmp/gpu-site:$PWD"
{ nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
  python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda, torch.cuda.get_device_name(0))"
  git log --oneline -1 2>/dev/null || true; nproc; date -u
} > "$WORK/device.txt" 2>&1
start=$(date +%s)
OUT="$WORK" bash benchmarks/gpu_track_check.sh > "$WORK/track.log" 2>&1
# the compiled check's Table 1 column gets what is left of about 8.5 minutes in all
OUT="$WORK" BUDGET=$(( 510 - ($(date +%s) - start) )) bash benchmarks/gpu_compiled_check.sh > "$WORK/compiled.log" 2>&1
cat "$WORK/device.txt" "$WORK/compiled-tests.txt" "$WORK/track-tests.txt" 2>/dev/null
for f in device.txt compiled.log track.log compiled-probe.jsonl track-fleet.jsonl column.txt; do
  [ -f "$WORK/$f" ] && cp "$WORK/$f" "$OUT/"
done
tail -n 30 "$WORK/compiled.log" "$WORK/track.log"
