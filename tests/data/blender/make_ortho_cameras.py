# Regenerates ortho_camera.{glb,dae,fbx} and persp_camera.{glb,dae,fbx} with
# Blender 3.4's exporters (glTF with Include > Cameras ticked; Collada and
# FBX with their defaults):
#   blender -b --factory-startup --python tests/data/blender/make_ortho_cameras.py
# One scene: a 4 m plane at z = -1 and the start-up file's camera (16:9,
# pose unchanged) made Orthographic with Orthographic Scale 6 and Clip Start
# 0.5; the persp_camera files keep it Perspective. The tests check that
# the Collada and FBX perspective cameras and the Collada orthographic one
# are the glTF ones, and that the FBX orthographic camera, which assimp 5.2
# reads as a perspective one, is refused. They only read the files: they
# need no Blender. (The files hold their export's date: regenerating
# changes their bytes, not their scene.)
import os

import bpy

here = os.path.dirname(os.path.abspath(__file__))
for name in ('Cube', 'Light'):
    bpy.data.objects.remove(bpy.data.objects[name])
bpy.ops.mesh.primitive_plane_add(size=4, location=(0, 0, -1))
cam = bpy.data.objects['Camera']
cam.data.clip_start = 0.5
bpy.ops.export_scene.fbx(filepath=os.path.join(here, 'persp_camera.fbx'))
bpy.ops.export_scene.gltf(filepath=os.path.join(here, 'persp_camera.glb'), export_format='GLB',
                          export_cameras=True)
bpy.ops.wm.collada_export(filepath=os.path.join(here, 'persp_camera.dae'))
cam.data.type = 'ORTHO'
cam.data.ortho_scale = 6.0
bpy.ops.export_scene.gltf(filepath=os.path.join(here, 'ortho_camera.glb'), export_format='GLB',
                          export_cameras=True)
bpy.ops.wm.collada_export(filepath=os.path.join(here, 'ortho_camera.dae'))
bpy.ops.export_scene.fbx(filepath=os.path.join(here, 'ortho_camera.fbx'))
