#!/usr/bin/env bash
# dofarm-train's training speed against the same network, loss, Adam step and
# data pipeline in Python with Debian's python3-torch and python3-h5py
# (bench/trainer/python_baseline.py), one after the other on this machine with
# the same number of intra-op threads:
#   step only  trainer_speed (random inputs) vs python_baseline.py
#   full loop  trainer_speed --loop SHARD (dofarm-train's readers, prefetch and
#              step) vs python_baseline.py --loop (h5py batch, then the step)
#   loaders    data_stream --shard SHARD vs the h5py pipeline, same shard
# Python is run in PyTorch's default layout (NCHW), with channels_last (NHWC,
# the layout dofarm-train uses on the CPU), and with channels_last plus the
# malloc setting dofarm-train makes (keep_freed_memory(), here through
# GLIBC_TUNABLES), so the ratios say how much of the gain is the layout, the
# allocator, and the rest (the loop's overlapped data). Needs: apt-get install
# python3-torch python3-h5py. Prints figures; never asserts.
#   bench/trainer/python_vs_cpp.sh BUILD_DIR SHARD.h5 [threads=1] [reps=5] [loop_steps=10]
set -euo pipefail
BUILD=${1:?build folder}
SHARD=${2:?a dofarm shard with >= 7 frames of >= 64x64}
export OMP_NUM_THREADS=${3:-1}
REPS=${4:-5}
STEPS=${5:-10}
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
PY=/usr/bin/python3
field() { awk -F': ' -v k="$1" 'index($0, k) == 1 { print $2 + 0 }'; }

cpp=$("$BUILD/bench/trainer/trainer_speed" --reps "$REPS" --models dof --no-infer \
  --loop "$SHARD" --steps "$STEPS" --formats nchw,nhwc)
echo "$cpp"
c_step_nchw=$(echo "$cpp" | awk -F'|' '/DOF \(CoC input\).*NCHW/ { print $7 + 0 }')
c_step=$(echo "$cpp" | awk -F'|' '/DOF \(CoC input\).*NHWC/ { print $7 + 0 }')
c_loop=$(echo "$cpp" | awk -F'|' '$2 ~ /NHWC/ && NF == 5 { print $3 + 0 }')
# With >= 2 threads dofarm-train splits the step across 2 model replicas
# (train.cpu_replicas auto); the same run on one model shows what that adds.
c_one_step=$c_step c_one_loop=$c_loop
if [ "$OMP_NUM_THREADS" -ge 2 ]; then
  one=$("$BUILD/bench/trainer/trainer_speed" --reps "$REPS" --models dof --no-infer \
    --loop "$SHARD" --steps "$STEPS" --formats nhwc --replicas 1)
  echo "$one"
  c_one_step=$(echo "$one" | awk -F'|' '/DOF \(CoC input\).*NHWC/ { print $7 + 0 }')
  c_one_loop=$(echo "$one" | awk -F'|' '$2 ~ /NHWC/ && NF == 5 { print $3 + 0 }')
fi
py_nchw=$($PY "$HERE/python_baseline.py" --reps "$REPS" --shard "$SHARD" --loop "$STEPS")
echo "$py_nchw"
py_nhwc=$($PY "$HERE/python_baseline.py" --reps "$REPS" --shard "$SHARD" --loop "$STEPS" --channels-last)
echo "$py_nhwc"
py_heap=$(GLIBC_TUNABLES=glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=1073741824 \
  $PY "$HERE/python_baseline.py" --reps "$REPS" --shard "$SHARD" --loop "$STEPS" --channels-last)
echo "$py_heap (GLIBC_TUNABLES as keep_freed_memory())"
p_step=$(echo "$py_nchw" | field "python train step ms")
p_loop=$(echo "$py_nchw" | field "python loop ms/step")
p_step_cl=$(echo "$py_nhwc" | field "python train step ms")
p_loop_cl=$(echo "$py_nhwc" | field "python loop ms/step")
p_step_h=$(echo "$py_heap" | field "python train step ms")
p_loop_h=$(echo "$py_heap" | field "python loop ms/step")
p_data=$(echo "$py_nchw" | field "python data batch ms")
echo
echo "| threads | measure | Python NCHW ms | Python NHWC ms | Python NHWC + heap ms | C++ ms |" \
  "C++ / Python NCHW | C++ / Python NHWC | C++ / Python NHWC + heap |"
echo "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
awk -v t="$OMP_NUM_THREADS" -v a="$p_step" -v b="$p_step_cl" -v h="$p_step_h" -v c="$c_step" \
  -v d="$c_step_nchw" -v e="$p_loop" -v f="$p_loop_cl" -v i="$p_loop_h" -v g="$c_loop" 'BEGIN {
  printf "| %d | step only | %.0f | %.0f | %.0f | %.0f | **%.2fx** | %.2fx | %.2fx |\n", t, a, b, h, c, a / c, b / c, h / c
  printf "| %d | full loop | %.0f | %.0f | %.0f | %.0f | **%.2fx** | %.2fx | %.2fx |\n", t, e, f, i, g, e / g, f / g, i / g
  printf "| %d | step only, C++ in NCHW | %.0f | | | %.0f | %.2fx | | |\n", t, a, d, a / d
}'
if [ "$OMP_NUM_THREADS" -ge 2 ]; then
  awk -v t="$OMP_NUM_THREADS" -v a="$p_step" -v b="$p_step_cl" -v h="$p_step_h" -v c="$c_one_step" \
    -v e="$p_loop" -v f="$p_loop_cl" -v i="$p_loop_h" -v g="$c_one_loop" 'BEGIN {
    printf "| %d | step only, C++ one model | %.0f | %.0f | %.0f | %.0f | %.2fx | %.2fx | %.2fx |\n", t, a, b, h, c, a / c, b / c, h / c
    printf "| %d | full loop, C++ one model | %.0f | %.0f | %.0f | %.0f | %.2fx | %.2fx | %.2fx |\n", t, e, f, i, g, e / g, f / g, i / g
  }'
fi
echo "(steps/s ratios; the target is >= 1.5x the Python loop)"
echo
echo "loaders on $SHARD: h5py $(awk -v m="$p_data" 'BEGIN { printf "%.1f", 4000 / m }') samples/s (one process)"
"$BUILD/bench/trainer/data_stream" --shard "$SHARD" --samples 200 --readers 1,2 | tail -4
