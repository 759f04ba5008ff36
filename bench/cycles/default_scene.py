# Blender's start-up scene (the cube, its lamp, its camera and its World,
# nothing changed), exported as Blender's glTF exporter does by default
# (a .glb) with Include > Cameras and Include > Punctual Lights ticked
# (Blender 3.4 leaves both off: without them the file has neither the
# camera nor the lamp), and rendered with Cycles, for
# bench/cycles/default_scene_vs_cycles.sh.
# Blender is a benchmark tool here, never a dependency of dofarm.
#
#   blender -b -noaudio --factory-startup -P bench/cycles/default_scene.py -- OUT_DIR SPP WIDTH HEIGHT [SPECULAR]
#   (SPECULAR: the cube material's Specular instead of its 0.5, to tell the
#   material models apart: at 0 both renderers' cube is diffuse alone)
#   -> OUT_DIR/scene.glb, OUT_DIR/cycles<SPP>.pfm (linear RGB, rows bottom-up)
#
# Cycles is set as in bench/cycles/cycles_common.py (no denoising, no
# adaptive sampling, box filter, no clamping, 15 bounces, 2 threads); the
# scene itself, the World included, is the start-up file's.
import os
import sys

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cycles_common  # noqa: E402


def main():
    argv = sys.argv[sys.argv.index("--") + 1:]
    if len(argv) not in (4, 5):
        raise SystemExit("usage: default_scene.py -- OUT_DIR SPP WIDTH HEIGHT [SPECULAR]")
    out, spp, width, height = argv[0], int(argv[1]), int(argv[2]), int(argv[3])
    if len(argv) == 5:
        material = bpy.data.materials["Material"]
        principled = next(n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
        principled.inputs["Specular"].default_value = float(argv[4])
    os.makedirs(out, exist_ok=True)
    cycles_common.patch_numpy()
    scene = bpy.context.scene
    bpy.ops.export_scene.gltf(filepath=os.path.join(out, "scene.glb"), export_cameras=True,
                              export_lights=True)
    cycles_common.configure_cycles(scene, width, height, 2, 15)
    cycles_common.render_series(scene, [spp], 0, os.path.join(out, "cycles"), width, height)


main()
