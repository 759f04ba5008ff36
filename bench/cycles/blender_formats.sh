#!/usr/bin/env bash
# One Blender scene exported as glTF, Collada and FBX (bench/cycles/
# blender_formats.py), each rendered by dofarm from the file's own camera
# under a uniform white environment, at the same size and spp: do the three
# exports render as one scene? Prints, per camera type, the correlation of
# the Collada and FBX renders' luminances with the glTF render's, the ratio
# of their means and their relative RMSE against it (materials included:
# assimp reads the Collada and FBX materials its own way). An FBX
# orthographic camera is refused (docs/renderer.md, "Orthographic cameras");
# the script says so instead of a row. See bench/README.md,
# "blender_formats.sh".
#
#   bench/cycles/blender_formats.sh [BUILD_DIR=build] [OUT_DIR=/tmp/blender_formats] [SPP=64]
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
build=$(cd "${1:-build}" && pwd)
out=${2:-/tmp/blender_formats}
spp=${3:-64}
command -v blender > /dev/null ||
  { echo "blender_formats.sh: needs blender (apt-get install blender)" >&2; exit 2; }
for cam in persp ortho; do
  dir="$out/$cam"
  mkdir -p "$dir"
  blender -b -noaudio --factory-startup -P "$here/blender_formats.py" -- "$dir" "$cam" \
    > "$dir/blender.log" 2>&1 || { cat "$dir/blender.log" >&2; exit 1; }
  rows=()
  for ext in glb dae fbx; do
    printf 'scene = "scene.%s"\nseed = 3\n[image]\nwidth = 192\nheight = 108\n[camera]\nfrom_scene = true\n[environment]\ncolor = [1, 1, 1]\n[buffers]\nversions = 1\nalbedo_ref_spp = 1\n' \
      "$ext" > "$dir/$ext.toml"
    if "$build/bench/render_spp" --job "$dir/$ext.toml" --spp "$spp" --threads 2 \
      --out "$dir/${ext}_" > "$dir/$ext.log" 2>&1; then
      [ "$ext" = glb ] || rows+=("$ext=$dir/${ext}_$spp.pfm")
    else
      echo "$cam camera, .$ext: $(tail -1 "$dir/$ext.log")"
      [ "$ext" != glb ] || exit 1
    fi
  done
  echo "$cam camera, $spp spp:"
  [ ${#rows[@]} -eq 0 ] || python3 "$here/feature_compare.py" against "the glTF export" \
    "$dir/glb_$spp.pfm" "${rows[@]}"
done
