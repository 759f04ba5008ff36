#!/usr/bin/env bash
# Renders the study job set (jobs/study/*.toml: the Cornell box and the
# textured HDRI courtyard at 256 px height, large apertures, a third of the
# frames pinhole) through the embedded farm, one job after the other, into
# OUT/<job>/shard-*.h5 (+ manifest.json). Resumable: `dofarm run` into a
# folder that already holds the same job continues it (staged tiles whose
# checksum holds are not rendered again), so stop it at any time (Ctrl-C,
# kill) and start the same command again.
#
#   bench/trainer/render_study.sh                 # both jobs, as bundled
#   OUT=/data/study bench/trainer/render_study.sh
#   JOBS="cornell" bench/trainer/render_study.sh  # one job only
#   bench/trainer/render_study.sh --set frames.end=15   # extra --set for every job
#
# Environment: DOFARM (default build/dofarm), OUT (default out/study),
# WORKERS (default 1: one worker process using all THREADS), THREADS (default
# 0 = all cores), JOBS (default "cornell courtyard"). Run it in the
# background with nohup and follow OUT/<job>.log; `dofarm status` is not
# needed: the log prints progress and an ETA. Cost: bench/README.md,
# "Reference ceiling".
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
DOFARM=${DOFARM:-$ROOT/build/dofarm}
OUT=${OUT:-$ROOT/out/study}
WORKERS=${WORKERS:-1}
THREADS=${THREADS:-0}
JOBS=${JOBS:-cornell courtyard}

if [ ! -x "$DOFARM" ]; then
  echo "render_study.sh: $DOFARM not found; build first (scripts/build.sh) or set DOFARM" >&2
  exit 2
fi
mkdir -p "$OUT"
for job in $JOBS; do
  spec="$ROOT/jobs/study/$job.toml"
  if [ ! -f "$spec" ]; then
    echo "render_study.sh: no job $spec" >&2
    exit 2
  fi
  echo "render_study.sh: $job -> $OUT/$job (log $OUT/$job.log)"
  "$DOFARM" run "$spec" --out "$OUT/$job" --workers "$WORKERS" --threads "$THREADS" "$@" \
    2>&1 | tee -a "$OUT/$job.log"
done
echo "render_study.sh: done; shards in $OUT/*/"
