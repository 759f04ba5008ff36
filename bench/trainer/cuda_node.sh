#!/usr/bin/env bash
# dofarm-train on a CUDA machine that has PyTorch (pip) but no Debian
# archive: a trainer-only build (-DDOFARM_TRAINER_ONLY=ON) against the
# machine's libtorch, with the Debian 12 libraries the trainer needs carried
# as .deb files and unpacked into a private prefix; then the speed figures, a
# real training run with evaluation, and the trainer's tests with CUDA
# visible. Prints figures; never asserts.
#
#   bench/trainer/cuda_node.sh prepare DIR DATA   # on a Debian 12 machine:
#       .debs into DIR/debs, DATA's shards and manifest into DIR/data
#   bench/trainer/cuda_node.sh run DIR OUT        # on the CUDA machine
#
# Figures of one H200 run are in docs/trainer.md ("Training on a GPU node").
set -uo pipefail
cd "$(dirname "$0")/../.."
mode=${1:?usage: cuda_node.sh prepare DIR DATA | run DIR OUT}
dir=${2:?the carried folder}
dir=$(cd "$dir" 2>/dev/null && pwd || echo "$dir")

if [ "$mode" = prepare ]; then
  data=${3:?the farm output folder whose shards to train on}
  mkdir -p "$dir/debs" "$dir/data"
  # The trainer's libraries (dofarm_common: OpenEXR, HDF5, spdlog, fmt,
  # toml++, JSON, ZeroMQ, libsodium, stb; the tests: GoogleTest) and what
  # their shared objects need beyond libc, libstdc++ and zlib.
  (cd "$dir/debs" && apt-get download \
    libhdf5-dev libhdf5-103-1 libhdf5-hl-100 libsz2 libaec0 libaec-dev \
    libopenexr-dev libopenexr-3-1-30 libimath-dev libimath-3-1-29 \
    libspdlog-dev libspdlog1.10 libfmt-dev libfmt9 libcli11-dev nlohmann-json3-dev \
    libtomlplusplus-dev libtomlplusplus3 libzmq3-dev libzmq5 cppzmq-dev libsodium-dev libsodium23 \
    libstb-dev libgtest-dev zlib1g-dev zlib1g pkgconf pkgconf-bin libpkgconf3 \
    libbrotli1 libbsd0 libcom-err2 libcurl4 libdb5.3 libffi8 libgmp10 libgnutls30 \
    libgssapi-krb5-2 libhogweed6 libidn2-0 libk5crypto3 libkeyutils1 libkrb5-3 \
    libkrb5support0 libldap-2.5-0 libmd0 libnettle8 libnghttp2-14 libnorm1 libp11-kit0 \
    libpgm-5.3-0 libpsl5 librtmp1 libsasl2-2 libsasl2-modules-db libssh2-1 libssl3 \
    libtasn1-6 libunistring2 libzstd1) || exit 1
  cp "$data"/shard-*.h5 "$data"/manifest.json "$dir/data/" || exit 1
  du -sh "$dir"
  exit 0
fi
[ "$mode" = run ] || { echo "usage: cuda_node.sh prepare DIR DATA | run DIR OUT" >&2; exit 2; }
OUT=${3:?the folder for logs and figures}
mkdir -p "$OUT"
T=$SECONDS
stamp() { echo "== [$((SECONDS - T)) s] $*"; }
stamp start
nvidia-smi -L
head -1 /etc/os-release
P=$(mktemp -d /tmp/dofarm-prefix.XXXXXX) L=$(mktemp -d /tmp/dofarm-libs.XXXXXX)
for f in "$dir"/debs/*.deb; do dpkg -x "$f" "$P"; done
# Only the shared objects the machine lacks are put on the library path, so
# its own (newer) libssl, libcurl and the like stay in use.
for d in "$P/usr/lib/x86_64-linux-gnu" "$P/lib/x86_64-linux-gnu"; do
  [ -d "$d" ] || continue
  for so in "$d"/*.so.*; do
    n=$(basename "$so")
    ldconfig -p | grep -q "[[:space:]]$n " || ln -sf "$so" "$L/$n"
  done
done
export LD_LIBRARY_PATH=$L${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
export PKG_CONFIG_PATH=$P/usr/lib/x86_64-linux-gnu/pkgconfig:$P/usr/share/pkgconfig PKG_CONFIG_SYSROOT_DIR=$P
# libzmq.pc names its static-link dependencies (Requires.private), which
# pkg-config wants to find even for a shared link: stand-ins satisfy it.
mkdir -p "$P/pcstub"
for p in krb5-gssapi openpgm-5.3 norm libbsd; do
  printf 'Name: %s\nDescription: stand-in\nVersion: 99\n' $p >"$P/pcstub/$p.pc"
done
export PKG_CONFIG_PATH=$PKG_CONFIG_PATH:$P/pcstub
torch_prefix=$(python3 -c 'import torch; print(torch.utils.cmake_prefix_path)')
B=$P/build
cmake -S . -B "$B" -G Ninja -DCMAKE_BUILD_TYPE=Release -DDOFARM_TRAINER_ONLY=ON \
  "-DCMAKE_PREFIX_PATH=$P/usr;$torch_prefix" -DHDF5_ROOT="$P/usr/lib/x86_64-linux-gnu/hdf5/serial" \
  "-DCMAKE_EXE_LINKER_FLAGS=-Wl,--as-needed -Wl,-rpath-link,$L" >"$OUT/cmake.txt" 2>&1 ||
  { tail -40 "$OUT/cmake.txt"; exit 1; }
ninja -C "$B" dofarm-train trainer_speed test_trainer >"$OUT/build.txt" 2>&1 ||
  { grep -m20 -A6 "error\|undefined" "$OUT/build.txt"; exit 1; }
stamp built
D=$dir/data
stamp "inference and training-step speed"
timeout 200 "$B/bench/trainer/trainer_speed" --reps 10 --models dof --formats nchw,nhwc \
  --loop "$D/shard-00000.h5" --steps 40 2>&1 | tee "$OUT/trainer_speed.md"
stamp "training: project defaults, 4000 steps"
timeout -s INT 600 "$B/dofarm-train" train --data "$D" --run "$OUT/run" \
  --set train.epochs=16 --set train.steps_per_epoch=250 --set train.val_sequences=8 >"$OUT/train.txt" 2>&1
echo "train rc=$?"; tail -3 "$OUT/train.txt"
"$B/dofarm-train" eval --run "$OUT/run" --data "$D" --out "$OUT/report" >"$OUT/eval.txt" 2>&1
echo "eval rc=$?"; tail -3 "$OUT/eval.txt"
stamp "test_trainer with CUDA visible"
timeout 300 "$B/tests/test_trainer" --gtest_brief=1 >"$OUT/test_trainer.txt" 2>&1
echo "test_trainer rc=$?"; grep -E "FAILED|PASSED" "$OUT/test_trainer.txt" | tail -10
stamp done
