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
# The study's networks on such a machine, when its shards are too large to
# carry there (the study's 40 training frames are about 0.8 GB):
#
#   bench/trainer/cuda_node.sh prepare-study DIR  # on a Debian 12 machine, after
#       scripts/build.sh: .debs into DIR/debs, and DIR/render-kit.tar.xz: the
#       built dofarm and the shared objects it needs beyond the C and C++
#       runtimes, so that it renders there without a Debian archive
#   bench/trainer/cuda_node.sh study DIR OUT      # on the CUDA machine
#       renders the training frames there (all its cores), builds dofarm-train
#       meanwhile, trains RUNS side by side on the GPU with
#       `dof_study.sh --train-only`, and packs each run (its files and a
#       weights-only checkpoint, `export --format checkpoint`, as
#       checkpoints/eval.pt) into OUT/run-CONFIG-SEED.tar, small enough to
#       bring back. Score them where the held-out frames are:
#       `dofarm-train eval --run RUN --checkpoint RUN/checkpoints/eval.pt ...`.
#     env: RUNS (default "thesis_prefilter:2 thesis_prefilter_nococ:2",
#       CONFIG:SEED words of dof_study.sh's configurations), STEPS (4000),
#       EPOCHS (40), JOB (cornell: the study job of jobs/study/ to render),
#       FRAMES (8-47; ranges joined by commas, e.g. 0-19,29-47, each
#       rendered as a farm output of its own and all trained on together),
#       REF_CAP (512, buffers.reference_max_spp),
#       DEADLINE (seconds after the start at which every training still
#       running is stopped with SIGINT, writing its checkpoint; default 510),
#       THREADS_PER_RUN (3, OMP_NUM_THREADS of each training), STUDY_DIR
#       (/tmp/dofarm-gpu-study: shards, build and runs). Run the same
#       command again while the machine is still up and it goes on: the
#       render and the build are found done and the runs resume.
#
# Figures of one H200 run are in docs/trainer.md ("Training on a GPU node").
set -uo pipefail
cd "$(dirname "$0")/../.."
mode=${1:?usage: cuda_node.sh prepare DIR DATA | run DIR OUT}
dir=${2:?the carried folder}
dir=$(cd "$dir" 2>/dev/null && pwd || echo "$dir")

# download_debs DEST: the trainer's libraries as .deb files.
download_debs() {
  # The trainer's libraries (dofarm_common: OpenEXR, HDF5, spdlog, fmt,
  # toml++, JSON, ZeroMQ, libsodium, stb; the tests: GoogleTest) and what
  # their shared objects need beyond libc, libstdc++ and zlib.
  (cd "$1" && apt-get download \
    libhdf5-dev libhdf5-103-1 libhdf5-hl-100 libsz2 libaec0 libaec-dev \
    libopenexr-dev libopenexr-3-1-30 libimath-dev libimath-3-1-29 \
    libspdlog-dev libspdlog1.10 libfmt-dev libfmt9 libcli11-dev nlohmann-json3-dev \
    libtomlplusplus-dev libtomlplusplus3 libzmq3-dev libzmq5 cppzmq-dev libsodium-dev libsodium23 \
    libstb-dev libgtest-dev zlib1g-dev zlib1g pkgconf pkgconf-bin libpkgconf3 \
    libbrotli1 libbsd0 libcom-err2 libcurl4 libdb5.3 libffi8 libgmp10 libgnutls30 \
    libgssapi-krb5-2 libhogweed6 libidn2-0 libk5crypto3 libkeyutils1 libkrb5-3 \
    libkrb5support0 libldap-2.5-0 libmd0 libnettle8 libnghttp2-14 libnorm1 libp11-kit0 \
    libpgm-5.3-0 libpsl5 librtmp1 libsasl2-2 libsasl2-modules-db libssh2-1 libssl3 \
    libtasn1-6 libunistring2 libzstd1)
}

