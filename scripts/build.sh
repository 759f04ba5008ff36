#!/usr/bin/env bash
# Builds dofarm into build/ (Release, Ninja): installs the Debian packages if
# any are missing, configures once, then lets Ninja rebuild only what changed,
# so a second run with nothing changed takes about a second.
# Run from anywhere; paths are relative to the repository root.
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")/.."

# DOFARM_ROLES picks what this machine is for (scripts/install-deps.sh): e.g.
# `DOFARM_ROLES=render scripts/build.sh` on a render node installs and builds
# neither libtorch nor the tests. Default: all.
read -r -a roles <<< "${DOFARM_ROLES:-all}"
scripts/install-deps.sh "${roles[@]}"
opts=()
has_role() { printf '%s\n' "${roles[@]}" | grep -qxE "$1"; }
has_role 'trainer|test|all' || opts+=(-DDOFARM_BUILD_TRAINER=OFF)
has_role 'test|all' || opts+=(-DDOFARM_BUILD_TESTS=OFF)

# Configure only when there is no build yet: Ninja re-runs CMake by itself when
# a CMakeLists.txt (or a globbed source list) changes.
if [ ! -f build/build.ninja ]; then
  cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release "${opts[@]}"
fi
cmake --build build -j "$(nproc)"
