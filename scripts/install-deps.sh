#!/usr/bin/env bash
# Installs every Debian package dofarm needs. Idempotent: packages already
# present are left alone; safe to run again.
set -euo pipefail

PKGS=(
  build-essential cmake ninja-build pkg-config git
  libembree-dev            # Embree 3: BVH and ray queries
  libopenexr-dev           # multi-layer EXR frames, HDR environment maps
  libhdf5-dev              # training shards
  libzmq3-dev cppzmq-dev   # coordinator <-> worker transport
  libsodium-dev            # BLAKE2b content hashes of job inputs, lease tokens
  libsqlite3-dev           # durable job store
  libtorch-dev             # trainer (dofarm-train only)
  libspdlog-dev libfmt-dev # logging
  libcli11-dev             # command line
  libgtest-dev libgmock-dev
  libassimp-dev            # glTF 2.0 / OBJ / FBX scenes
  libtomlplusplus-dev      # job specs
  libstb-dev               # PNG/JPG/HDR textures
  nlohmann-json3-dev       # --json output
  zlib1g-dev
  slurm-wlm munge          # the cluster engine the deployment is tested against
  python3                  # scene generator (jobs/scenes/make_scenes.py)
  chromium                 # tests only: the eval report page opened in a headless browser
)

missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
echo "install-deps: all packages present"
