#!/usr/bin/env python3
# The dofarm half of bench/cycles/gltf_features_vs_cycles.sh: writes the job
# files (and control variants) for a scene that feature_scene.py exported,
# and prints the comparison with Cycles' image. Plain Python (no numpy).
#
#   feature_compare.py header FEATURE
#   feature_compare.py variants FEATURE DIR SIZE   -> DIR/<variant>.toml, prints the variants
#   feature_compare.py rows FEATURE DIR SPP [SPECULAR TINT]
#   feature_compare.py versus CYCLES.pfm LABEL=DOFARM.pfm...   (any two
#               renders of one size: correlation, mean ratio, relative RMSE;
#               bench/cycles/default_scene_vs_cycles.sh)
#   feature_compare.py against NAME REF.pfm LABEL=DOFARM.pfm...   (the same
#               against another reference, named NAME in the table;
#               bench/cycles/blender_formats.sh)
#
# Variants (each a job of its own, rendered by bench/render_spp):
#   specular    file (as exported), ignored (KHR_materials_specular removed:
#               how dofarm rendered it before reading the extension)
#   specular_texture  file, untextured (specularTexture and
#               specularColorTexture removed: how dofarm rendered it before
#               reading them)
#   normal_map  file, flipped (the map's green inverted: a frame whose up is
#               the wrong way), nomap (normalTexture removed); the same for
#   normal_map_tangents (the file carries TANGENT)
#   alpha_mask, alpha_blend  file, opaque (alphaMode removed)
#   clearcoat_normal  file, flipped (the coat map's green inverted), nomap
#               (clearcoatNormalTexture removed: how dofarm rendered it
#               before reading it)
#   uv_map      file, set0 (control: every texCoord removed, so the texture
#               reads TEXCOORD_0: how dofarm rendered it before reading set 1)
#   transmission  file, opaque (KHR_materials_transmission removed: how
#               dofarm rendered it before reading the extension), ior1
#               (control: IOR 1, so nothing bends); these jobs add the
#               world's grey (0.3) as a constant environment
#   animation, skinning, shape_keys, camera  file, static (the animations removed)
#   animation_spline, shape_keys_spline, camera_spline  file, linear (control: each
#               CUBICSPLINE sampler made LINEAR over its key values, as
#               dofarm interpolated them before reading the tangents), static
#   clipping    file, unclipped (control: znear 0.01 and no zfar)
#   soft_lamps  sized (the job's [lights] radius = 0.25, sun_angle = 10:
#               the lamps' sizes in Blender), file (control: the file alone,
#               a point lamp and parallel sunlight)
#   spot_cone   file, khr (control: asset.generator not Blender's, so the
#               spot takes KHR_lights_punctual's recommended falloff)
#   spot_soft   sized (the job's [lights] radius = 0.25), file (control: a
#               point spot, hard edges)
#   lamp_mirror sized, file (control: the file alone: points, which no
#               mirror shows)
#   ortho       file (an orthographic camera, 3 m across), persp (control:
#               a perspective camera that frames the floor the same: what a
#               user would get from a renderer without orthographic cameras)
#   ortho_dof   file (the job's fstop = 0.8, focal_distance = 4.2, as set in
#               Blender: lens radius 1 / (2 N) = 0.625, focal plane 4.2 m
#               beyond Clip Start), lens (control: the radius a perspective
#               camera's 50 mm lens would give at f/0.8, 0.03125),
#               from_camera (control: focal_distance 3.2, the focal plane
#               4.2 m from the camera, as if Cycles counted Focus Distance
#               from the camera), pinhole (control: no lens)
#   clearcoat   file, ignored (KHR_materials_clearcoat removed), quarter
#               (clearcoatFactor x 0.25: Blender 3.4's Principled v1 weighs
#               its clearcoat lobe by a quarter, as Disney's 2012 model does)
# Measures: specular and clearcoat, dofarm / Cycles per channel over the centre 8 x 8
# pixels (lamp, surface and camera in line: the coat's highlight, and
# Cycles' Disney diffuse equals Lambert's there); the others, the
# correlation of pixel luminances with Cycles' (the pattern of light and
# shade, or of holes) and the ratio of the means; for transmission over the
# centre 32 x 32 pixels (inside the sphere's disk: the refracted floor), and
# for specular_texture too (the highlight, which the checker modulates).
import copy
import json
import math
import struct
import sys
import zlib

