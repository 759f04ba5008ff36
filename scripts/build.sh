#!/usr/bin/env bash
# Builds dofarm into build/ (Release, Ninja): installs the Debian packages if
# any are missing, configures once, then lets Ninja rebuild only what changed,
# so a second run with nothing changed takes about a second.
# Run from anywhere; paths are relative to the repository root.
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")/.."

scripts/install-deps.sh

# Configure only when there is no build yet: Ninja re-runs CMake by itself when
# a CMakeLists.txt (or a globbed source list) changes.
if [ ! -f build/build.ninja ]; then
  cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release
fi
cmake --build build -j "$(nproc)"
