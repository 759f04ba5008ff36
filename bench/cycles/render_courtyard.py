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
import sys

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cycles_common  # noqa: E402


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
    cycles_common.patch_numpy()
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

    cycles_common.configure_cycles(scene, args.width, args.height, args.threads,
                                   args.max_bounces)
    return scene


def main():
    args = parse_args()
    scene = setup(args)
    cycles_common.render_series(scene, [int(s) for s in args.spp.split(",")], args.seed,
                                args.out, args.width, args.height, args.perf_ctl)


main()
