#!/usr/bin/env bash
# What Blender's glTF exporter writes from a Principled BSDF, rendered by
# dofarm against Cycles' render of the same Blender scene: the coat's
# Specular and Specular Tint (KHR_materials_specular; Specular from an
# image, which the exporter bakes into specularColorTexture), a tangent-space
# normal map (normalTexture; exported without and with TANGENT), an Alpha
# Clip cut-out (alphaMode MASK), Alpha Blend (BLEND), Clearcoat
# (KHR_materials_clearcoat) and a glass sphere (Transmission:
# KHR_materials_transmission), smooth and rough, and a texture read through
# a second UV map (texCoord 1) and a coat with its own normal map
# (clearcoatNormalTexture); animation: a moving cube and lamp, an
# armature, a shape key, and the cube and the shape key exported with
# their Bezier keys (CUBICSPLINE samplers); a moving camera, sampled per
# frame and as a spline; the camera's clipping planes (znear, zfar); and
# lamps with a Radius and a Sun with an Angle (the job's [lights]), also
# as a mirror shows them; a spot lamp's cone and Blend.
# bench/cycles/feature_scene.py builds, exports and renders each scene with
# Cycles; dofarm renders the exported file and control variants
# (bench/cycles/feature_compare.py says which and what is measured), and
# one table per feature is printed. bench/README.md has the figures.
#
#   bench/cycles/gltf_features_vs_cycles.sh [BUILD_DIR] [OUT_DIR] [SPP]
#   (BUILD_DIR default build, OUT_DIR /tmp/gltf_features_vs_cycles, SPP 64;
#    needs Debian's blender and python3-numpy, which its glTF exporter
#    imports; neither is a dependency of dofarm)
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
build=$(cd "${1:-build}" && pwd)
out=${2:-/tmp/gltf_features_vs_cycles}
spp=${3:-64}
command -v blender > /dev/null ||
  { echo "gltf_features_vs_cycles.sh: needs blender (apt-get install blender python3-numpy)" >&2; exit 2; }
mkdir -p "$out"

# One scene: FEATURE DIR SIZE [SPECULAR TINT]; prints its table rows.
scene() {
  local feature=$1 dir=$2 size=$3
  shift 3
  blender -b -noaudio --factory-startup -P "$here/feature_scene.py" -- "$feature" "$dir" "$spp" "$@" \
    > "$dir.blender.log" 2>&1 || { cat "$dir.blender.log" >&2; exit 1; }
  for v in $(python3 "$here/feature_compare.py" variants "$feature" "$dir" "$size"); do
    "$build/bench/render_spp" --job "$dir/$v.toml" --spp "$spp" --threads 2 --out "$dir/${v}_" \
      > "$dir/$v.log" 2>&1 || { cat "$dir/$v.log" >&2; exit 1; }
  done
  python3 "$here/feature_compare.py" rows "$feature" "$dir" "$spp" "$@"
}

echo "KHR_materials_specular (centre 8 x 8 pixels, $spp spp):"
python3 "$here/feature_compare.py" header specular
for pair in "0 0" "0.5 0" "1 0" "0.5 1"; do
  set -- $pair
  scene specular "$out/specular-s$1-t$2" 64 "$1" "$2"
done
for feature in specular_texture normal_map normal_map_tangents alpha_mask alpha_blend uv_map animation skinning shape_keys \
  animation_spline shape_keys_spline camera camera_spline clipping soft_lamps lamp_mirror spot_cone spot_soft ortho ortho_dof clearcoat_normal; do
  echo
  echo "$feature ($spp spp):"
  python3 "$here/feature_compare.py" header "$feature"
  scene "$feature" "$out/$feature" 96
done
echo
echo "clearcoat (centre 8 x 8 pixels, $spp spp):"
python3 "$here/feature_compare.py" header clearcoat
for roughness in 0.1 0.3 0.6; do
  scene clearcoat "$out/clearcoat-r$roughness" 64 "$roughness"
done
echo
echo "transmission (centre 32 x 32 pixels, $spp spp):"
for roughness in 0 0.3; do
  echo "Roughness $roughness:"
  python3 "$here/feature_compare.py" header transmission
  scene transmission "$out/transmission-r$roughness" 96 "$roughness"
done
echo "Roughness 0.3, Cycles' glass set to Multiscatter GGX:"
python3 "$here/feature_compare.py" header transmission
scene transmission "$out/transmission-r0.3-multi" 96 0.3 MULTI_GGX
