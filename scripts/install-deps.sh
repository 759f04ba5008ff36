#!/usr/bin/env bash
# Installs the Debian packages a dofarm machine needs, by role. Idempotent:
# packages already present are left alone; safe to run again.
#
#   scripts/install-deps.sh [--list] [ROLE...]
#
# Roles (several may be given; none means `all`):
#   render   a render node or coordinator host: builds and runs `dofarm`
#            (worker, coordinator, submit/status, inspect). No libtorch, no Slurm.
#   trainer  a training machine: builds and runs `dofarm-train` too (libtorch).
#   cluster  a Slurm node: slurmctld/slurmd and munge (add to render/trainer).
#   test     everything the test suite runs: all of the above, GoogleTest,
#            chromium (pages opened in a headless browser), Slurm for the
#            deployment test.
#   all      the same as test: what `scripts/build.sh` and CI install.
# --list prints the packages of the roles, one per line, and installs nothing.
set -euo pipefail

BUILD=(build-essential cmake ninja-build pkg-config git)
RENDER=(
  libembree-dev            # Embree 3: BVH and ray queries
  libopenexr-dev           # multi-layer EXR frames, HDR environment maps
  libhdf5-dev              # training shards
  libzmq3-dev cppzmq-dev   # coordinator <-> worker transport
  libsodium-dev            # BLAKE2b content hashes of job inputs, lease tokens
  libsqlite3-dev           # durable job store
  libspdlog-dev libfmt-dev # logging
  libcli11-dev             # command line
  libassimp-dev            # glTF 2.0 / OBJ / FBX scenes
  libtomlplusplus-dev      # job specs
  libstb-dev               # PNG/JPG/HDR textures
  nlohmann-json3-dev       # --json output
  libcpp-httplib-dev       # the coordinator's opt-in status page and /metrics
  zlib1g-dev
  python3                  # scene generator (jobs/scenes/make_scenes.py)
)
TRAINER=(libtorch-dev)     # dofarm-train only
CLUSTER=(slurm-wlm munge)  # the cluster engine of deploy/slurm
TEST=(
  libgtest-dev libgmock-dev
  chromium                 # report and status pages opened in a headless browser
  openimageio-tools openexr hdf5-tools  # frame EXRs and shards read by other tools
)

list=0
roles=()
for arg in "$@"; do
  case "$arg" in
    --list) list=1 ;;
    render | trainer | cluster | test | all) roles+=("$arg") ;;
    -h | --help)
      sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//'
      exit 0
      ;;
    *)
      echo "install-deps: unknown role '$arg' (roles: render, trainer, cluster, test, all)" >&2
      exit 2
      ;;
  esac
done
[ ${#roles[@]} -gt 0 ] || roles=(all)

PKGS=()
for r in "${roles[@]}"; do
  case "$r" in
    render) PKGS+=("${BUILD[@]}" "${RENDER[@]}") ;;
    trainer) PKGS+=("${BUILD[@]}" "${RENDER[@]}" "${TRAINER[@]}") ;;
    cluster) PKGS+=("${CLUSTER[@]}") ;;
    test | all) PKGS+=("${BUILD[@]}" "${RENDER[@]}" "${TRAINER[@]}" "${CLUSTER[@]}" "${TEST[@]}") ;;
  esac
done
mapfile -t PKGS < <(printf '%s\n' "${PKGS[@]}" | awk '!seen[$0]++')

if [ "$list" -eq 1 ]; then
  printf '%s\n' "${PKGS[@]}"
  exit 0
fi

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
echo "install-deps: all packages present (roles: ${roles[*]})"