if [ "$mode" = prepare ]; then
  data=${3:?the farm output folder whose shards to train on}
  mkdir -p "$dir/debs" "$dir/data"
  download_debs "$dir/debs" || exit 1
  cp "$data"/shard-*.h5 "$data"/manifest.json "$dir/data/" || exit 1
  du -sh "$dir"
  exit 0
fi
if [ "$mode" = prepare-study ]; then
  bin=${DOFARM:-build/dofarm}
  [ -x "$bin" ] || { echo "cuda_node.sh: $bin not found; build first (scripts/build.sh)" >&2; exit 2; }
  mkdir -p "$dir/debs"
  download_debs "$dir/debs" || exit 1
  kit=$(mktemp -d)
  mkdir "$kit/libs"
  cp "$bin" "$kit/dofarm" && strip "$kit/dofarm"
  # Every shared object ldd resolves but the C and C++ runtimes, which the
  # GPU machine has in newer versions.
  ldd "$bin" | awk '$3 ~ /^\// {print $3}' | while read -r so; do
    case $(basename "$so") in
      libc.so.* | libm.so.* | libpthread.so.* | libdl.so.* | librt.so.* | libresolv.so.* | \
        libstdc++.so.* | libgcc_s.so.*) ;;
      *) cp -L "$so" "$kit/libs/" ;;
    esac
  done
  tar -C "$kit" -cf - dofarm libs | xz -T0 -6 > "$dir/render-kit.tar.xz" || exit 1
  rm -rf "$kit"
  du -sh "$dir"
  exit 0
fi
case $mode in run | study) ;; *)
  echo "usage: cuda_node.sh prepare DIR DATA | run DIR OUT | prepare-study DIR | study DIR OUT" >&2
  exit 2
  ;;
