# Regenerates materials.glb, materials.dae and materials.fbx with Blender
# 3.4's exporters (glTF with its defaults; Collada and FBX with theirs):
#   blender -b --factory-startup --python tests/data/blender/make_materials.py
# The start-up cube with its lamp and camera removed, its material made
# base (0.2, 0.5, 0.8), roughness 0.5; an ico sphere (1 subdivision) with a
# material "Metal": base (0.9, 0.6, 0.3), metallic 1, roughness 0.3; a
# 4 m plane at z = -1 without a material. The tests check that the Collada
# and FBX materials carry the glTF ones' base colour and metallic (Blender
# writes Metallic as their reflectivity), and FBX their roughness, and that
# the plane is grey, not the cube's blue, in the Collada file. They only
# read the files: they need no Blender.
import os

import bpy

here = os.path.dirname(os.path.abspath(__file__))
for name in ('Light', 'Camera'):
    bpy.data.objects.remove(bpy.data.objects[name])
principled = bpy.data.materials['Material'].node_tree.nodes['Principled BSDF']
principled.inputs['Base Color'].default_value = (0.2, 0.5, 0.8, 1)
principled.inputs['Roughness'].default_value = 0.5
bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=1, radius=0.6, location=(1.6, -1.4, -0.4))
metal = bpy.data.materials.new('Metal')
metal.use_nodes = True
m = metal.node_tree.nodes['Principled BSDF']
m.inputs['Base Color'].default_value = (0.9, 0.6, 0.3, 1)
m.inputs['Metallic'].default_value = 1.0
m.inputs['Roughness'].default_value = 0.3
bpy.context.object.data.materials.append(metal)
bpy.ops.mesh.primitive_plane_add(size=4, location=(0, 0, -1))  # no material
bpy.ops.export_scene.gltf(filepath=os.path.join(here, 'materials.glb'), export_format='GLB')
bpy.ops.wm.collada_export(filepath=os.path.join(here, 'materials.dae'))
bpy.ops.export_scene.fbx(filepath=os.path.join(here, 'materials.fbx'))
