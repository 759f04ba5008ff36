# Blender script for bench/cycles/specular_vs_cycles.sh: a 4 m plane with a
# Principled BSDF of the given Specular and Specular Tint, lit by a 1000 W
# point lamp 2 m above its centre, seen from 5 m above; exports it as glTF
# (Punctual Lights on: Blender's exporter writes the Principled Specular as
# KHR_materials_specular) and renders it with Cycles into a PFM.
#
#   blender -b -noaudio --factory-startup -P specular_plane.py -- OUT_DIR SPECULAR TINT SPP
#   -> OUT_DIR/plane.gltf (+ .bin), OUT_DIR/cycles.pfm (64 x 64, linear RGB)
import os
import struct
import sys

import bpy

SIZE = 64


def main():
    argv = sys.argv[sys.argv.index("--") + 1:]
    if len(argv) != 4:
        raise SystemExit("usage: specular_plane.py -- OUT_DIR SPECULAR TINT SPP")
    out, specular, tint, spp = argv[0], float(argv[1]), float(argv[2]), int(argv[3])
    os.makedirs(out, exist_ok=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene

    bpy.ops.mesh.primitive_plane_add(size=4.0)
    plane = bpy.context.active_object
    mat = bpy.data.materials.new("plane")
    mat.use_nodes = True
    p = mat.node_tree.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (0.8, 0.4, 0.2, 1.0)
    p.inputs["Roughness"].default_value = 0.5
    p.inputs["Specular"].default_value = specular
    p.inputs["Specular Tint"].default_value = tint
    plane.data.materials.append(mat)

    lamp_data = bpy.data.lights.new("lamp", type="POINT")
    lamp_data.energy = 1000.0
    lamp_data.shadow_soft_size = 0.0
    lamp = bpy.data.objects.new("lamp", lamp_data)
    lamp.location = (0.0, 0.0, 2.0)
    scene.collection.objects.link(lamp)

    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    cam.location = (0.0, 0.0, 5.0)  # looks down its -z: at the plane
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
