#!/usr/bin/env bash
# KHR_materials_specular against Cycles: Blender's exporter writes a
# Principled BSDF's Specular and Specular Tint as the extension's
# specularColorFactor (0.08 Specular / F0(IOR), tinted towards the base
# colour). For each (Specular, Tint) pair, bench/cycles/specular_plane.py
# builds a plane (base colour 0.8, 0.4, 0.2, roughness 0.5) under a 1000 W
# point lamp, exports it and renders it with Cycles; dofarm renders the
# exported file as written and with the extension removed (as it rendered
# before it read the extension). Printed: what the file says, and dofarm /
# Cycles per channel over the centre 8 x 8 pixels, where lamp, pixel and
# camera are in line (Cycles' Principled diffuse is Disney's, which equals
# Lambert's at normal incidence only).
#
#   bench/cycles/specular_vs_cycles.sh [BUILD_DIR] [OUT_DIR] [SPP]
#   (BUILD_DIR default build, OUT_DIR /tmp/specular_vs_cycles, SPP 256;
#    needs Debian's blender and python3-numpy for its glTF exporter)
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
build=$(cd "${1:-build}" && pwd)
out=${2:-/tmp/specular_vs_cycles}
spp=${3:-256}
command -v blender > /dev/null || { echo "specular_vs_cycles.sh: needs blender (apt-get install blender python3-numpy)" >&2; exit 2; }
mkdir -p "$out"
printf '| Specular | Tint | specularColorFactor in the file | dofarm / Cycles (R, G, B) | extension ignored (R, G, B) |\n'
printf '| --- | --- | --- | --- | --- |\n'
for pair in "0 0" "0.5 0" "1 0" "0.5 1"; do
  set -- $pair
  dir=$out/s$1-t$2
  blender -b -noaudio --factory-startup -P "$here/specular_plane.py" -- "$dir" "$1" "$2" "$spp" \
    > "$dir.blender.log" 2>&1 || { cat "$dir.blender.log" >&2; exit 1; }
  python3 - "$dir" <<'PY'
import json, sys
d = sys.argv[1]
g = json.load(open(d + "/plane.gltf"))
for m in g["materials"]:
    m.get("extensions", {}).pop("KHR_materials_specular", None)
g["extensionsUsed"] = [e for e in g.get("extensionsUsed", []) if e != "KHR_materials_specular"]
json.dump(g, open(d + "/plane_noext.gltf", "w"))
for name in ("plane", "plane_noext"):
    open("%s/%s.toml" % (d, name), "w").write(
        'scene = "%s.gltf"\nseed = 3\n[image]\nwidth = 64\nheight = 64\n'
        '[frames]\nstart = 0\nend = 0\n[camera]\nfrom_scene = true\n'
        '[[camera.key]]\nframe = 0\naperture = 0.0\nfocal_distance = 5.0\n'
        '[buffers]\nversions = 1\nalbedo_ref_spp = 1\n' % name)
PY
  for name in plane plane_noext; do
    "$build/bench/render_spp" --job "$dir/$name.toml" --spp "$spp" --threads 2 \
      --out "$dir/${name}_" > "$dir/$name.log" 2>&1 || { cat "$dir/$name.log" >&2; exit 1; }
  done
  python3 - "$dir" "$spp" "$1" "$2" <<'PY'
import json, struct, sys
d, spp, specular, tint = sys.argv[1:5]
def centre(path):
    data = open(path, "rb").read()
    head, dims, scale, body = data.split(b"\n", 3)
    w, h = map(int, dims.split())
    px = struct.unpack("<%df" % (w * h * 3), body[: 12 * w * h])
    s = [0.0, 0.0, 0.0]
    for y in range(h // 2 - 4, h // 2 + 4):
        for x in range(w // 2 - 4, w // 2 + 4):
            for c in range(3):
                s[c] += px[3 * (y * w + x) + c] / 64.0
    return s
cy = centre(d + "/cycles.pfm")
ratio = lambda p: ", ".join("%.3f" % (a / b) for a, b in zip(centre(p), cy))
ext = json.load(open(d + "/plane.gltf"))["materials"][0].get("extensions", {})
factor = ext.get("KHR_materials_specular", {}).get("specularColorFactor", "(none)")
if isinstance(factor, list):
    factor = "[" + ", ".join("%.3f" % v for v in factor) + "]"
print("| %s | %s | %s | %s | %s |" % (specular, tint, factor,
      ratio("%s/plane_%s.pfm" % (d, spp)), ratio("%s/plane_noext_%s.pfm" % (d, spp))))
PY
done
