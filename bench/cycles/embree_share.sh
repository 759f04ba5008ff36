#!/usr/bin/env bash
# How much of a render is ray traversal, in dofarm and in Blender Cycles: both
# trace their rays with the same Embree (Debian's libembree3, which Blender
# 3.4 links too), so the share of CPU samples inside libembree3 is the same
# measure in both. Each renderer renders the same frame at the same sample
# count under `perf record`, profiled only while it renders (perf's control
# FIFO: bench/render_spp --perf-ctl, bench/cycles/render_*.py --perf-ctl),
# and the script prints, per renderer, CPU seconds, the shares of Embree, of
# the renderer's own code and of the kernel, and the CPU seconds spent
# outside Embree. See bench/README.md, "embree_share".
#
# usage: bench/cycles/embree_share.sh [BUILD_DIR] [OUT_DIR]
#   env: SCENE (courtyard: bench/cycles/courtyard_dof.toml, or cornell:
#        bench/cycles/cornell_dof.toml with the glTF materials), SPP (64),
#        THREADS (2), FREQ (perf's sampling rate, 999)
# Needs perf, `blender` 3.4 (+ python3-numpy for its glTF importer) and
# BUILD_DIR/bench/render_spp. Run it on an otherwise idle machine.
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
build=$(cd "${1:-$root/build}" && pwd)
out=${2:-/tmp/embree_share}
scene=${SCENE:-courtyard}
spp=${SPP:-64}
threads=${THREADS:-2}
freq=${FREQ:-999}
mkdir -p "$out"

case "$scene" in
  courtyard)
    cycles_cmd=(blender -b -noaudio --factory-startup --python "$root/bench/cycles/render_courtyard.py" --
                --gltf "$root/jobs/scenes/courtyard.gltf" --hdri "$root/jobs/assets/hdri/courtyard.exr"
                --width 320 --height 180)
    ;;
  cornell)
    cycles_cmd=(blender -b -noaudio --factory-startup --python "$root/bench/cycles/render_cornell.py" --
                --gltf "$root/jobs/scenes/cornell.gltf" --position 0.15 1.02 3.75 --look-at 0 1 0
                --fov 38 --focus 4.9 --aperture 0.0261379 --max-bounces 15 --size 256)
    ;;
  *)
    echo "embree_share.sh: SCENE must be courtyard or cornell, got '$scene'" >&2
    exit 2
    ;;
esac
cycles_cmd+=(--threads "$threads" --out "$out/cycles_" --spp "$spp")
dofarm_cmd=("$build/bench/render_spp" --job "$root/bench/cycles/${scene}_dof.toml" --threads "$threads"
            --out "$out/dofarm_" --spp "$spp")

profile() {  # profile NAME CMD...: perf data in OUT/NAME.data, the render's line in OUT/NAME.txt
  local name=$1
  shift
  local fifo=$out/$name.ctl
  rm -f "$fifo"
  mkfifo "$fifo"
  perf record -q -F "$freq" -D -1 --control="fifo:$fifo" -o "$out/$name.data" -- \
    "$@" --perf-ctl "$fifo" 2>/dev/null | grep '^spp ' >"$out/$name.txt"
  rm -f "$fifo"
}

echo "embree_share.sh: $scene, $spp spp, $threads threads -> $out" >&2
profile cycles "${cycles_cmd[@]}"
profile dofarm "${dofarm_cmd[@]}"

echo
echo "| renderer | CPU s | samples | Embree | renderer's own code | kernel | other | CPU s outside Embree |"
echo "| --- | --- | --- | --- | --- | --- | --- | --- |"
for name in cycles dofarm; do
  own=blender
  [[ "$name" == dofarm ]] && own=render_spp
  cpu=$(awk '{print $4}' "$out/$name.txt")
  perf report -i "$out/$name.data" --no-children --sort dso --stdio -F overhead,sample,dso 2>/dev/null |
    awk -v name="$name" -v own="$own" -v cpu="$cpu" '
      /^#/ || NF < 3 { next }
      { pct = $1; sub("%", "", pct); n = $2; total += n
        if ($3 ~ /^libembree3/) embree += n
        else if ($3 == own) mine += n
        else if ($3 ~ /kernel/) kernel += n
        else other += n }
      END {
        if (total == 0) { print "| " name " | " cpu " | no samples |"; exit 1 }
        printf "| %s | %.2f | %d | %.1f%% | %.1f%% | %.1f%% | %.1f%% | %.2f |\n", name, cpu, total,
               100 * embree / total, 100 * mine / total, 100 * kernel / total, 100 * other / total,
               cpu * (1 - embree / total)
      }'
done
