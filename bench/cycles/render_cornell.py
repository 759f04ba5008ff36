# Renders dofarm's Cornell box with Blender Cycles at several sample counts,
# for bench/cycles_vs_dofarm.sh. Blender is a benchmark tool here, never a
# dependency of dofarm.
#
#   blender -b --factory-startup --python bench/cycles/render_cornell.py -- \
#       --gltf jobs/scenes/cornell.gltf --out PREFIX --spp 16,32,64 [--seed 0] \
#       [--threads 2] [--size 256] [--position 0.15 1.02 3.75] \
#       [--look-at 0 1 0] [--fov 38] [--focus 4.9] [--aperture 0.0261379] \
#       [--max-bounces 15] [--blender-clamp] [--lambert] [--perf-ctl FIFO]
#
# Camera values are in glTF coordinates (+y up) and dofarm's units, as in
# bench/cycles/cornell_dof.toml: --fov is the vertical field of view in
# degrees, --aperture the lens radius, --focus the distance of the focal
# plane along the viewing axis (dofarm's focal_distance; Blender's focus
# distance is measured the same way).
#
# Settings chosen to match dofarm's renderer: no denoising, no adaptive
# sampling, box pixel filter 1 pixel wide, no clamping, no glossy blur (with
# --blender-clamp: Blender's defaults, indirect clamp 10 and filter glossy 1),
# caustics on, one tile for the whole image, a fixed number of threads.
# dofarm's max_depth counts surface interactions after the camera; its last
# one only adds emission, so max_depth D traces the light paths of
# Cycles' max_bounces D - 1 (direct light is bounce 0 in Cycles).
#
# --perf-ctl FIFO: "enable" / "disable" to perf's control FIFO around each
# timed render, as in bench/cycles/render_courtyard.py.
#
# Writes PREFIX<N>.pfm (linear RGB, rows bottom-up) and prints one line per
# render: "spp N cpu_s C wall_s W". The times are of bpy.ops.render.render(),
# after a warm-up render at 1 spp (untimed); scene import is not counted, the
# scene sync and BVH build of each render are (about 0.01 s here, under 1% of
# the 16 spp render).
import argparse
import math
import os
import sys

import bpy
from mathutils import Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cycles_common  # noqa: E402


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="render_cornell.py")
    p.add_argument("--gltf", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--spp", required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--position", type=float, nargs=3, default=[0.15, 1.02, 3.75])
    p.add_argument("--look-at", type=float, nargs=3, default=[0.0, 1.0, 0.0])
    p.add_argument("--fov", type=float, default=38.0)
    p.add_argument("--focus", type=float, default=4.9)
    p.add_argument("--aperture", type=float, default=0.0261379)
    p.add_argument("--max-bounces", type=int, default=15)
    # Blender's defaults for clamping (indirect 10) and filter glossy (1.0):
    # less noise, but biased; what a Blender user renders with.
    p.add_argument("--blender-clamp", action="store_true")
    # Every material as Lambert (Diffuse BSDF, roughness 0) with the base
    # colour the importer read, plus its emission: the model dofarm renders
    # for a glTF material with IOR 1 (bench/README.md, "matched materials").
    p.add_argument("--lambert", action="store_true")
    p.add_argument("--perf-ctl", default="")
    return p.parse_args(argv)


def gltf_to_blender(v):
    # The glTF importer turns +y up into Blender's +z up: (x, y, z) -> (x, -z, y).
    return Vector((v[0], -v[2], v[1]))


def make_lambert(material):
    """Replaces the importer's Principled BSDF by Diffuse BSDF + Emission.

    Blender 3.4's Principled BSDF is not Lambert even at specular 0: its
    diffuse part is Disney's, with a retro-reflection term that depends on
    roughness. The Diffuse BSDF at roughness 0 is exactly Lambert (Cycles
    uses its Lambert closure, not Oren-Nayar, at roughness 0)."""
    tree = material.node_tree
    principled = next(n for n in tree.nodes if n.type == "BSDF_PRINCIPLED")
    output = next(n for n in tree.nodes if n.type == "OUTPUT_MATERIAL")
    for name in ("Base Color", "Emission", "Emission Strength"):
        if principled.inputs[name].is_linked:
            raise SystemExit("%s: %s is textured; --lambert takes constant materials only"
                             % (material.name, name))
    base = principled.inputs["Base Color"].default_value
    emission = principled.inputs["Emission"].default_value
    strength = principled.inputs["Emission Strength"].default_value
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = base
    diffuse.inputs["Roughness"].default_value = 0.0
    shader = diffuse.outputs["BSDF"]
    if strength > 0 and max(emission[:3]) > 0:
        emit = tree.nodes.new("ShaderNodeEmission")
        emit.inputs["Color"].default_value = emission
        emit.inputs["Strength"].default_value = strength
        add = tree.nodes.new("ShaderNodeAddShader")
        tree.links.new(diffuse.outputs["BSDF"], add.inputs[0])
        tree.links.new(emit.outputs["Emission"], add.inputs[1])
        shader = add.outputs["Shader"]
    tree.nodes.remove(principled)
    tree.links.new(shader, output.inputs["Surface"])


def setup(args):
    cycles_common.patch_numpy()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=os.path.abspath(args.gltf))
    scene = bpy.context.scene
    if args.lambert:
        for material in bpy.data.materials:
            if material.use_nodes:
                make_lambert(material)

    # Camera: vertical fit on a 36 mm sensor, so lens = 18 mm / tan(fov / 2)
    # and Cycles' aperture radius lens / (2 N) equals --aperture.
    cam_data = bpy.data.cameras.new("bench_camera")
    cam_data.sensor_fit = "VERTICAL"
    cam_data.sensor_height = 36.0
    cam_data.lens = 18.0 / math.tan(math.radians(args.fov) / 2)
    cam_data.clip_start = 1e-3
    cam_data.clip_end = 1e4
    cam_data.dof.use_dof = args.aperture > 0
    cam_data.dof.focus_distance = args.focus
    if args.aperture > 0:
        cam_data.dof.aperture_fstop = cam_data.lens * 1e-3 / (2.0 * args.aperture)
    cam_data.dof.aperture_blades = 0  # a disk, as dofarm's concentric mapping
    cam_data.dof.aperture_ratio = 1.0
    cam = bpy.data.objects.new("bench_camera", cam_data)
    scene.collection.objects.link(cam)
    pos = gltf_to_blender(args.position)
    target = gltf_to_blender(args.look_at)
    cam.location = pos
    # Blender cameras look down local -z with local +y up; world up is +z.
    cam.rotation_mode = "QUATERNION"
    cam.rotation_quaternion = (target - pos).to_track_quat("-Z", "Y")
    scene.camera = cam

    cycles_common.configure_cycles(scene, args.size, args.size, args.threads, args.max_bounces,
                                   args.blender_clamp)
    # No world light: dofarm renders the Cornell box without an environment.
    if scene.world is None:
        scene.world = bpy.data.worlds.new("black")
    scene.world.use_nodes = False
    scene.world.color = (0.0, 0.0, 0.0)
    return scene


def main():
    args = parse_args()
    scene = setup(args)
    cycles_common.render_series(scene, [int(x) for x in args.spp.split(",")], args.seed,
                                args.out, args.size, args.size, args.perf_ctl)


main()
