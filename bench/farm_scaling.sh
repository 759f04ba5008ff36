#!/usr/bin/env bash
# Frames/hour of the embedded farm (`dofarm run`) with 1 and with 2 local
# workers (one render thread each) on the same small Cornell job, measured in
# one run so the ratio is comparable. Prints figures; never asserts.
#   bench/farm_scaling.sh [build/dofarm] [frames=8]
set -euo pipefail
DOFARM=${1:-build/dofarm}
FRAMES=${2:-8}
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
SETS=(--set image.width=96 --set image.height=96 --set buffers.versions=4
      --set buffers.reference_spp=32 --set buffers.albedo_ref_spp=4
      --set frames.end=$((FRAMES - 1)) --set frames.per_shard=4 --set farm.tile=32)
declare -A FPH
for w in 1 2; do
  start=$(date +%s.%N)
  "$DOFARM" --log-level warn run "$ROOT/jobs/cornell.toml" --out "$TMP/w$w" --workers "$w" \
    --threads 1 "${SETS[@]}" > /dev/null
  end=$(date +%s.%N)
  secs=$(awk -v a="$start" -v b="$end" 'BEGIN { print b - a }')
  FPH[$w]=$(awk -v f="$FRAMES" -v s="$secs" 'BEGIN { print f * 3600 / s }')
  printf 'workers %d: %d frames in %.1f s = %.0f frames/hour\n' "$w" "$FRAMES" "$secs" "${FPH[$w]}"
done
printf 'speed-up 2 workers / 1 worker: %.2fx (target >= 1.9x; needs 2 idle cores)\n' \
  "$(awk -v a="${FPH[2]}" -v b="${FPH[1]}" 'BEGIN { print a / b }')"
