#!/usr/bin/env bash
# Training-step time of dofarm-train's model (bench/trainer/trainer_speed)
# against the same network, loss and Adam step in Python with Debian's
# python3-torch (bench/trainer/python_baseline.py), one after the other on
# this machine and with the same number of intra-op threads, and the data
# pipelines of both on one shard. Needs: apt-get install python3-torch
# python3-h5py. Prints figures; never asserts.
#   bench/trainer/python_vs_cpp.sh BUILD_DIR SHARD.h5 [threads=1]
set -euo pipefail
BUILD=${1:?build folder}
SHARD=${2:?a dofarm shard with >= 7 frames of >= 64x64}
export OMP_NUM_THREADS=${3:-1}
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
cpp=$("$BUILD/bench/trainer/trainer_speed" 3 | awk -F'|' '/DOF \(CoC input\)/ { print $6 + 0 }')
py=$(/usr/bin/python3 "$HERE/python_baseline.py" --reps 3 --shard "$SHARD")
py_step=$(echo "$py" | awk -F': ' '/train step/ { print $2 + 0 }')
echo "$py"
echo "C++ train step ms (DOF, 4 x 7 x 64^2): $cpp"
awk -v c="$cpp" -v p="$py_step" -v t="$OMP_NUM_THREADS" \
  'BEGIN { printf "threads %d: C++ steps/s / Python steps/s = %.2f (target >= 1.5)\n", t, p / c }'
# C++ data stream on synthetic shards of the same kind (samples/s by reader count):
if [ -x "$BUILD/bench/trainer/data_stream" ]; then "$BUILD/bench/trainer/data_stream" 100 256 | tail -5; fi
