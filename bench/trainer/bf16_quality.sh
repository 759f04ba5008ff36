#!/usr/bin/env bash
# Does bfloat16 cost quality? (issue 13: keep a CPU speed-up only if it does
# not.) Trains one configuration twice on the same shards, the same seed and
# the same optimiser steps, once with train.precision = fp32 and once with
# bf16 (trainer/precision.h), then scores each run's last weights on its
# validation frames with fp32 and with bf16 inference (`eval --precision`),
# and prints one table: training precision, inference precision, SSIM, PSNR,
# relative MSE, flicker, training wall seconds, ms per --time-size² frame.
#
#   bench/trainer/bf16_quality.sh [--steps N] [--preset P] [--time-size S]
#                                 [--set KEY=VALUE]... DATA_DIR [OUT]
#
# Defaults: 600 steps (3 epochs), preset default, time size 512, OUT
# /tmp/bf16_quality. Resumable as dof_study.sh: a finished run is not
# trained again. Prints figures; never asserts. Exit status 0, 2 on bad
# arguments. Environment: DOFARM_TRAIN (default build/dofarm-train).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
TRAIN=${DOFARM_TRAIN:-$ROOT/build/dofarm-train}
STEPS=600
PRESET=default
TIME_SIZE=512
SETS=()
POS=()
die() { echo "bf16_quality.sh: $*" >&2; exit 2; }
while [ $# -gt 0 ]; do
  case $1 in
    --steps) STEPS=${2:?}; shift 2 ;;
    --preset) PRESET=${2:?}; shift 2 ;;
    --time-size) TIME_SIZE=${2:?}; shift 2 ;;
    --set) SETS+=(--set "${2:?}"); shift 2 ;;
    -h|--help) sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    -*) die "unknown option $1 (see --help)" ;;
    *) POS+=("$1"); shift ;;
  esac
done
[ ${#POS[@]} -ge 1 ] && [ ${#POS[@]} -le 2 ] || die "expected DATA_DIR [OUT] (see --help)"
[[ $STEPS =~ ^[1-9][0-9]*$ ]] || die "--steps: expected a positive integer, got '$STEPS'"
[[ $TIME_SIZE =~ ^[1-9][0-9]*$ ]] || die "--time-size: expected a positive integer, got '$TIME_SIZE'"
DATA=${POS[0]}
OUT=${POS[1]:-/tmp/bf16_quality}
[ -d "$DATA" ] || die "no data folder $DATA"
[ -x "$TRAIN" ] || die "$TRAIN not found; build dofarm-train or set DOFARM_TRAIN"
EPOCHS=3
[ "$STEPS" -ge "$EPOCHS" ] || EPOCHS=$STEPS
PER_EPOCH=$(( (STEPS + EPOCHS - 1) / EPOCHS ))
mkdir -p "$OUT"

rows=()
for tp in fp32 bf16; do
  run=$OUT/run-$tp
  if [ -f "$run/bench.done" ]; then
    echo "bf16_quality.sh: $tp run trained, not trained again" >&2
  else
    t0=$(date +%s.%N)
    "$TRAIN" --log-level warn train --data "$DATA" --run "$run" --preset "$PRESET" \
      --set "train.precision=$tp" --set "train.epochs=$EPOCHS" \
      --set "train.steps_per_epoch=$PER_EPOCH" "${SETS[@]}"
    t1=$(date +%s.%N)
    python3 -c "print(f'{$t1 - $t0:.0f}')" > "$run/bench.done"
  fi
  wall=$(cat "$run/bench.done")
  for ip in fp32 bf16; do
    report=$OUT/report-$tp-$ip
    if [ ! -f "$report/report.json" ]; then
      rm -rf "$report.tmp"
      "$TRAIN" --log-level warn eval --run "$run" --data "$DATA" --out "$report.tmp" \
        --checkpoint last --images 0 --validation-only --precision "$ip" \
        --time-size "$TIME_SIZE" > /dev/null
      mv "$report.tmp" "$report"
    fi
    rows+=("$tp $ip $wall $report/report.json")
  done
done

python3 - "$TIME_SIZE" "${rows[@]}" <<'PY'
import json, sys
size = sys.argv[1]
print(f"| training | inference | SSIM | PSNR dB | rel. MSE | flicker | training wall s | ms per {size}² frame |")
print("| --- | --- | --- | --- | --- | --- | --- | --- |")
for row in sys.argv[2:]:
    tp, ip, wall, path = row.split(" ", 3)
    r = json.load(open(path))
    d = r["summary"]["denoised"]["all"]
    def f(v, spec):
        return "–" if v is None else format(v, spec)
    ms = r.get("denoise_ms_at_size")
    ms = ms.get("ms") if isinstance(ms, dict) else ms
    print(f"| {tp} | {ip} | {f(d['ssim'], '.4f')} | {f(d['psnr'], '.2f')} | "
          f"{f(d['rel_mse'], '.4f')} | {f(d.get('flicker'), '.4g')} | {wall} | {f(ms, '.0f')} |")
PY
