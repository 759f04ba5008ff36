#!/usr/bin/env bash
# Frames/hour of the embedded farm (`dofarm run`) with 1 and with 2 local
# workers (one render thread each) on the same Cornell job, measured in one
# run so the ratio is comparable. Prints figures; never asserts.
#
#   bench/farm_scaling.sh [build/dofarm] [frames=12] [profile=job] [size=64]
#
# Profiles:
#   job    the bundled job's own per-pixel work (jobs/cornell.toml: 10 noisy
#          versions, 1024 reference spp, 24 albedo spp) at SIZE x SIZE: what a
#          farm spends its hours on, only smaller frames. This is the figure
#          the target (2 workers >= 1.9x one) is about.
#   light  4 versions, 32 reference spp at 96 x 96: tasks of a few tens of
#          milliseconds, so the fixed cost per task, the packs and the start
#          and end of a batch weigh far more than in any real batch. It shows
#          the farm's overhead, not its throughput.
# Needs two idle cores: anything else running shows up in the ratio.
set -euo pipefail
DOFARM=${1:-build/dofarm}
FRAMES=${2:-12}
PROFILE=${3:-job}
SIZE=${4:-64}
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
case "$PROFILE" in
  job)
    SETS=(--set image.width="$SIZE" --set image.height="$SIZE" --set farm.tile=32) ;;
  light)
    SETS=(--set image.width=96 --set image.height=96 --set buffers.versions=4
          --set buffers.reference_spp=32 --set buffers.albedo_ref_spp=4 --set farm.tile=32) ;;
  *) echo "unknown profile '$PROFILE' (job or light)" >&2; exit 2 ;;
esac
SETS+=(--set frames.end=$((FRAMES - 1)) --set frames.per_shard=4)
echo "profile $PROFILE: ${SETS[*]}"
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
# The two runs must have produced the same data (the farm is deterministic).
for f in "$TMP"/w1/shard-*.h5; do
  a=$("$DOFARM" inspect --json "$f" | grep -o '"data_checksum": *"[^"]*"')
  b=$("$DOFARM" inspect --json "$TMP/w2/$(basename "$f")" | grep -o '"data_checksum": *"[^"]*"')
  [ "$a" = "$b" ] || echo "WARNING: $(basename "$f") differs between 1 and 2 workers"
done
printf 'speed-up 2 workers / 1 worker: %.2fx (target >= 1.9x)\n' \
  "$(awk -v a="${FPH[2]}" -v b="${FPH[1]}" 'BEGIN { print a / b }')"