esac
OUT=${3:?the folder for logs and figures}
if [ "$mode" = study ]; then
  # The settings are checked before anything is written or started: a
  # mistyped range or run must not cost a GPU machine's render and build.
  RUNS=${RUNS:-thesis_prefilter:2 thesis_prefilter_nococ:2}
  FRAMES=${FRAMES:-8-47} JOB=${JOB:-cornell}
  bad() { echo "cuda_node.sh: $1" >&2; exit 2; }
  [ -f "jobs/study/$JOB.toml" ] || bad "JOB: no study job jobs/study/$JOB.toml (JOB='$JOB')"
  IFS=, read -ra ranges <<<"$FRAMES"
  [ ${#ranges[@]} -gt 0 ] || bad "FRAMES: expected ranges like 0-19,29-47, got '$FRAMES'"
  for f in "${ranges[@]}"; do
    [[ $f =~ ^[0-9]+-[0-9]+$ ]] || bad "FRAMES: expected ranges like 0-19,29-47, got '$FRAMES'"
    ((10#${f%-*} <= 10#${f#*-})) || bad "FRAMES: range '$f' ends before it starts"
  done
  [ -n "${RUNS// /}" ] || bad "RUNS: expected CONFIG:SEED words, got nothing"
  for r in $RUNS; do
    [[ $r =~ ^[a-z0-9_]+:[0-9]+$ ]] || bad "RUNS: expected CONFIG:SEED words like default:1, got '$r'"
  done
  # Fixed folders, so that the same command again on a machine that is
  # still up goes on where the last one stopped: the render finds its job
  # done, ninja has nothing to build, and dof_study.sh resumes the runs.
  G=${STUDY_DIR:-/tmp/dofarm-gpu-study}
  K=$G/kit S=$G/data
  [ -f "$dir/render-kit.tar.xz" ] || [ -x "$K/dofarm" ] ||
    bad "$dir/render-kit.tar.xz not found (cuda_node.sh prepare-study makes it)"
fi
mkdir -p "$OUT"
T=$SECONDS
stamp() { echo "== [$((SECONDS - T)) s] $*"; }
stamp start
nvidia-smi -L
head -1 /etc/os-release
if [ "$mode" = study ]; then
  # The render starts first, on every core, and the build runs beside it.
  mkdir -p "$K" "$S"
  [ -x "$K/dofarm" ] || xz -dc "$dir/render-kit.tar.xz" | tar -C "$K" -xf - || exit 1
  data=()
  for f in "${ranges[@]}"; do data+=("$S/$JOB-$f/$JOB"); done
  (for f in "${ranges[@]}"; do
    LD_LIBRARY_PATH=$K/libs DOFARM=$K/dofarm OUT=$S/$JOB-$f JOBS=$JOB bench/trainer/render_study.sh \
      --set "frames.start=${f%-*}" --set "frames.end=${f#*-}" \
      --set "buffers.reference_max_spp=${REF_CAP:-512}" || exit 1
  done >"$OUT/render.txt" 2>&1) &
  render_pid=$!
  P=$G/prefix L=$G/libs
  mkdir -p "$P" "$L"
else
  P=$(mktemp -d /tmp/dofarm-prefix.XXXXXX) L=$(mktemp -d /tmp/dofarm-libs.XXXXXX)
fi
if [ ! -f "$P/.unpacked" ]; then
  for f in "$dir"/debs/*.deb; do dpkg -x "$f" "$P"; done
  touch "$P/.unpacked"
fi
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
targets=(dofarm-train trainer_speed test_trainer)
[ "$mode" = study ] && targets=(dofarm-train)
ninja -C "$B" "${targets[@]}" >"$OUT/build.txt" 2>&1 ||
  { grep -m20 -A6 "error\|undefined" "$OUT/build.txt"; exit 1; }
stamp built
if [ "$mode" = study ]; then
  wait "$render_pid" || { tail -20 "$OUT/render.txt"; exit 1; }
  stamp "rendered: $(ls "${data[@]/%//shard-00000.h5}" | wc -l) farm outputs, $(du -sch "${data[@]}" | tail -1 | cut -f1)"
  # dof_study.sh runs dofarm-train through this wrapper, which stops it with
  # SIGINT at the deadline: it writes its checkpoint and exits 3, and
  # dof_study.sh leaves the run unfinished (no study.done).
  stop_at=$((EPOCHSECONDS + ${DEADLINE:-510} - (SECONDS - T)))
  cat >"$P/train-deadline" <<EOF
#!/bin/sh
left=\$(( $stop_at - \$(date +%s) ))
[ "\$left" -gt 0 ] || left=1
exec timeout -s INT "\$left" "$B/dofarm-train" "\$@"
EOF
  chmod +x "$P/train-deadline"
  W=$P/study
  pids=()
  for r in $RUNS; do
    c=${r%:*} seed=${r#*:}
    OMP_NUM_THREADS=${THREADS_PER_RUN:-3} DOFARM_TRAIN=$P/train-deadline bash bench/trainer/dof_study.sh \
      --train-only --steps "${STEPS:-4000}" --epochs "${EPOCHS:-40}" --configs "$c" \
      --set "train.seed=$seed" --set data.val_fraction=0 --set train.warmup_steps=40 \
      --out "$W/seed-$seed" "${data[@]}" >>"$W-$c-$seed.txt" 2>&1 &
    pids+=($!)
  done
  stamp "training: $RUNS"
  for p in "${pids[@]}"; do wait "$p"; done
  stamp "trained"
  for r in $RUNS; do
    c=${r%:*} seed=${r#*:}
    run=$W/seed-$seed/runs/$c
    step=$(tail -1 "$run/steps.csv" 2>/dev/null | cut -d, -f1)
    echo "$c seed $seed: $( [ -f "$run/study.done" ] && cat "$run/study.done" || echo "unfinished"), last step ${step:-?}"
    cp "$W-$c-$seed.txt" "$run/train-log.txt" 2>/dev/null
    "$B/dofarm-train" --log-level warn export --run "$run" --checkpoint last --format checkpoint \
      --out "$run/checkpoints/eval.pt" || continue
    tar -C "$W/seed-$seed/runs" --exclude 'last.pt' --exclude 'best.pt' --exclude 'step-*.pt' \
      -cf "$OUT/run-$c-$seed.tar" "$c"
  done
  ls -la "$OUT"
  stamp done
  exit 0
fi
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
