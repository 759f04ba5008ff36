# Blender script for bench/cycles/normal_map_vs_cycles.sh: a 4 m plane whose
# Principled BSDF takes its normal from a tangent-space normal map (Image
# Texture, Non-Color -> Normal Map node, the setup Blender's glTF exporter
# writes as normalTexture), lit by a sun from the side, seen from above.
# The map is made here from a height field of bumps that vary along both
# image axes, so a frame oriented wrongly in either axis shows. Exports the
# scene as glTF (Punctual Lights on) and renders it with Cycles into a PFM.
#
#   blender -b -noaudio --factory-startup -P normal_map_plane.py -- OUT_DIR SPP
#   -> OUT_DIR/plane.gltf (+ .bin, bumps.png), OUT_DIR/cycles.pfm (SIZE^2, linear RGB)
import math
import os
import struct
import sys

import bpy

SIZE = 96
MAP = 128  # normal map texels per side


def normal_map(path):
    # h = sin(2 pi 2 x) * sin(2 pi 3 y) over the unit square (x right, y up,
    # as Blender's pixels: row 0 at the bottom); n = (-dh/dx, -dh/dy, 1) with a
    # slope scale, stored as (n + 1) / 2 (OpenGL convention: green is up).
    img = bpy.data.images.new("bumps", MAP, MAP, alpha=False)
    # Before the pixels: changing a generated image's colour space
    # regenerates it (black).
    img.colorspace_settings.name = "Non-Color"
    px = [0.0] * (MAP * MAP * 4)
    a = 0.08
    for j in range(MAP):
        y = (j + 0.5) / MAP
        for i in range(MAP):
            x = (i + 0.5) / MAP
            dx = a * 2 * math.pi * 2 * math.cos(2 * math.pi * 2 * x) * math.sin(2 * math.pi * 3 * y)
            dy = a * 2 * math.pi * 3 * math.sin(2 * math.pi * 2 * x) * math.cos(2 * math.pi * 3 * y)
            n = (-dx, -dy, 1.0)
            l = math.sqrt(sum(c * c for c in n))
            k = 4 * (j * MAP + i)
            px[k:k + 4] = [(n[0] / l + 1) / 2, (n[1] / l + 1) / 2, (n[2] / l + 1) / 2, 1.0]
    img.pixels = px
    img.filepath_raw = path
    img.file_format = "PNG"
    img.save()
    return img


def main():
    argv = sys.argv[sys.argv.index("--") + 1:]
    if len(argv) != 2:
        raise SystemExit("usage: normal_map_plane.py -- OUT_DIR SPP")
    out, spp = argv[0], int(argv[1])
    os.makedirs(out, exist_ok=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene

    bpy.ops.mesh.primitive_plane_add(size=4.0)
    plane = bpy.context.active_object
    mat = bpy.data.materials.new("bumpy")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    p = nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (0.7, 0.7, 0.7, 1.0)
    p.inputs["Roughness"].default_value = 1.0
    p.inputs["Specular"].default_value = 0.0
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = normal_map(os.path.join(out, "bumps.png"))
    nmap = nodes.new("ShaderNodeNormalMap")
    nmap.space = "TANGENT"
    links.new(tex.outputs["Color"], nmap.inputs["Color"])
    links.new(nmap.outputs["Normal"], p.inputs["Normal"])
    plane.data.materials.append(mat)

    sun_data = bpy.data.lights.new("sun", type="SUN")
    sun_data.energy = 3.0
    sun_data.angle = 0.0
    sun = bpy.data.objects.new("sun", sun_data)
    # Light from +x, +y and above: tilts towards either image axis show.
    sun.rotation_euler = (math.radians(-50.0), math.radians(35.0), 0.0)
    scene.collection.objects.link(sun)

    cam_data = bpy.data.cameras.new("camera")
    cam = bpy.data.objects.new("camera", cam_data)
    cam.location = (0.0, 0.0, 5.0)
    scene.collection.objects.link(cam)
    scene.camera = cam

    scene.world = bpy.data.worlds.new("black")
    scene.world.use_nodes = False
    scene.world.color = (0.0, 0.0, 0.0)
    scene.render.engine = "CYCLES"
    scene.render.resolution_x = SIZE
    scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    c = scene.cycles
    c.device = "CPU"
    c.samples = spp
    c.use_denoising = False
    c.use_adaptive_sampling = False
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    c.max_bounces = 8

    bpy.ops.export_scene.gltf(filepath=os.path.join(out, "plane.gltf"),
                              export_format="GLTF_SEPARATE", export_lights=True,
                              export_cameras=True)

    exr = os.path.join(out, "cycles.exr")
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = exr
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(exr)
    px = list(img.pixels)  # RGBA, rows bottom-up, as PFM
    rgb = [0.0] * (SIZE * SIZE * 3)
    for k in range(3):
        rgb[k::3] = px[k::4]
    with open(os.path.join(out, "cycles.pfm"), "wb") as f:
        f.write(b"PF\n%d %d\n-1.0\n" % (SIZE, SIZE))
        f.write(struct.pack("<%df" % len(rgb), *rgb))


main()
