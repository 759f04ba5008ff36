# Exports one Blender scene as glTF (.glb, Include > Cameras ticked),
# Collada and FBX (their defaults), for bench/cycles/blender_formats.sh:
# the start-up file with its lamp removed, the cube given a coloured
# Principled material (base (0.2, 0.5, 0.8), roughness 0.5), a metal sphere
# (base (0.9, 0.6, 0.3), metallic 1, roughness 0.3) and a 10 m floor at
# z = -1 (base 0.8, roughness 1); the start-up camera (16:9, 50 mm) made Orthographic with scale 7
# when the last argument is "ortho", and Clip Start 0.5 either way.
#   blender -b --factory-startup -P bench/cycles/blender_formats.py -- OUT_DIR [ortho]
import os
import sys

import bpy

argv = sys.argv[sys.argv.index('--') + 1:]
out = argv[0]
ortho = len(argv) > 1 and argv[1] == 'ortho'
bpy.data.objects.remove(bpy.data.objects['Light'])
principled = bpy.data.materials['Material'].node_tree.nodes['Principled BSDF']
principled.inputs['Base Color'].default_value = (0.2, 0.5, 0.8, 1)
principled.inputs['Roughness'].default_value = 0.5
bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(1.6, -1.4, -0.4))
metal = bpy.data.materials.new('Metal')
metal.use_nodes = True
m = metal.node_tree.nodes['Principled BSDF']
m.inputs['Base Color'].default_value = (0.9, 0.6, 0.3, 1)
m.inputs['Metallic'].default_value = 1.0
m.inputs['Roughness'].default_value = 0.3
bpy.context.object.data.materials.append(metal)
bpy.ops.mesh.primitive_plane_add(size=10, location=(0, 0, -1))
floor = bpy.data.materials.new('Floor')
floor.use_nodes = True
f = floor.node_tree.nodes['Principled BSDF']
f.inputs['Base Color'].default_value = (0.8, 0.8, 0.8, 1)
f.inputs['Roughness'].default_value = 1.0
bpy.context.object.data.materials.append(floor)
cam = bpy.data.objects['Camera']
cam.data.clip_start = 0.5
if ortho:
    cam.data.type = 'ORTHO'
    cam.data.ortho_scale = 7.0
os.makedirs(out, exist_ok=True)
bpy.ops.export_scene.gltf(filepath=os.path.join(out, 'scene.glb'), export_format='GLB',
                          export_cameras=True)
bpy.ops.wm.collada_export(filepath=os.path.join(out, 'scene.dae'))
bpy.ops.export_scene.fbx(filepath=os.path.join(out, 'scene.fbx'))
