#!/usr/bin/env bash
# dofarm against Blender Cycles at equal error on the Cornell box with depth of
# field (bench/cycles/cornell_dof.toml: 256x256, f/1.0, focused on the back
# wall) or, with SCENE=courtyard, on the HDRI-lit textured courtyard
# (bench/cycles/courtyard_dof.toml: frame 24 of jobs/courtyard.toml at
# 320x180, Cycles through bench/cycles/render_courtyard.py). See
# bench/README.md, "cycles_vs_dofarm".
#
# usage: bench/cycles_vs_dofarm.sh [BUILD_DIR] [OUT_DIR]
#   env: SCENE (cornell; courtyard takes MATERIALS=gltf only: it is textured),
#        SPP (16,32,64,128,256), REF_SPP (4096), THREADS (2), REPEATS (1),
#        MATERIALS=lambert (default: every material Lambert in both renderers,
#        bench/cycles/lambert_scene.py, so both render one model and their
#        references can be compared for bias) or gltf (the bundled scene as
#        each renderer reads it: the models differ, only noise is compared),
#        CYCLES_CLAMP=1 for Blender's default clamp and filter glossy (biased),
#        KEEP_REF=1 to reuse a Cycles reference already in OUT_DIR (dofarm's is
#        rendered again: it is what changes), KEEP_REF=2 to reuse both
#
# Each renderer renders the spp list (REPEATS times, alternating Cycles and
# dofarm; the fastest time of each is kept) and a reference at REF_SPP with
# other random numbers; every image is compared with its own renderer's
# reference (bench/cycles/compare.py). With MATERIALS=lambert the two
# references are then compared with each other (mean and regions).
# Needs `blender` (3.4; its glTF importer needs python3-numpy) and
# BUILD_DIR/bench/render_spp.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
build=$(cd "${1:-$root/build}" && pwd)
out=${2:-/tmp/cycles_vs_dofarm}
spp=${SPP:-16,32,64,128,256}
ref=${REF_SPP:-4096}
threads=${THREADS:-2}
repeats=${REPEATS:-1}
scene=${SCENE:-cornell}
if [[ "$scene" == courtyard ]]; then
  materials=${MATERIALS:-gltf}
  if [[ "$materials" != gltf ]]; then
    echo "cycles_vs_dofarm.sh: SCENE=courtyard takes MATERIALS=gltf only (its materials are textured)" >&2
    exit 2
  fi
elif [[ "$scene" == cornell ]]; then
  materials=${MATERIALS:-lambert}
else
  echo "cycles_vs_dofarm.sh: SCENE must be cornell or courtyard, got '$scene'" >&2
  exit 2
fi
mkdir -p "$out"
case "$materials" in
  lambert)
    python3 "$root/bench/cycles/lambert_scene.py" "$out"
    job=$out/cornell_lambert.toml
    gltf=$out/cornell_lambert.gltf
    blender_flags=(--lambert)
    dofarm_flags=(--lambert)
    ;;
  gltf)
    job=$root/bench/cycles/${scene}_dof.toml
    gltf=$root/jobs/scenes/$scene.gltf
    blender_flags=()
    dofarm_flags=()
    ;;
  *)
    echo "cycles_vs_dofarm.sh: MATERIALS must be lambert or gltf, got '$materials'" >&2
    exit 2
    ;;
esac

# The camera of cornell_dof.toml, for Blender.
camera=(--position 0.15 1.02 3.75 --look-at 0 1 0 --fov 38 --focus 4.9 --aperture 0.0261379
        --max-bounces 15 --size 256)
[[ "${CYCLES_CLAMP:-0}" == 1 ]] && camera+=(--blender-clamp)
camera+=("${blender_flags[@]}")

cycles() {  # cycles SEED PREFIX SPP_LIST
  if [[ "$scene" == courtyard ]]; then
    # The file's camera at frame 24 and the lens of courtyard_dof.toml
    # (render_courtyard.py's defaults).
    blender -b --factory-startup --python "$root/bench/cycles/render_courtyard.py" -- \
      --gltf "$gltf" --hdri "$root/jobs/assets/hdri/courtyard.exr" --width 320 --height 180 \
      --threads "$threads" --seed "$1" --out "$2" --spp "$3" | grep '^spp '
    return
  fi
  blender -b --factory-startup --python "$root/bench/cycles/render_cornell.py" -- \
    --gltf "$gltf" --threads "$threads" --seed "$1" --out "$2" \
    --spp "$3" "${camera[@]}" | grep '^spp '
}
dofarm() {  # dofarm SEED PREFIX SPP_LIST
  "$build/bench/render_spp" --job "$job" --threads "$threads" --seed "$1" --out "$2" --spp "$3" \
    "${dofarm_flags[@]}"
}

keep=${KEEP_REF:-0}
if [[ "$keep" == 0 || ! -f "$out/cycles_ref$ref.pfm" ]]; then
  echo "Cycles reference, $ref spp" >&2
  cycles 1001 "$out/cycles_ref" "$ref" >/dev/null
fi
if [[ "$keep" != 2 || ! -f "$out/dofarm_ref$ref.pfm" ]]; then
  echo "dofarm reference, $ref spp" >&2
  dofarm 1001 "$out/dofarm_ref" "$ref" >/dev/null
fi
: >"$out/cycles_times.txt"
: >"$out/dofarm_times.txt"
for ((r = 0; r < repeats; ++r)); do
  echo "round $((r + 1))/$repeats: Cycles, then dofarm, at $spp spp on $threads threads" >&2
  cycles 0 "$out/cycles_" "$spp" | tee -a "$out/cycles_times.txt" >&2
  dofarm 7 "$out/dofarm_" "$spp" | tee -a "$out/dofarm_times.txt" >&2
done
python3 "$root/bench/cycles/compare.py" "$out" "$spp" "$ref"
if [[ "$materials" == lambert ]]; then
  python3 "$root/bench/cycles/compare.py" --bias "$out" "$spp" "$ref"
fi