VARIANTS = {"specular": ["file", "ignored"], "clearcoat": ["file", "ignored", "quarter"], "normal_map": ["file", "flipped", "nomap"],
            "normal_map_tangents": ["file", "flipped", "nomap"], "alpha_mask": ["file", "opaque"],
            "alpha_blend": ["file", "opaque"], "transmission": ["file", "opaque", "ior1"],
            "uv_map": ["file", "set0"], "specular_texture": ["file", "untextured"], "clearcoat_normal": ["file", "flipped", "nomap"],
            "animation": ["file", "static"], "skinning": ["file", "static"],
            "shape_keys": ["file", "static"], "animation_spline": ["file", "linear", "static"],
            "shape_keys_spline": ["file", "linear", "static"],
            "camera": ["file", "static"], "clipping": ["file", "unclipped"], "camera_spline": ["file", "linear", "static"],
            "soft_lamps": ["sized", "file"], "lamp_mirror": ["sized", "file"],
            "spot_cone": ["file", "khr"], "spot_soft": ["sized", "file"],
            "ortho": ["file", "persp"], "ortho_dof": ["file", "lens", "from_camera", "pinhole"]}
WHAT = {"file": "the exported file", "ignored": "KHR_materials_specular ignored",
        "flipped": "control: the map's green inverted", "nomap": "control: no normal map",
        "opaque": "control: alphaMode ignored (opaque)", "ior1": "control: IOR 1 (no bending)",
        "set0": "control: the texture reads TEXCOORD_0",
        "untextured": "control: the specular textures removed (factors only)",
        "static": "control: the node animation removed (the pose exported, frame 0)",
        "linear": "control: the same keys interpolated linearly (tangents dropped)",
        "unclipped": "control: the camera's znear 0.01 and no zfar (no clipping)",
        "sized": "the file, with the job's lights.radius = 0.25 and lights.sun_angle = 10",
        "khr": "control: the same file said to come from elsewhere (KHR_lights_punctual's recommended falloff)",
        "persp": "control: a perspective camera framing the floor the same (yfov 33.4 degrees)",
        "lens": "control: lens radius 0.03125 (50 mm at f/0.8, a perspective camera's)",
        "from_camera": "control: focal_distance 3.2 (the focal plane 4.2 m from the camera, not from Clip Start)",
        "pinhole": "control: no lens (aperture 0)"}
# The lens keys of a variant's job ([[camera.key]]); default a pinhole.
LENS = {("ortho_dof", "file"): "fstop = 0.8\nfocal_distance = 4.2\n",
        ("ortho_dof", "lens"): "aperture = 0.03125\nfocal_distance = 4.2\n",
        ("ortho_dof", "from_camera"): "fstop = 0.8\nfocal_distance = 3.2\n"}
# Lamp sizes a job gives back (features soft_lamps and lamp_mirror, variant sized).
LIGHTS = {"sized": "[lights]\nradius = 0.25\nsun_angle = 10.0\n"}
# Features whose rows add the relative RMSE against Cycles: what differs
# covers a small part of the image (a moved part, a penumbra).
RMSE_FEATURES = ("animation", "skinning", "shape_keys", "animation_spline", "shape_keys_spline",
                 "camera", "camera_spline", "soft_lamps", "lamp_mirror", "spot_cone", "spot_soft",
                 "ortho", "ortho_dof")
# The frames feature_scene.py renders the animated scenes at (its
# ANIMATION_FRAME), at Blender's 24 fps.
ANIMATION_FRAME = {"animation": 9, "skinning": 13, "shape_keys": 13, "animation_spline": 5,
                   "shape_keys_spline": 5, "camera": 5, "camera_spline": 5}


