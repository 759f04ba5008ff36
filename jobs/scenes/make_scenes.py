#!/usr/bin/env python3
"""Writes the scenes dofarm ships: glTF 2.0 files and their PNG textures.

Everything here is made from code (CC0, self-made); only the Python standard
library is used, so anyone can regenerate the files:

    python3 jobs/scenes/make_scenes.py          # writes next to this script

The output is deterministic (same bytes on every run): floats are rounded
before they reach JSON, PNGs are compressed with a fixed zlib level, and no
timestamps are written.

Scenes
  cornell.gltf    The Cornell box, 2 units wide (x in [-1, 1], y in [0, 2],
                  z in [-1, 1], open towards +z), as in the DESIGN.md example
                  camera. Red left wall (x = -1), green right wall (x = +1),
                  a tall and a short box, a ceiling light facing down, a GGX
                  metal sphere (roughness 0.2) and a rough dielectric sphere.
  courtyard.gltf  Outdoor scene in metres, lit by an HDRI (see
                  jobs/courtyard.toml): checker-textured ground, brushed and
                  polished metal, rough plastic with a metallic-roughness
                  texture, one small emitter, and an animated camera.
  test/*.gltf     Analytic scenes with known answers for the renderer tests.

HDR emission: glTF's emissiveFactor is limited to [0, 1]; the radiance scale
lives in KHR_materials_emissive_strength. assimp 5.2.5 does not import that
extension, so dofarm's loader reads it from the glTF JSON itself
(worker/render/scene_data.cpp). The files stay valid glTF for other tools.
"""

import base64
import json
import math
import os
import struct
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))

# --------------------------------------------------------------------------
# Small vector helpers


def add(a, b):
    return [a[0] + b[0], a[1] + b[1], a[2] + b[2]]


def sub(a, b):
    return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]


def scale(a, s):
    return [a[0] * s, a[1] * s, a[2] * s]


def cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def normalize(a):
    length = math.sqrt(dot(a, a))
    return [a[0] / length, a[1] / length, a[2] / length]


def lerp(a, b, t):
    return [a[i] + (b[i] - a[i]) * t for i in range(len(a))]


def rnd(values, digits=6):
    """Rounds floats for JSON so the text is short and stable."""
    return [round(float(v), digits) + 0.0 for v in values]


def rotate_y(p, degrees):
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return [c * p[0] + s * p[2], p[1], -s * p[0] + c * p[2]]


