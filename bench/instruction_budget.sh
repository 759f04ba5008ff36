#!/usr/bin/env bash
# The own-ray ratio of bench/render_throughput counted in instructions
# instead of seconds: exact, and the same on every run of the same binary,
# where this machine's timings spread by 10-15% between runs. callgrind
# counts the instructions executed inside each of render_throughput's
# timed parts, one part per run (--collect-atstart=no --toggle-collect on
# renderer_pass, replay_scene_pass, replay_bare_pass), on one thread:
#
#   - the renderer: one frame of the job (noisy versions, reference,
#     albedo_ref, aux), split into Embree (libembree3) and the rest;
#   - the renderer's own rays replayed through Scene (what the own-ray
#     ratio divides by), and through bare Embree;
#
# then prints them per ray, the instruction ratio (replay / renderer) next
# to the time ratio of a native run of render_throughput, and the
# renderer's functions by instructions per ray (self cost). Use it to see
# what a change to the renderer saves exactly; bench/README.md,
# "instruction_budget.sh".
#
# usage: bench/instruction_budget.sh [BUILD_DIR] [OUT_DIR]
#   env: SCENE (courtyard or cornell), SIZE (image width, 128), TOP (20),
#        SKY (map, the job's own; constant: the map replaced by a grey sky of
#        its mean luminance, render_throughput --constant-sky)
# Needs valgrind (callgrind_annotate) and BUILD_DIR/bench/render_throughput.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
build=$(cd "${1:-$root/build}" && pwd)
out=${2:-/tmp/instruction_budget}
scene=${SCENE:-courtyard}
size=${SIZE:-128}
top=${TOP:-20}
sky=${SKY:-map}
case "$scene" in
  courtyard | cornell) ;;
  *)
    echo "instruction_budget.sh: SCENE must be courtyard or cornell, got '$scene'" >&2
    exit 2
    ;;
esac
[[ "$size" =~ ^[0-9]+$ ]] || { echo "instruction_budget.sh: SIZE must be a number, got '$size'" >&2; exit 2; }
[[ "$top" =~ ^[0-9]+$ ]] || { echo "instruction_budget.sh: TOP must be a number, got '$top'" >&2; exit 2; }
if [ "$sky" != map ] && [ "$sky" != constant ]; then
  echo "instruction_budget.sh: SKY must be map or constant, got '$sky'" >&2
  exit 2
fi
bin=$build/bench/render_throughput
[ -x "$bin" ] || { echo "instruction_budget.sh: no $bin (ninja -C BUILD_DIR bench/render_throughput)" >&2; exit 2; }
command -v valgrind >/dev/null && command -v callgrind_annotate >/dev/null ||
  { echo "instruction_budget.sh: needs valgrind (apt install valgrind)" >&2; exit 2; }
mkdir -p "$out"
args=(--scene "$scene" --size "$size" --threads 1 --rays 1000)
[ "$sky" = constant ] && args+=(--constant-sky)

echo "instruction_budget.sh: $scene ($sky sky), width $size, 1 thread -> $out" >&2
for pass in renderer_pass replay_scene_pass replay_bare_pass; do
  echo "  callgrind, counting $pass ..." >&2
  valgrind --tool=callgrind --callgrind-out-file="$out/$pass.cg" --collect-atstart=no \
    --toggle-collect="*::${pass}*" "$bin" "${args[@]}" --repeats 1 >"$out/$pass.txt" 2>"$out/$pass.valgrind"
done
echo "  native run (--repeats 3) for the time ratio ..." >&2
"$bin" "${args[@]}" --repeats 3 >"$out/native.txt"

total() {  # the instructions callgrind counted in a profile
  local n
  n=$(awk '/^totals:/ {print $2}' "$1")
  if [ -z "$n" ] || [ "$n" = 0 ]; then
    echo "instruction_budget.sh: $1 counted nothing (was the pass inlined?)" >&2
    exit 1
  fi
  echo "$n"
}
rays=$(sed -nE 's/^  paths [0-9]+  rays ([0-9]+) .*/\1/p' "$out/renderer_pass.txt")
paths=$(sed -nE 's/^  paths ([0-9]+)  rays .*/\1/p' "$out/renderer_pass.txt")
[ -n "$rays" ] && [ "$rays" -gt 0 ] || { echo "instruction_budget.sh: no ray count in $out/renderer_pass.txt" >&2; exit 1; }
renderer=$(total "$out/renderer_pass.cg")
replay=$(total "$out/replay_scene_pass.cg")
bare=$(total "$out/replay_bare_pass.cg")
# The renderer's instructions by function (self cost), and Embree's part.
callgrind_annotate --auto=no --threshold=100 "$out/renderer_pass.cg" 2>/dev/null |
  awk '/^-+$/ {rule++} rule >= 4 && /^ *[0-9,]+ / {n = $1; gsub(",", "", n);
       line = $0; sub(/^ *[0-9,]+ +(\([ 0-9.%]+\) +)?/, "", line); print n "\t" line}' >"$out/functions.tsv"
embree=$(awk -F'\t' '$2 ~ /libembree/ {s += $1} END {printf "%.0f", s}' "$out/functions.tsv")
time_ratio=$(sed -nE 's/^ratio renderer \/ own rays replayed: ([0-9]+)% \(Scene\).*/\1/p' "$out/native.txt")

awk -v r="$renderer" -v e="$embree" -v s="$replay" -v b="$bare" -v n="$rays" -v p="$paths" \
    -v scene="$scene" -v size="$size" -v tr="$time_ratio" -v sky="$sky" 'BEGIN {
  printf "\n%s (%s sky), width %d, one frame, 1 thread: %d paths, %d rays (%.2f per path)\n", scene, sky, size, p, n, n / p
  printf "| part | instructions | per ray |\n| --- | --- | --- |\n"
  printf "| renderer | %.0f | %.0f |\n", r, r / n
  printf "| of it in libembree3 | %.0f | %.0f |\n", e, e / n
  printf "| of it outside Embree | %.0f | %.0f |\n", r - e, (r - e) / n
  printf "| own rays replayed through Scene | %.0f | %.0f |\n", s, s / n
  printf "| own rays replayed through bare Embree | %.0f | %.0f |\n", b, b / n
  printf "instruction ratio, replay through Scene / renderer: %.1f%% (bare Embree: %.1f%%)\n", 100 * s / r, 100 * b / r
  printf "time ratio of a native run (render_throughput --repeats 3): %s%%\n", tr
  printf "for 50%%: the renderer at most %.0f instructions per ray, %.0f fewer than now\n", 2 * s / n, (r - 2 * s) / n
}'
echo
echo "the renderer's functions by instructions per ray (self cost; top $top):"
grep -v $'\tPROGRAM TOTALS' "$out/functions.tsv" | sort -t$'\t' -k1,1nr |
  awk -F'\t' -v n="$rays" -v r="$renderer" -v top="$top" 'NR <= top {
    name = $2; sub(/ \[.*\]$/, "", name); sub(/^\?\?\?:/, "", name)
    gsub(/\(anonymous namespace\)/, "{anon}", name); sub(/\(.*$/, "", name)
    obj = $2; sub(/^.*\[/, "", obj); sub(/\]$/, "", obj); sub(/^.*\//, "", obj)
    printf "  %7.1f  %5.1f%%  %s  (%s)\n", $1 / n, 100 * $1 / r, name, obj }'
