#!/usr/bin/env bash
# The main job end to end on the bundled Cornell sequence, at preview size so
# it finishes in minutes on a laptop: render through the embedded farm
# (coordinator + local workers), train the DOF denoiser briefly, evaluate.
# Full size is `build/dofarm run jobs/cornell.toml --out DIR` (512x512,
# 1024 spp references: a cluster's worth of work).
# Running it again resumes: finished shards are kept.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
OUT=${OUT:-out/cornell}
WORKERS=${WORKERS:-2}

build/dofarm run jobs/cornell.toml --out "$OUT/data" --workers "$WORKERS" \
  --set image.width=128 --set image.height=128 \
  --set frames.end=31 --set frames.per_shard=16 \
  --set buffers.versions=4 --set buffers.reference_spp=64 --set buffers.albedo_ref_spp=8

if [ ! -x build/dofarm-train ]; then
  echo "shards are in $OUT/data; dofarm-train was not built (no libtorch), so no training"
  exit 0
fi
build/dofarm-train train --data "$OUT/data" --run "$OUT/run" \
  --set train.epochs=2 --set train.steps_per_epoch=15 --set train.val_sequences=4 \
  --set train.warmup_steps=10
build/dofarm-train eval --run "$OUT/run" --data "$OUT/data" --out "$OUT/report"
echo "report: $OUT/report/report.md"