def read_png(path):
    """8-bit RGB or RGBA, not interlaced (what Blender writes): w, h, channels, rows."""
    data = open(path, "rb").read()
    pos, idat = 8, b""
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, ctype = struct.unpack(">IIBB", body[:10])
            if depth != 8 or ctype not in (2, 6):
                raise SystemExit("%s: expected 8-bit RGB or RGBA" % path)
            ch = 3 if ctype == 2 else 4
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw, rows, prev, stride = zlib.decompress(idat), [], bytearray(w * ch), w * ch + 1
    for y in range(h):
        f, line = raw[y * stride], bytearray(raw[y * stride + 1:(y + 1) * stride])
        for i in range(len(line)):
            a = line[i - ch] if i >= ch else 0
            b, c = prev[i], (prev[i - ch] if i >= ch else 0)
            p = a + b - c
            paeth = a if abs(p - a) <= abs(p - b) and abs(p - a) <= abs(p - c) else (
                b if abs(p - b) <= abs(p - c) else c)
            line[i] = (line[i] + (0, a, b, (a + b) // 2, paeth)[f]) & 255
        rows.append(bytes(line))
        prev = line
    return w, h, ch, rows


def write_png(path, w, h, ch, rows):
    def chunk(kind, body):
        return (struct.pack(">I", len(body)) + kind + body +
                struct.pack(">I", zlib.crc32(kind + body) & 0xffffffff))
    header = struct.pack(">IIBBBBB", w, h, 8, 2 if ch == 3 else 6, 0, 0, 0)
    raw = b"".join(b"\0" + r for r in rows)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) +
                chunk(b"IEND", b""))


