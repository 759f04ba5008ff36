#!/usr/bin/env bash
# glTF normal maps against Cycles: bench/cycles/normal_map_plane.py builds a
# plane whose Principled BSDF takes a tangent-space normal map of bumps
# varying along both image axes, lit by a sun from the side, exports it with
# Blender's glTF exporter and renders it with Cycles. dofarm renders the
# exported file, and two controls: the same file with the map's green
# channel inverted (a frame whose up is the wrong way) and with the
# normalTexture removed (no map). Printed per render: the correlation of its
# pixel luminances with Cycles' (1 = the same pattern of light and shade;
# the flat plane scores about 0, the flipped frame less than the right one)
# and the ratio of the means.
#
#   bench/cycles/normal_map_vs_cycles.sh [BUILD_DIR] [OUT_DIR] [SPP]
#   (BUILD_DIR default build, OUT_DIR /tmp/normal_map_vs_cycles, SPP 64;
#    needs Debian's blender and python3-numpy for its glTF exporter)
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
build=$(cd "${1:-build}" && pwd)
out=${2:-/tmp/normal_map_vs_cycles}
spp=${3:-64}
command -v blender > /dev/null || { echo "normal_map_vs_cycles.sh: needs blender (apt-get install blender python3-numpy)" >&2; exit 2; }
mkdir -p "$out"
blender -b -noaudio --factory-startup -P "$here/normal_map_plane.py" -- "$out" "$spp" \
  > "$out/blender.log" 2>&1 || { cat "$out/blender.log" >&2; exit 1; }
python3 - "$out" <<'PY'
import json, sys, zlib, struct
d = sys.argv[1]
g = json.load(open(d + "/plane.gltf"))
uri = g["images"][g["textures"][g["materials"][0]["normalTexture"]["index"]]["source"]]["uri"]

def read_png(path):  # 8-bit RGB(A), no interlace: what Blender writes here
    data = open(path, "rb").read()
    pos, idat, w = 8, b"", 0
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, ctype = struct.unpack(">IIBB", body[:10])
            assert depth == 8 and ctype in (2, 6), "8-bit RGB or RGBA expected"
            ch = 3 if ctype == 2 else 4
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw, rows, prev = zlib.decompress(idat), [], bytearray(w * ch)
    stride = w * ch + 1
    for y in range(h):
        f, line = raw[y * stride], bytearray(raw[y * stride + 1:(y + 1) * stride])
        for i in range(len(line)):
            a = line[i - ch] if i >= ch else 0
            b, c = prev[i], prev[i - ch] if i >= ch else 0
            p = a + b - c
            pred = [0, a, b, (a + b) // 2, a if abs(p - a) <= abs(p - b) and abs(p - a) <= abs(p - c) else (b if abs(p - b) <= abs(p - c) else c)][f]
            line[i] = (line[i] + pred) & 255
        rows.append(bytes(line)); prev = line
    return w, h, ch, rows

def write_png(path, w, h, ch, rows):
    raw = b"".join(b"\0" + r for r in rows)
    def chunk(k, b):
        return struct.pack(">I", len(b)) + k + b + struct.pack(">I", zlib.crc32(k + b) & 0xffffffff)
    ctype = 2 if ch == 3 else 6
    open(path, "wb").write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, ctype, 0, 0, 0))
                           + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))

w, h, ch, rows = read_png(d + "/" + uri)
flipped = [bytes(v if i % ch != 1 else 255 - v for i, v in enumerate(r)) for r in rows]
write_png(d + "/flipped_green.png", w, h, ch, flipped)
variants = {"plane": g}
f = json.loads(json.dumps(g)); f["images"][0]["uri"] = "flipped_green.png"; variants["flipped"] = f
n = json.loads(json.dumps(g)); n["materials"][0].pop("normalTexture"); variants["nomap"] = n
for name, doc in variants.items():
    json.dump(doc, open("%s/%s_v.gltf" % (d, name), "w"))
    open("%s/%s.toml" % (d, name), "w").write(
        'scene = "%s_v.gltf"\nseed = 3\n[image]\nwidth = 96\nheight = 96\n'
        '[frames]\nstart = 0\nend = 0\n[camera]\nfrom_scene = true\n'
        '[[camera.key]]\nframe = 0\naperture = 0.0\nfocal_distance = 5.0\n'
        '[buffers]\nversions = 1\nalbedo_ref_spp = 1\n' % name)
PY
for name in plane flipped nomap; do
  "$build/bench/render_spp" --job "$out/$name.toml" --spp "$spp" --threads 2 \
    --out "$out/${name}_" > "$out/$name.log" 2>&1 || { cat "$out/$name.log" >&2; exit 1; }
done
python3 - "$out" "$spp" <<'PY'
import struct, sys
d, spp = sys.argv[1:3]
def lum(path):
    data = open(path, "rb").read()
    head, dims, scale, body = data.split(b"\n", 3)
    w, h = map(int, dims.split())
    px = struct.unpack("<%df" % (w * h * 3), body[: 12 * w * h])
    return [0.2126 * px[3 * i] + 0.7152 * px[3 * i + 1] + 0.0722 * px[3 * i + 2] for i in range(w * h)]
def corr(a, b):
    ma, mb = sum(a) / len(a), sum(b) / len(b)
    sab = sum((x - ma) * (y - mb) for x, y in zip(a, b))
    saa = sum((x - ma) ** 2 for x in a); sbb = sum((y - mb) ** 2 for y in b)
    return sab / (saa * sbb) ** 0.5 if saa > 0 and sbb > 0 else 0.0
cy = lum(d + "/cycles.pfm")
print("| dofarm render | correlation with Cycles | mean / Cycles' mean |")
print("| --- | --- | --- |")
for name, what in (("plane", "the exported file"), ("flipped", "control: map's green inverted"),
                   ("nomap", "control: no normal map")):
    x = lum("%s/%s_%s.pfm" % (d, name, spp))
    print("| %s | %.3f | %.3f |" % (what, corr(x, cy), (sum(x) / len(x)) / (sum(cy) / len(cy))))
PY