def quat_look_at(eye, target, up=(0.0, 1.0, 0.0)):
    """Unit quaternion [x, y, z, w] (glTF order) of a camera at `eye` that
    looks at `target`; glTF cameras look down their local -z."""
    back = normalize(sub(eye, target))
    right = normalize(cross(list(up), back))
    up2 = cross(back, right)
    # Rotation matrix with columns right, up2, back -> quaternion (Shepperd).
    m = [[right[0], up2[0], back[0]], [right[1], up2[1], back[1]], [right[2], up2[2], back[2]]]
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = [(m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, 0.25 * s]
    elif m[0][0] > m[1][1] and m[0][0] > m[2][2]:
        s = math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2]) * 2
        q = [0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s, (m[2][1] - m[1][2]) / s]
    elif m[1][1] > m[2][2]:
        s = math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2]) * 2
        q = [(m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s, (m[0][2] - m[2][0]) / s]
    else:
        s = math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1]) * 2
        q = [(m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s, (m[1][0] - m[0][1]) / s]
    if q[3] < 0:  # one hemisphere, so LINEAR interpolation between keys is short
        q = [-v for v in q]
    return q


# --------------------------------------------------------------------------
# Meshes: (positions, normals, uvs, indices), flat lists of 3-/2-tuples


def quad(p0, p1, p2, p3, uv_scale=1.0):
    """Quad p0 p1 p2 p3 (counter-clockwise seen from the front side)."""
    n = normalize(cross(sub(p1, p0), sub(p3, p0)))
    uvs = [[0, uv_scale], [uv_scale, uv_scale], [uv_scale, 0], [0, 0]]
    return [p0, p1, p2, p3], [n] * 4, uvs, [0, 1, 2, 0, 2, 3]


def merge(*meshes):
    pos, nrm, uv, idx = [], [], [], []
    for p, n, t, i in meshes:
        base = len(pos)
        pos += p
        nrm += n
        uv += t
        idx += [base + k for k in i]
    return pos, nrm, uv, idx


def box(center, size, angle_y=0.0, bottom=True):
    """Axis-aligned box of `size` rotated about +y by angle_y degrees, outward
    normals, one flat-shaded quad per face with its own 0..1 uvs."""
    hx, hy, hz = size[0] / 2, size[1] / 2, size[2] / 2

    def corner(sx, sy, sz):
        return add(center, rotate_y([sx * hx, sy * hy, sz * hz], angle_y))

    faces = [
        ((-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)),  # +z
        ((1, -1, -1), (-1, -1, -1), (-1, 1, -1), (1, 1, -1)),  # -z
        ((1, -1, 1), (1, -1, -1), (1, 1, -1), (1, 1, 1)),  # +x
        ((-1, -1, -1), (-1, -1, 1), (-1, 1, 1), (-1, 1, -1)),  # -x
        ((-1, 1, 1), (1, 1, 1), (1, 1, -1), (-1, 1, -1)),  # +y
    ]
    if bottom:
        faces.append(((-1, -1, -1), (1, -1, -1), (1, -1, 1), (-1, -1, 1)))  # -y
    return merge(*[quad(*[corner(*c) for c in f]) for f in faces])


def icosphere(subdivisions):
    """Unit icosphere, smooth normals (= positions), spherical uvs."""
    t = (1.0 + math.sqrt(5.0)) / 2.0
    verts = [normalize(v) for v in [
        [-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
        [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
             (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
             (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(subdivisions):
        cache = {}

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                cache[key] = len(verts)
                verts.append(normalize(scale(add(verts[a], verts[b]), 0.5)))
            return cache[key]

        new_faces = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new_faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new_faces
    uvs = [[0.5 + math.atan2(v[0], v[2]) / (2 * math.pi), math.acos(max(-1, min(1, v[1]))) / math.pi]
           for v in verts]
    return verts, list(verts), uvs, [i for f in faces for i in f]


# --------------------------------------------------------------------------
# PNG (8-bit RGB, no interlace): what stb_image and every viewer read


def write_png(path, width, height, pixel):
    """pixel(x, y) -> (r, g, b) in 0..255; y = 0 is the top row."""
    raw = bytearray()
    for y in range(height):
        raw.append(0)  # filter type None
        for x in range(width):
            raw += bytes(pixel(x, y))

    def chunk(tag, data):
        body = tag + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n"
    png += chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(bytes(raw), 9))
    png += chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


# --------------------------------------------------------------------------
# glTF writer


class Gltf:
    def __init__(self):
        self.bin = bytearray()
        self.doc = {"asset": {"version": "2.0", "generator": "dofarm make_scenes.py"},
                    "scene": 0, "scenes": [{"nodes": []}], "nodes": [], "meshes": [],
                    "materials": [], "accessors": [], "bufferViews": []}
        self.extensions = set()

    def _view(self, data, target=None):
        while len(self.bin) % 4:
            self.bin.append(0)
        view = {"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data)}
        if target:
            view["target"] = target
        self.bin += data
        self.doc["bufferViews"].append(view)
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, values, kind, component=5126, target=34962, minmax=False):
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[kind]
        flat = [v for item in values for v in (item if width > 1 else [item])]
        fmt = "<%d%s" % (len(flat), "f" if component == 5126 else "I")
        acc = {"bufferView": self._view(struct.pack(fmt, *flat), target), "componentType": component,
               "count": len(values), "type": kind}
        if minmax:
            cols = [[item[i] if width > 1 else item for item in values] for i in range(width)]
            # Bounds of the float32 values actually stored, as the spec asks.
            f32 = lambda v: struct.unpack("<f", struct.pack("<f", v))[0]
            acc["min"] = [f32(min(c)) for c in cols]
            acc["max"] = [f32(max(c)) for c in cols]
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def geometry(self, mesh):
        """Stores a mesh's vertex data once; returns attributes + indices that
        several glTF meshes (different materials) may share."""
        pos, nrm, uv, idx = mesh
        attributes = {"POSITION": self.accessor(pos, "VEC3", minmax=True),
                      "NORMAL": self.accessor(nrm, "VEC3")}
        if uv:
            attributes["TEXCOORD_0"] = self.accessor(uv, "VEC2")
        return attributes, self.accessor(idx, "SCALAR", 5125, 34963)

    def material(self, name, base=(0.8, 0.8, 0.8), metallic=0.0, roughness=0.5, emission=None,
                 ior=None, base_tex=None, mr_tex=None):
        pbr = {"baseColorFactor": rnd(list(base) + [1.0]), "metallicFactor": metallic,
               "roughnessFactor": roughness}
        if base_tex is not None:
            pbr["baseColorTexture"] = {"index": base_tex}
        if mr_tex is not None:
            pbr["metallicRoughnessTexture"] = {"index": mr_tex}
        mat = {"name": name, "pbrMetallicRoughness": pbr}
        ext = {}
        if emission:
            strength = max(emission)
            mat["emissiveFactor"] = rnd([e / strength for e in emission])
            if strength != 1.0:
                ext["KHR_materials_emissive_strength"] = {"emissiveStrength": strength}
        if ior is not None:
            ext["KHR_materials_ior"] = {"ior": ior}
        if ext:
            mat["extensions"] = ext
            self.extensions.update(ext)
        self.doc["materials"].append(mat)
        return len(self.doc["materials"]) - 1

    def texture(self, uri):
        self.doc.setdefault("samplers", [{"magFilter": 9729, "minFilter": 9729,
                                          "wrapS": 10497, "wrapT": 10497}])
        images = self.doc.setdefault("images", [])
        images.append({"uri": uri})
        textures = self.doc.setdefault("textures", [])
        textures.append({"sampler": 0, "source": len(images) - 1})
        return len(textures) - 1

    def mesh(self, name, geometry, material, mode=None):
        attributes, indices = geometry
        prim = {"attributes": attributes, "indices": indices, "material": material}
        if mode is not None:
            prim["mode"] = mode
        self.doc["meshes"].append({"name": name, "primitives": [prim]})
        return len(self.doc["meshes"]) - 1

    def node(self, name, mesh=None, translation=None, rotation=None, scale_=None, camera=None,
             children=None, root=True):
        node = {"name": name}
        for key, value in (("mesh", mesh), ("camera", camera), ("children", children)):
            if value is not None:
                node[key] = value
        if translation is not None:
            node["translation"] = rnd(translation)
        if rotation is not None:
            node["rotation"] = rnd(rotation)
        if scale_ is not None:
            node["scale"] = rnd(scale_)
        self.doc["nodes"].append(node)
        index = len(self.doc["nodes"]) - 1
        if root:
            self.doc["scenes"][0]["nodes"].append(index)
        return index

    def object(self, name, geometry, material, mode=None, **node_args):
        return self.node(name, mesh=self.mesh(name, geometry, material, mode), **node_args)

    def write(self, path, embed=False):
        doc = dict(self.doc)
        if self.extensions:
            doc["extensionsUsed"] = sorted(self.extensions)
        if embed:
            uri = "data:application/octet-stream;base64," + base64.b64encode(self.bin).decode()
        else:
            uri = os.path.splitext(os.path.basename(path))[0] + ".bin"
            with open(os.path.join(os.path.dirname(path), uri), "wb") as f:
                f.write(self.bin)
        doc["buffers"] = [{"byteLength": len(self.bin), "uri": uri}]
        with open(path, "w") as f:
            json.dump(doc, f, indent=1)
            f.write("\n")


# --------------------------------------------------------------------------
# Cornell box

# Radiance of the ceiling light: the warm white of the classic scene.
CORNELL_LIGHT = (17.0, 12.0, 4.0)


def make_cornell(path):
    g = Gltf()
    white = g.material("white", base=(0.73, 0.73, 0.73), roughness=1.0)
    red = g.material("red", base=(0.65, 0.05, 0.05), roughness=1.0)
    green = g.material("green", base=(0.12, 0.45, 0.15), roughness=1.0)
    light = g.material("light", base=(0.78, 0.78, 0.78), roughness=1.0, emission=CORNELL_LIGHT)
    metal = g.material("glossy_metal", base=(0.95, 0.64, 0.54), metallic=1.0, roughness=0.2)
    plastic = g.material("rough_dielectric", base=(0.2, 0.3, 0.8), roughness=0.35, ior=1.46)

    # Walls face into the box. The front (z = +1) is open.
    walls = [
        ("floor", white, quad([-1, 0, 1], [1, 0, 1], [1, 0, -1], [-1, 0, -1])),
        ("ceiling", white, quad([-1, 2, -1], [1, 2, -1], [1, 2, 1], [-1, 2, 1])),
        ("back_wall", white, quad([-1, 0, -1], [1, 0, -1], [1, 2, -1], [-1, 2, -1])),
        ("left_wall", red, quad([-1, 0, 1], [-1, 0, -1], [-1, 2, -1], [-1, 2, 1])),
        ("right_wall", green, quad([1, 0, -1], [1, 0, 1], [1, 2, 1], [1, 2, -1])),
    ]
    for name, mat, mesh in walls:
        g.object(name, g.geometry(mesh), mat)
    # The light: 0.47 x 0.38 like the classic 130 x 105 of 556, just below the
    # ceiling so it does not z-fight with it, normal -y.
    ly = 1.998
    g.object("light", g.geometry(quad([-0.235, ly, -0.19], [0.235, ly, -0.19], [0.235, ly, 0.19],
                                      [-0.235, ly, 0.19])), light)
    g.object("tall_box", g.geometry(box([-0.33, 0.6, -0.28], [0.6, 1.2, 0.6], 17.0, bottom=False)),
             white)
    g.object("short_box", g.geometry(box([0.33, 0.3, 0.33], [0.6, 0.6, 0.6], -18.0, bottom=False)),
             white)
    # One sphere mesh, placed by node transforms (exercises the loader's
    # hierarchy flattening): metal on the short box, dielectric on the floor.
    sphere = g.geometry(icosphere(3))
    g.object("metal_sphere", sphere, metal, translation=[0.33, 0.85, 0.33], scale_=[0.25] * 3)
    g.object("dielectric_sphere", sphere, plastic, translation=[-0.55, 0.2, 0.55],
             scale_=[0.2] * 3)
    g.write(path)


# --------------------------------------------------------------------------
# Courtyard

CHECKER_SIZE = (64, 64)
MR_SIZE = (32, 16)
FPS = 24.0
# The camera rig (static parent) and the animated camera node under it.
RIG_OFFSET = [0.0, 0.2, 0.0]
CAM_TRANSLATION_KEYS = [(0.0, [0.0, 1.0, 6.0]), (1.0, [1.0, 0.8, 4.5]), (2.0, [1.8, 0.7, 3.2])]
CAM_TARGET_START, CAM_TARGET_END = [0.0, 0.6, -1.0], [-0.6, 0.6, -3.0]
CAM_ROTATION_TIMES = [0.0, 0.5, 1.5, 2.0]
CAM_YFOV_DEG = 45.0
CAM_ASPECT = 16.0 / 9.0


def cam_local_position(t):
    keys = CAM_TRANSLATION_KEYS
    for (t0, p0), (t1, p1) in zip(keys, keys[1:]):
        if t <= t1:
            return lerp(p0, p1, (t - t0) / (t1 - t0))
    return keys[-1][1]


def make_courtyard(folder):
    write_png(os.path.join(folder, "courtyard_checker.png"), *CHECKER_SIZE,
              lambda x, y: (200, 190, 170) if ((x // 8) + (y // 8)) % 2 == 0 else (70, 66, 60))
    # glTF metallic-roughness texture (linear): G = roughness, B = metallic.
    # Stripes of roughness 0.25 and 0.75 with a smooth ramp between them.
    def mr(x, y):
        rough = 0.25 + 0.5 * (0.5 - 0.5 * math.cos(2 * math.pi * x / MR_SIZE[0]))
        return (0, int(round(rough * 255)), 0)

    write_png(os.path.join(folder, "courtyard_plastic_mr.png"), *MR_SIZE, mr)

    g = Gltf()
    checker = g.texture("courtyard_checker.png")
    plastic_mr = g.texture("courtyard_plastic_mr.png")
    ground = g.material("ground_tiles", base=(1, 1, 1), roughness=0.9, base_tex=checker)
    brushed = g.material("brushed_metal", base=(0.91, 0.92, 0.92), metallic=1.0, roughness=0.3)
    polished = g.material("polished_metal", base=(0.95, 0.93, 0.88), metallic=1.0, roughness=0.05)
    red_plastic = g.material("red_plastic", base=(0.7, 0.08, 0.06), metallic=1.0, roughness=1.0,
                             mr_tex=plastic_mr)
    blue_plastic = g.material("blue_plastic", base=(0.1, 0.2, 0.7), metallic=1.0, roughness=1.0,
                              mr_tex=plastic_mr)
    stone = g.material("stone", base=(0.55, 0.52, 0.48), roughness=0.8)
    lamp = g.material("lamp", base=(1, 1, 1), roughness=1.0, emission=(20.0, 12.0, 6.0))

    # 30 m x 30 m ground, checker repeated 15 times: 0.25 m tiles.
    g.object("ground", g.geometry(quad([-15, 0, 15], [15, 0, 15], [15, 0, -15], [-15, 0, -15],
                                       uv_scale=15.0)), ground)
    sphere = g.geometry(icosphere(3))
    # Depths from the first camera position (z = 6): 4 m to 16 m.
    g.object("brushed_pillar", g.geometry(box([-2.0, 1.0, -3.0], [0.8, 2.0, 0.8], 20.0)), brushed)
    g.object("polished_sphere", sphere, polished, translation=[1.2, 0.7, -1.0], scale_=[0.7] * 3)
    g.object("plastic_sphere", sphere, red_plastic, translation=[-0.8, 0.4, 1.5],
             scale_=[0.4] * 3)
    g.object("plastic_box", g.geometry(box([2.6, 0.5, -5.0], [1.0, 1.0, 1.0], -30.0)),
             blue_plastic)
    g.object("far_wall", g.geometry(box([0.0, 1.5, -10.0], [12.0, 3.0, 0.5])), stone)
    g.object("lamp", sphere, lamp, translation=[0.4, 0.15, 2.4], scale_=[0.15] * 3)

    g.doc["cameras"] = [{"name": "fly", "type": "perspective", "perspective": {
        "yfov": round(math.radians(CAM_YFOV_DEG), 6), "aspectRatio": round(CAM_ASPECT, 6),
        "znear": 0.05, "zfar": 100.0}}]
    first_rotation = quat_look_at(cam_local_position(0.0), CAM_TARGET_START)
    camera_node = g.node("camera", camera=0, translation=CAM_TRANSLATION_KEYS[0][1],
                         rotation=first_rotation, root=False)
    g.node("camera_rig", translation=RIG_OFFSET, children=[camera_node])

    end = CAM_ROTATION_TIMES[-1]
    rotations = []
    for t in CAM_ROTATION_TIMES:
        # The rig offset moves eye and target alike, so it does not change the
        # rotation.
        target = lerp(CAM_TARGET_START, CAM_TARGET_END, t / end)
        rotations.append(rnd(quat_look_at(cam_local_position(t), target)))
    t_in = g.accessor([k[0] for k in CAM_TRANSLATION_KEYS], "SCALAR", target=None, minmax=True)
    t_out = g.accessor([rnd(k[1]) for k in CAM_TRANSLATION_KEYS], "VEC3", target=None)
    r_in = g.accessor(CAM_ROTATION_TIMES, "SCALAR", target=None, minmax=True)
    r_out = g.accessor(rotations, "VEC4", target=None)
    g.doc["animations"] = [{"name": "fly_through", "samplers": [
        {"input": t_in, "output": t_out, "interpolation": "LINEAR"},
        {"input": r_in, "output": r_out, "interpolation": "LINEAR"}], "channels": [
        {"sampler": 0, "target": {"node": camera_node, "path": "translation"}},
        {"sampler": 1, "target": {"node": camera_node, "path": "rotation"}}]}]
    g.write(os.path.join(folder, "courtyard.gltf"))


# --------------------------------------------------------------------------
# Analytic test scenes (small: the buffer is embedded as base64)


def make_test_scenes(folder):
    os.makedirs(folder, exist_ok=True)

    # White furnace: a unit sphere at the origin, base colour 1, no metal. Lit
    # by a constant environment its diffuse part returns exactly the
    # environment radiance.
    g = Gltf()
    mat = g.material("white", base=(1, 1, 1), roughness=1.0)
    g.object("sphere", g.geometry(icosphere(4)), mat)
    g.write(os.path.join(folder, "furnace_sphere.gltf"), embed=True)

    # A 20 x 20 plane at z = -2 facing +z: a camera at the origin looking down
    # -z sees depth exactly 2 everywhere within 78 degrees of field of view.
    g = Gltf()
    mat = g.material("grey", base=(0.5, 0.5, 0.5), roughness=1.0)
    g.object("plane", g.geometry(quad([-10, -10, -2], [10, -10, -2], [10, 10, -2], [-10, 10, -2])),
             mat)
    g.write(os.path.join(folder, "plane_at_distance.gltf"), embed=True)

    # Closed box [-1, 1]^3 with a 0.5 x 0.5 light facing down at y = 0.99:
    # no light escapes, no environment is needed. Walls have inward normals.
    g = Gltf()
    wall = g.material("wall", base=(0.5, 0.5, 0.5), roughness=1.0)
    light = g.material("light", base=(0, 0, 0), roughness=1.0, emission=(10.0, 10.0, 10.0))
    pos, nrm, uv, idx = box([0, 0, 0], [2, 2, 2])
    idx = [i for t in range(0, len(idx), 3) for i in (idx[t], idx[t + 2], idx[t + 1])]
    g.object("walls", g.geometry((pos, [scale(n, -1) for n in nrm], uv, idx)), wall)
    g.object("light", g.geometry(quad([-0.25, 0.99, -0.25], [0.25, 0.99, -0.25],
                                      [0.25, 0.99, 0.25], [-0.25, 0.99, 0.25])), light)
    g.write(os.path.join(folder, "light_box.gltf"), embed=True)

    # A valid quad plus degenerate triangles the renderer must survive: zero
    # area (collinear), a repeated index, and a sliver.
    g = Gltf()
    mat = g.material("grey", base=(0.5, 0.5, 0.5), roughness=0.5)
    pos = [[-1, -1, -2], [1, -1, -2], [1, 1, -2], [-1, 1, -2],
           [-0.5, 0, -1.5], [0, 0, -1.5], [0.5, 0, -1.5],  # collinear
           [0, 0.5, -1.5], [1e-7, 0.5, -1.5], [0, -0.5, -1.5]]  # sliver
    nrm = [[0, 0, 1]] * len(pos)
    uv = [[0, 0]] * len(pos)
    idx = [0, 1, 2, 0, 2, 3, 4, 5, 6, 5, 5, 6, 7, 8, 9]
    g.object("degenerate", g.geometry((pos, nrm, uv, idx)), mat)
    g.write(os.path.join(folder, "degenerate.gltf"), embed=True)

    # Lines only: a file that loads but has no triangles (a loader error).
    g = Gltf()
    mat = g.material("grey")
    g.object("lines", g.geometry(([[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 1]] * 3, [],
                                  [0, 1, 1, 2])), mat, mode=1)
    g.write(os.path.join(folder, "no_triangles.gltf"), embed=True)

    # A triangle with a NaN vertex (a loader error, never a silent hole).
    g = Gltf()
    mat = g.material("grey")
    nan = float("nan")
    geometry = g.geometry(([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1]] * 3, [], [0, 1, 2]))
    g.object("nan", geometry, mat)
    g.bin[0:4] = struct.pack("<f", nan)  # first x, after min/max were taken
    g.write(os.path.join(folder, "nan_vertex.gltf"), embed=True)


if __name__ == "__main__":
    make_cornell(os.path.join(HERE, "cornell.gltf"))
    make_courtyard(HERE)
    make_test_scenes(os.path.join(HERE, "test"))