def linear_samplers(v, d):
    """Every CUBICSPLINE sampler of glTF document v (its buffer in DIR) made
    LINEAR over the same key values: each key's in-tangent, value and
    out-tangent become the value alone, in a copy of the buffer (linear.bin)."""
    buf = v["buffers"][0]
    data = open(d + "/" + buf["uri"], "rb").read()
    extra = bytearray()
    for anim in v.get("animations", []):
        for smp in anim["samplers"]:
            if smp.get("interpolation") != "CUBICSPLINE":
                continue
            acc = v["accessors"][smp["output"]]
            view = v["bufferViews"][acc["bufferView"]]
            width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[acc["type"]]
            keys = v["accessors"][smp["input"]]["count"]
            n = acc["count"] * width
            floats = struct.unpack_from("<%df" % n, data,
                                        view.get("byteOffset", 0) + acc.get("byteOffset", 0))
            per = n // (3 * keys)  # floats per value (a target count for weights)
            values = []
            for k in range(keys):
                values += floats[(3 * k + 1) * per:(3 * k + 2) * per]
            offset = len(data) + len(extra)
            extra += struct.pack("<%df" % len(values), *values)
            v["bufferViews"].append({"buffer": 0, "byteOffset": offset, "byteLength": 4 * len(values)})
            new = {"bufferView": len(v["bufferViews"]) - 1, "componentType": 5126,
                   "count": len(values) // width, "type": acc["type"]}
            v["accessors"].append(new)
            smp["output"] = len(v["accessors"]) - 1
            smp["interpolation"] = "LINEAR"
    open(d + "/linear.bin", "wb").write(data + bytes(extra))
    buf["uri"] = "linear.bin"
    buf["byteLength"] = len(data) + len(extra)


def variants(feature, d, size):
    g = json.load(open(d + "/scene.gltf"))
    for name in VARIANTS[feature]:
        v = copy.deepcopy(g)
        mats = v["materials"]
        if name == "ignored":
            ext = "KHR_materials_clearcoat" if feature == "clearcoat" else "KHR_materials_specular"
            for m in mats:
                m.get("extensions", {}).pop(ext, None)
            v["extensionsUsed"] = [e for e in v.get("extensionsUsed", []) if e != ext]
        elif name == "quarter":
            for m in mats:
                cc = m.get("extensions", {}).get("KHR_materials_clearcoat")
                if cc:
                    cc["clearcoatFactor"] = 0.25 * cc.get("clearcoatFactor", 0.0)
        elif name == "nomap":
            for m in mats:
                m.pop("normalTexture", None)
                m.get("extensions", {}).get("KHR_materials_clearcoat", {}).pop(
                    "clearcoatNormalTexture", None)
        elif name == "opaque" and feature == "transmission":
            for m in mats:
                m.get("extensions", {}).pop("KHR_materials_transmission", None)
            v["extensionsUsed"] = [e for e in v.get("extensionsUsed", [])
                                   if e != "KHR_materials_transmission"]
        elif name == "opaque":
            for m in mats:
                m.pop("alphaMode", None)
        elif name == "untextured":
            for m in mats:
                for key in ("specularTexture", "specularColorTexture"):
                    m.get("extensions", {}).get("KHR_materials_specular", {}).pop(key, None)
        elif name == "static":
            v.pop("animations", None)
        elif name == "khr":
            v["asset"]["generator"] = "feature_compare.py"  # not Blender: the extension's falloff
        elif name == "linear":
            linear_samplers(v, d)
        elif name == "persp":
            # Half of 3 m at the floor, 5 m away: yfov = 2 atan(1.5 / 5).
            for cam in v.get("cameras", []):
                near = cam["orthographic"]["znear"]
                far = cam["orthographic"].get("zfar")
                cam.pop("orthographic")
                cam["type"] = "perspective"
                cam["perspective"] = {"yfov": 2.0 * math.atan(1.5 / 5.0), "aspectRatio": 1.0,
                                      "znear": near}
                if far:
                    cam["perspective"]["zfar"] = far
        elif name == "unclipped":
            for cam in v.get("cameras", []):
                cam["perspective"]["znear"] = 0.01
                cam["perspective"].pop("zfar", None)
        elif name == "set0":
            for m in mats:
                for info in [m.get("pbrMetallicRoughness", {}).get("baseColorTexture", {})]:
                    info.pop("texCoord", None)
        elif name == "ior1":
            for m in mats:
                if "KHR_materials_transmission" in m.get("extensions", {}):
                    m["extensions"]["KHR_materials_ior"] = {"ior": 1.0}
        elif name == "flipped":
            infos = [m["normalTexture"] for m in mats if "normalTexture" in m] + [
                m["extensions"]["KHR_materials_clearcoat"]["clearcoatNormalTexture"] for m in mats
                if "clearcoatNormalTexture" in m.get("extensions", {}).get("KHR_materials_clearcoat", {})]
            image = v["images"][v["textures"][infos[0]["index"]]["source"]]
            w, h, ch, rows = read_png(d + "/" + image["uri"])
            rows = [bytes(x if i % ch != 1 else 255 - x for i, x in enumerate(r)) for r in rows]
            write_png(d + "/flipped_green.png", w, h, ch, rows)
            image["uri"] = "flipped_green.png"
        json.dump(v, open("%s/%s.gltf" % (d, name), "w"))
        world = '[environment]\ncolor = [0.3, 0.3, 0.3]\n' if feature == "transmission" else ""
        frame = ANIMATION_FRAME.get(feature, 0)
        open("%s/%s.toml" % (d, name), "w").write(
            'scene = "%s.gltf"\nseed = 3\n[image]\nwidth = %d\nheight = %d\n'
            '[frames]\nstart = %d\nend = %d\nfps = 24\n[camera]\nfrom_scene = true\n'
            '[[camera.key]]\nframe = %d\n%s'
            '[buffers]\nversions = 1\nalbedo_ref_spp = 1\n%s%s'
            % (name, size, size, frame, frame, frame,
               LENS.get((feature, name), "aperture = 0.0\nfocal_distance = 5.0\n"), world,
               LIGHTS.get(name, "")))
        print(name)


def read_pfm(path):
    data = open(path, "rb").read()
    _, dims, _, body = data.split(b"\n", 3)
    w, h = map(int, dims.split())
    return w, h, struct.unpack("<%df" % (w * h * 3), body[:12 * w * h])


def centre(path):
    w, h, px = read_pfm(path)
    s = [0.0, 0.0, 0.0]
    for y in range(h // 2 - 4, h // 2 + 4):
        for x in range(w // 2 - 4, w // 2 + 4):
            for c in range(3):
                s[c] += px[3 * (y * w + x) + c] / 64.0
    return s


def luminance(path, window=0):
    """Pixel luminances, all or the centre window x window."""
    w, h, px = read_pfm(path)
    keep = lambda i: not window or (abs(i % w - w // 2 + 0.5) < window / 2 and
                                    abs(i // w - h // 2 + 0.5) < window / 2)
    return [0.2126 * px[3 * i] + 0.7152 * px[3 * i + 1] + 0.0722 * px[3 * i + 2]
            for i in range(w * h) if keep(i)]


def correlation(a, b):
    ma, mb = sum(a) / len(a), sum(b) / len(b)
    sab = sum((x - ma) * (y - mb) for x, y in zip(a, b))
    saa, sbb = sum((x - ma) ** 2 for x in a), sum((y - mb) ** 2 for y in b)
    return sab / (saa * sbb) ** 0.5 if saa > 0 and sbb > 0 else 0.0


def header(feature):
    if feature == "specular":
        print("| Specular | Tint | specularColorFactor in the file | dofarm / Cycles (R, G, B) |"
              " extension ignored (R, G, B) |")
        print("| --- | --- | --- | --- | --- |")
    elif feature == "clearcoat":
        print("| Clearcoat Roughness | dofarm / Cycles (R, G, B) | extension ignored (R, G, B) |"
              " clearcoatFactor x 0.25 (R, G, B) |")
        print("| --- | --- | --- | --- |")
    elif feature in RMSE_FEATURES:
        # What moves (or a penumbra) covers a small part of the image: the
        # relative RMSE shows it where the correlation hardly does.
        print("| dofarm render | correlation with Cycles | mean / Cycles' mean |"
              " relative RMSE against Cycles |")
        print("| --- | --- | --- | --- |")
    else:
        print("| dofarm render | correlation with Cycles | mean / Cycles' mean |")
        print("| --- | --- | --- |")


def rows(feature, d, spp, extra):
    image = lambda name: "%s/%s_%s.pfm" % (d, name, spp)
    if feature == "specular":
        cy = centre(d + "/cycles.pfm")
        ratio = lambda name: ", ".join("%.3f" % (a / b) for a, b in zip(centre(image(name)), cy))
        ext = json.load(open(d + "/scene.gltf"))["materials"][0].get("extensions", {})
        f = ext.get("KHR_materials_specular", {}).get("specularColorFactor")
        f = "[" + ", ".join("%.3f" % x for x in f) + "]" if f else "(none)"
        print("| %s | %s | %s | %s | %s |" % (extra[0], extra[1], f, ratio("file"), ratio("ignored")))
        return
    if feature == "clearcoat":
        cy = centre(d + "/cycles.pfm")
        ratio = lambda name: ", ".join("%.3f" % (a / b) for a, b in zip(centre(image(name)), cy))
        print("| %s | %s | %s | %s |" % (extra[0], ratio("file"), ratio("ignored"), ratio("quarter")))
        return
    window = 32 if feature in ("transmission", "specular_texture") else 0
    cy = luminance(d + "/cycles.pfm", window)
    for name in VARIANTS[feature]:
        x = luminance(image(name), window)
        what = WHAT[name]
        if feature == "transmission" and name == "opaque":
            what = "control: KHR_materials_transmission ignored (opaque)"
        elif feature == "soft_lamps" and name == "file":
            what = "control: the file alone (a point lamp, parallel sunlight: hard shadows)"
        elif feature == "spot_soft" and name == "file":
            what = "control: the file alone (a point spot: hard shadow)"
        elif feature == "lamp_mirror" and name == "file":
            what = "control: the file alone (points, which the mirror cannot show)"
        row = "| %s | %.3f | %.3f |" % (what, correlation(x, cy),
                                          (sum(x) / len(x)) / (sum(cy) / len(cy)))
        if feature in RMSE_FEATURES:
            rmse = (sum((a - b) ** 2 for a, b in zip(x, cy)) / len(x)) ** 0.5
            row += " %.3f |" % (rmse / (sum(cy) / len(cy)))
        print(row)


def versus(cycles_pfm, labelled, reference="Cycles"):
    """One row per dofarm render against the reference image (Cycles')."""
    cy = luminance(cycles_pfm)
    mean_cy = sum(cy) / len(cy)
    print("| dofarm render | correlation with %s | mean / %s mean |"
          " relative RMSE against %s |" % (reference, reference, reference))
    print("| --- | --- | --- | --- |")
    for item in labelled:
        label, path = item.rsplit("=", 1)
        x = luminance(path)
        if len(x) != len(cy):
            raise SystemExit("%s: not the size of %s" % (path, cycles_pfm))
        rmse = (sum((a - b) ** 2 for a, b in zip(x, cy)) / len(x)) ** 0.5
        print("| %s | %.3f | %.3f | %.3f |" % (label, correlation(x, cy),
                                               (sum(x) / len(x)) / mean_cy, rmse / mean_cy))


def main():
    a = sys.argv[1:]
    if len(a) >= 2 and a[0] == "header":
        header(a[1])
    elif len(a) == 4 and a[0] == "variants":
        variants(a[1], a[2], int(a[3]))
    elif len(a) >= 4 and a[0] == "rows":
        rows(a[1], a[2], a[3], a[4:])
    elif len(a) >= 3 and a[0] == "versus":
        versus(a[1], a[2:])
    elif len(a) >= 4 and a[0] == "against":
        versus(a[2], a[3:], reference=a[1])
    else:
        raise SystemExit(__doc__ or "usage: see the head of feature_compare.py")


main()
