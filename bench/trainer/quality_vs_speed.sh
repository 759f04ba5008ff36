#!/usr/bin/env bash
# Denoising quality against denoising time for a few model sizes: each size is
# trained for the same number of steps on the same shards, then evaluated on
# the same validation frames; prints SSIM, PSNR and relative MSE (all pixels,
# in focus, out of focus) against the mean denoise milliseconds per frame.
# Prints figures; never asserts.
#
#   bench/trainer/quality_vs_speed.sh BUILD_DIR [DATA_DIR] [steps=150]
#
# Without DATA_DIR it first renders the bundled Cornell sequence at preview
# size through `dofarm run` (as scripts/pipeline.sh does) into a temporary
# folder. Sizes (encoder widths, DOF model with the CoC input):
#   small   16 24 32 43 57
#   thesis  36 48 64 85 113   (thesis 4.2, the default)
#   wide    48 64 85 113 151
set -euo pipefail
BUILD=${1:?build folder with dofarm and dofarm-train}
DATA=${2:-}
STEPS=${3:-150}
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
if [ -z "$DATA" ]; then
  DATA=$TMP/data
  "$BUILD/dofarm" --log-level warn run "$ROOT/jobs/cornell.toml" --out "$DATA" --workers 2 \
    --set image.width=128 --set image.height=128 \
    --set frames.end=31 --set frames.per_shard=16 \
    --set buffers.versions=4 --set buffers.reference_spp=64 --set buffers.albedo_ref_spp=8 \
    > /dev/null
fi
EPOCHS=3
PER_EPOCH=$(( (STEPS + EPOCHS - 1) / EPOCHS ))
declare -A WIDTHS=([small]="[16,24,32,43,57]" [thesis]="[36,48,64,85,113]" [wide]="[48,64,85,113,151]")
printf '%d training steps per size (%d epochs x %d), data %s\n\n' \
  $((EPOCHS * PER_EPOCH)) "$EPOCHS" "$PER_EPOCH" "$DATA"
printf '| size | widths | params | denoise ms/frame | SSIM | PSNR dB | rel. MSE | SSIM in focus | SSIM out of focus | train s |\n'
printf '| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n'
for size in small thesis wide; do
  run=$TMP/run-$size
  t0=$(date +%s.%N)
  "$BUILD/dofarm-train" --log-level warn train --data "$DATA" --run "$run" \
    --set "model.channels=${WIDTHS[$size]}" \
    --set train.epochs=$EPOCHS --set train.steps_per_epoch=$PER_EPOCH \
    --set train.val_sequences=4 --set train.warmup_steps=10 > /dev/null
  t1=$(date +%s.%N)
  "$BUILD/dofarm-train" --log-level warn eval --run "$run" --data "$DATA" --out "$TMP/report-$size" \
    --images 0 > /dev/null
  /usr/bin/env python3 - "$TMP/report-$size/report.json" "$size" "${WIDTHS[$size]}" \
    "$(awk -v a="$t0" -v b="$t1" 'BEGIN { print b - a }')" "$run" <<'EOF'
import json, re, sys, pathlib
report, size, widths, train_s, run = sys.argv[1:]
d = json.load(open(report))["summary"]
params = "?"
log = pathlib.Path(run) / "events.log"
if log.exists():
    m = re.search(r"([0-9][0-9,]*) parameters", log.read_text())
    if m:
        params = m.group(1)
def f(x, fmt):
    return "n/a" if x is None else fmt.format(x)
a, i, o = d["denoised"]["all"], d["denoised"]["in_focus"], d["denoised"]["out_of_focus"]
print(f"| {size} | {widths} | {params} | {d['denoise_ms_mean']:.1f} | {f(a['ssim'], '{:.4f}')} | "
      f"{f(a['psnr'], '{:.2f}')} | {f(a['rel_mse'], '{:.4f}')} | {f(i['ssim'], '{:.4f}')} | "
      f"{f(o['ssim'], '{:.4f}')} | {float(train_s):.0f} |")
EOF
done
