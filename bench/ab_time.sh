#!/usr/bin/env bash
# Two builds of a renderer benchmark (before and after a change) timed
# against each other closely enough to see a 1-2% difference on a shared
# machine whose speed changes by 10-30% from one second to the next
# (bench/README.md, "ab_time.sh").
#
# How: many short renders on one thread, A and B one right after the other
# on the same CPU, the order turned round every round (AB, BA, AB, ...):
# render_spp renders one frame of the job, reference buffer only, SPP paths
# per pixel (its CPU seconds are timed); render_throughput renders its own
# frame (noisy versions, reference, albedo, aux; the renderer's seconds of
# one pass are timed, as in its own-ray ratio). A
# change of the machine's speed then falls on both of a pair alike, and
# the ratio B/A of each pair keeps what differs between the binaries. The
# median of the ratios is the figure; their quartiles say how far to trust
# it, and the same script with B = A shows how far apart two identical
# binaries come out (the resolution). A change meant to keep images the
# same is also checked: the two PFMs of the last round are compared byte
# for byte.
#
# usage: bench/ab_time.sh BINARY_A BINARY_B [OUT_DIR]
#   BINARY_*: two render_spp or two render_throughput binaries
#   (BUILD/bench/...), e.g. one copied aside before the change; which of
#   the two from the file name (render_spp*, render_throughput*), else KIND.
#   env: SCENE (courtyard or cornell, courtyard), ROUNDS (20), CPU (the CPU
#        to pin both to, the last one allowed); render_spp: SPP (4),
#        FRAME (24); render_throughput: SIZE (image width, 256)
# Prints figures; asserts nothing. Needs taskset (util-linux) for pinning;
# without it the renders are not pinned.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
usage() {
  echo "usage: bench/ab_time.sh BINARY_A BINARY_B [OUT_DIR]" >&2
  exit 2
}
if [ $# -lt 2 ] || [ $# -gt 3 ]; then usage; fi
a=$1
b=$2
out=${3:-/tmp/ab_time}
scene=${SCENE:-courtyard}
spp=${SPP:-4}
frame=${FRAME:-24}
rounds=${ROUNDS:-20}
size=${SIZE:-256}
kind=
for bin in "$a" "$b"; do
  [ -x "$bin" ] || { echo "ab_time.sh: $bin is not an executable" >&2; exit 2; }
  case "$(basename "$bin")" in
    render_spp*) k=render_spp ;;
    render_throughput*) k=render_throughput ;;
    *) k=${KIND:-} ;;
  esac
  [ -n "$k" ] || { echo "ab_time.sh: is $bin render_spp or render_throughput? (set KIND)" >&2; exit 2; }
  [ -z "$kind" ] || [ "$kind" = "$k" ] || { echo "ab_time.sh: $a and $b are different benchmarks" >&2; exit 2; }
  kind=$k
done
case "$scene" in
  courtyard | cornell) ;;
  *)
    echo "ab_time.sh: SCENE must be courtyard or cornell, got '$scene'" >&2
    exit 2
    ;;
esac
for v in spp frame rounds size; do
  if ! [[ "${!v}" =~ ^[0-9]+$ ]] || { [ "${!v}" -eq 0 ] && [ "$v" != frame ]; }; then
    echo "ab_time.sh: ${v^^} must be a positive number, got '${!v}'" >&2
    exit 2
  fi
done
pin=()
if command -v taskset >/dev/null; then
  cpu=${CPU:-$(taskset -cp $$ | sed 's/.*: //' | tr ',' '\n' | tail -1 | sed 's/.*-//')}
  [[ "$cpu" =~ ^[0-9]+$ ]] || { echo "ab_time.sh: CPU must be a CPU number, got '$cpu'" >&2; exit 2; }
  pin=(taskset -c "$cpu")
fi
mkdir -p "$out"
job=$root/jobs/$scene.toml

# One render; prints its seconds. render_spp: the CPU seconds of its render;
# render_throughput: the renderer's seconds (one pass, --repeats 1).
render() {  # binary, output prefix
  local text
  if [ "$kind" = render_spp ]; then
    text=$("${pin[@]}" "$1" --job "$job" --frame "$frame" --spp "$spp" --threads 1 --out "$2") || {
      echo "ab_time.sh: $1 failed" >&2
      exit 1
    }
    awk '{for (i = 1; i < NF; ++i) if ($i == "cpu_s") print $(i + 1)}' <<<"$text"
  else
    text=$("${pin[@]}" "$1" --scene "$scene" --size "$size" --threads 1 --rays 1000 --repeats 1) || {
      echo "ab_time.sh: $1 failed" >&2
      exit 1
    }
    awk '/^renderer:/ {print $(NF - 1)}' <<<"$text"
  fi
}

if [ "$kind" = render_spp ]; then
  what="frame $frame, $spp spp"
else
  what="render_throughput's frame at width $size"
fi
echo "ab_time.sh: $scene, $what, $rounds rounds${pin:+, pinned to CPU ${cpu:-}}" >&2
: >"$out/times.txt"
for ((r = 1; r <= rounds; ++r)); do
  if ((r % 2)); then
    ta=$(render "$a" "$out/a_")
    tb=$(render "$b" "$out/b_")
  else
    tb=$(render "$b" "$out/b_")
    ta=$(render "$a" "$out/a_")
  fi
  echo "$ta $tb" >>"$out/times.txt"
done

awk '
  { a[NR] = $1; b[NR] = $2; r[NR] = $2 / $1; faster += ($2 < $1) }
  END {
    n = NR
    for (i = 1; i <= n; ++i)  # insertion sort of the ratios
      for (j = i; j > 1 && r[j - 1] > r[j]; --j) { t = r[j]; r[j] = r[j - 1]; r[j - 1] = t }
    printf "rounds %d  A %.3f-%.3f s  B %.3f-%.3f s per render\n", n, min(a, n), max(a, n), min(b, n), max(b, n)
    printf "B/A median %.4f  quartiles %.4f-%.4f  B faster in %d of %d rounds\n",
      quantile(r, n, 0.5), quantile(r, n, 0.25), quantile(r, n, 0.75), faster, n
  }
  function quantile(s, n, p,   x, i) { x = 1 + p * (n - 1); i = int(x); return i < n ? s[i] + (x - i) * (s[i + 1] - s[i]) : s[n] }
  function min(v, n,   m, i) { m = v[1]; for (i = 2; i <= n; ++i) if (v[i] < m) m = v[i]; return m }
  function max(v, n,   m, i) { m = v[1]; for (i = 2; i <= n; ++i) if (v[i] > m) m = v[i]; return m }
' "$out/times.txt"
if [ "$kind" = render_spp ]; then
  if cmp -s "$out/a_$spp.pfm" "$out/b_$spp.pfm"; then
    echo "images: byte-identical"
  else
    echo "images: differ"
  fi
fi
