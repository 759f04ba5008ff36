#!/usr/bin/env bash
# tests/e2e/test_pipeline.sh DOFARM DOFARM_TRAIN
#
# The whole pipeline on the bundled Cornell sequence, tiny: the embedded farm
# renders 16 frames into a shard, a short training run learns from it, `eval`
# writes its report, `denoise` turns a frame rendered by `dofarm render` into
# a denoised EXR, and `export` writes TorchScript. Checks what each step
# promises to leave behind; fails on the first step that does not.
set -euo pipefail
DOFARM=$1
TRAIN=$2
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
fail() { echo "FAIL: $*"; exit 1; }

SETS=(--set image.width=64 --set image.height=64 --set frames.end=15 --set frames.per_shard=16
      --set buffers.versions=3 --set buffers.reference_spp=16 --set buffers.albedo_ref_spp=4
      --set farm.tile=32)
"$DOFARM" --log-level warn run "$ROOT/jobs/cornell.toml" --out "$TMP/data" --workers 2 "${SETS[@]}"
[ -f "$TMP/data/shard-00000.h5" ] || fail "no shard"
grep -q '"shard-00000.h5"' "$TMP/data/manifest.json" || fail "shard not in the manifest"
"$DOFARM" inspect "$TMP/data/shard-00000.h5" --json > "$TMP/inspect.json" || fail "inspect"

cat > "$TMP/train.toml" <<'TOML'
[model]
channels = [8, 8, 8, 8, 8]

[train]
epochs = 2
steps_per_epoch = 3
val_sequences = 2
warmup_steps = 2
TOML
"$TRAIN" --log-level warn train --data "$TMP/data" --run "$TMP/run" --config "$TMP/train.toml"
[ -f "$TMP/run/checkpoints/best.pt" ] || fail "no best checkpoint"
[ "$(wc -l < "$TMP/run/loss.csv")" -ge 3 ] || fail "loss.csv has no row per epoch"

"$TRAIN" --log-level warn eval --run "$TMP/run" --data "$TMP/data" --out "$TMP/report"
[ -s "$TMP/report/report.md" ] || fail "no report.md"
[ -s "$TMP/report/report.json" ] || fail "no report.json"
ls "$TMP/report"/*.png > /dev/null || fail "no images in the report"

"$DOFARM" --log-level warn render "$ROOT/jobs/cornell.toml" --frame 3 --out "$TMP/frame.exr" "${SETS[@]}"
"$TRAIN" --log-level warn denoise --run "$TMP/run" "$TMP/frame.exr" "$TMP/denoised.exr"
[ -s "$TMP/denoised.exr" ] || fail "no denoised EXR"
"$TRAIN" --log-level warn export --run "$TMP/run" --out "$TMP/model.pt"
[ -s "$TMP/model.pt" ] || fail "no TorchScript export"
# Where Debian's python3-torch is installed, the export must load and run there.
if /usr/bin/python3 -c "import torch" 2> /dev/null; then
  /usr/bin/python3 - "$TMP/model.pt" <<'PY' || fail "torch.jit.load of the export"
import sys, torch
m = torch.jit.load(sys.argv[1])
y = m(torch.rand(1, 12, 64, 64))
assert tuple(y.shape) == (1, 3, 64, 64) and bool(torch.isfinite(y).all()), y.shape
print("torch.jit.load in Python: ok")
PY
fi
echo "PASS: farm -> shard -> training -> eval report, denoise, export"
