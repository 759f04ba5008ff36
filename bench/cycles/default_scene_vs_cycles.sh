#!/usr/bin/env bash
# Blender's start-up scene through dofarm, against Cycles: does a scene a
# Blender user never touched render as Blender renders it? The cube, the
# lamp (1000 W, Radius 0.1 m), the camera (16:9, 50 mm) and the World (a
# uniform grey of 0.0509), exported as a .glb with Cameras and Punctual
# Lights ticked (bench/cycles/default_scene.py), rendered by Cycles and by dofarm at the
# same spp and size:
#
#   as_exported   the job names the file and the frame size only: the lamp
#                 is a point (hard shadow) and the World, which glTF cannot
#                 carry, is missing (black)
#   defaults      the job adds what the file cannot say: [lights]
#                 radius = 0.1 and [environment] color = 0.0509 (jobs/README.md)
#
# Prints the correlation of pixel luminances with Cycles', the ratio of the
# means and the relative RMSE against Cycles. See bench/README.md,
# "default_scene_vs_cycles.sh".
#
#   bench/cycles/default_scene_vs_cycles.sh [BUILD_DIR=build] [OUT_DIR=/tmp/default_scene] [SPP=256]
#   env: SPECULAR (the cube's Specular instead of Blender's 0.5; 0 leaves
#        both renderers a diffuse cube, which separates the two material
#        models' diffuse from their specular layers)
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
build=$(cd "${1:-build}" && pwd)
out=${2:-/tmp/default_scene}
spp=${3:-256}
width=192
height=108
command -v blender > /dev/null ||
  { echo "default_scene_vs_cycles.sh: needs blender (apt-get install blender python3-numpy)" >&2; exit 2; }
mkdir -p "$out"
blender -b -noaudio --factory-startup -P "$here/default_scene.py" -- "$out" "$spp" "$width" "$height" \
  ${SPECULAR:+"$SPECULAR"} \
  > "$out/blender.log" 2>&1 || { cat "$out/blender.log" >&2; exit 1; }

job() {  # job NAME EXTRA_TOML
  printf 'scene = "scene.glb"\nseed = 3\n[image]\nwidth = %d\nheight = %d\n[frames]\nstart = 1\nend = 1\nfps = 24\n[camera]\nfrom_scene = true\n[buffers]\nversions = 1\nalbedo_ref_spp = 1\n[render]\nmax_depth = 16\n%b' \
    "$width" "$height" "$2" > "$out/$1.toml"
  "$build/bench/render_spp" --job "$out/$1.toml" --spp "$spp" --threads 2 --out "$out/$1_" \
    > "$out/$1.log" 2>&1 || { cat "$out/$1.log" >&2; exit 1; }
}
job as_exported ""
job defaults '[lights]\nradius = 0.1\n[environment]\ncolor = [0.0509, 0.0509, 0.0509]\n'

python3 "$here/feature_compare.py" versus "$out/cycles$spp.pfm" \
  "the file alone (point lamp, no World)=$out/as_exported_$spp.pfm" \
  "with [lights] radius = 0.1 and the World's grey=$out/defaults_$spp.pfm"
