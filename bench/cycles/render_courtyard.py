# Renders a frame of dofarm's courtyard (jobs/courtyard.toml: the glTF scene,
# its animated camera, the HDRI) with Blender Cycles at several sample
# counts, for bench/cycles/embree_share.sh. Blender is a benchmark tool here,
# never a dependency of dofarm.
#
#   blender -b -noaudio --factory-startup --python bench/cycles/render_courtyard.py -- \
#       --gltf jobs/scenes/courtyard.gltf --hdri jobs/assets/hdri/courtyard.exr \
#       --out PREFIX --spp 16,64 [--frame 24] [--width 640 --height 360] \
#       [--focus 3.4] [--aperture 0.08] [--threads 2] [--perf-ctl FIFO]
#
# The camera is the file's own, posed at --frame (Blender's glTF importer
# keys the node at frame = time * fps, dofarm's frame numbering at the
# job's 24 fps); --focus and --aperture are the lens of jobs/courtyard.toml
# at that frame (focal distance, lens radius in scene units). The HDRI is
# the world, at strength 1, turned so that Blender's equirectangular lookup
# reads the texel dofarm's does (dofarm: u = atan2(x, -z) / 2pi + 0.5 in
# glTF axes, worker/render/environment.cpp; Blender: u = -atan2(y, x) / 2pi
# + 0.5 in its z-up axes, which the importer maps from glTF as (x, -z, y);
# the two differ by a quarter turn about the vertical).
#
# Settings as bench/cycles/render_cornell.py: no denoising, no adaptive
# sampling, box filter one pixel wide, no clamping, no glossy blur, caustics
# on, one tile, a fixed number of threads, 15 bounces.
#
# --perf-ctl FIFO: writes "enable" to perf's control FIFO before each timed
# render and "disable" after it (perf record --delay=-1 --control=fifo:FIFO),
# so a profile holds the renders only, not Blender's start-up or the import.
#
# Writes PREFIX<N>.pfm (linear RGB, rows bottom-up) and prints one line per
# render: "spp N cpu_s C wall_s W". A warm-up render at 1 spp runs first
# (untimed, not profiled).
import argparse
import math
import os
import struct
import sys
import time

import bpy


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="render_courtyard.py")
    p.add_argument("--gltf", required=True)
    p.add_argument("--hdri", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--spp", required=True)
    p.add_argument("--frame", type=int, default=24)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=360)
    p.add_argument("--focus", type=float, default=3.4)
    p.add_argument("--aperture", type=float, default=0.08)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-bounces", type=int, default=15)
    p.add_argument("--perf-ctl", default="")
    return p.parse_args(argv)


def setup(args):
    # Blender 3.4's glTF importer uses np.bool, which numpy >= 1.24 no longer has.
    import numpy
    if not hasattr(numpy, "bool") or numpy.bool is not bool:
        try:
            numpy.bool = bool
        except AttributeError:
            pass
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=os.path.abspath(args.gltf))
    scene = bpy.context.scene
    cameras = [o for o in scene.objects if o.type == "CAMERA"]
    if not cameras:
        raise SystemExit("%s: no camera" % args.gltf)
    cam = cameras[0]
    scene.camera = cam
    scene.render.fps = 24
    scene.frame_set(args.frame)
    cam.data.clip_start = 1e-3
    cam.data.clip_end = 1e4
    cam.data.dof.use_dof = args.aperture > 0
    cam.data.dof.focus_distance = args.focus
    if args.aperture > 0:
        # Cycles' aperture radius is focal length / (2 N).
        cam.data.dof.aperture_fstop = cam.data.lens * 1e-3 / (2.0 * args.aperture)
    cam.data.dof.aperture_blades = 0
    cam.data.dof.aperture_ratio = 1.0

    world = bpy.data.worlds.new("hdri")
    scene.world = world
    world.use_nodes = True
    tree = world.node_tree
    background = next(n for n in tree.nodes if n.type == "BACKGROUND")
    background.inputs["Strength"].default_value = 1.0
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(os.path.abspath(args.hdri))
    env.interpolation = "Closest"  # dofarm reads the texel, unfiltered
    coord = tree.nodes.new("ShaderNodeTexCoord")
    mapping = tree.nodes.new("ShaderNodeMapping")
    mapping.vector_type = "POINT"
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, -math.pi / 2)
    tree.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
    tree.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    tree.links.new(env.outputs["Color"], background.inputs["Color"])
    world.cycles.sampling_method = "MANUAL"
    world.cycles.sample_map_resolution = 1024  # the map's own width

    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x = args.width
    r.resolution_y = args.height
    r.resolution_percentage = 100
    r.threads_mode = "FIXED"
    r.threads = args.threads
    r.use_persistent_data = False
    r.film_transparent = False
    r.image_settings.file_format = "OPEN_EXR"
    r.image_settings.color_depth = "32"
    r.image_settings.exr_codec = "NONE"
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"

    c = scene.cycles
    c.device = "CPU"
    c.use_denoising = False
    c.use_adaptive_sampling = False
    c.use_auto_tile = False
    c.max_bounces = args.max_bounces
    c.diffuse_bounces = args.max_bounces
    c.glossy_bounces = args.max_bounces
    c.transmission_bounces = args.max_bounces
    c.volume_bounces = 0
    c.transparent_max_bounces = args.max_bounces
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.blur_glossy = 0.0
    c.caustics_reflective = True
    c.caustics_refractive = True
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    return scene


def write_pfm(path, exr_path, width, height):
    img = bpy.data.images.load(exr_path)
    px = list(img.pixels)  # RGBA floats, rows from the bottom up, as PFM
    bpy.data.images.remove(img)
    rgb = [0.0] * (width * height * 3)
    rgb[0::3] = px[0::4]
    rgb[1::3] = px[1::4]
    rgb[2::3] = px[2::4]
    with open(path, "wb") as f:
        f.write(b"PF\n%d %d\n-1.0\n" % (width, height))
        f.write(struct.pack("<%df" % len(rgb), *rgb))


def perf_control(path, command):
    if path:
        with open(path, "w") as f:
            f.write(command + "\n")


def render(scene, spp, args, profile):
    scene.cycles.samples = spp
    scene.cycles.seed = args.seed
    if profile:
        perf_control(args.perf_ctl, "enable")
    c0, w0 = time.process_time(), time.perf_counter()
    bpy.ops.render.render(write_still=False)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    if profile:
        perf_control(args.perf_ctl, "disable")
    return cpu, wall


def main():
    args = parse_args()
    scene = setup(args)
    render(scene, 1, args, False)  # warm-up: kernels, caches, the map's tables
    for spp in [int(s) for s in args.spp.split(",")]:
        cpu, wall = render(scene, spp, args, True)
        exr = os.path.abspath(args.out + "%d.exr" % spp)
        bpy.data.images["Render Result"].save_render(exr)
        write_pfm(args.out + "%d.pfm" % spp, exr, args.width, args.height)
        os.remove(exr)
        print("spp %d cpu_s %.3f wall_s %.3f" % (spp, cpu, wall), flush=True)


main()
