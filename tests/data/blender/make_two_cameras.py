# Regenerates two_cameras.{glb,fbx} with Blender 3.4's exporters (glTF with
# Include > Cameras ticked; FBX with its defaults):
#   blender -b --factory-startup --python tests/data/blender/make_two_cameras.py
# One scene: a 4 m plane at z = -1, the start-up file's perspective camera
# ("Camera", 16:9, Clip Start 0.5) and a second camera "Top", orthographic
# (Orthographic Scale 5, Clip Start 0.25) looking straight down from 3 m.
# The FBX file holds both as assimp 5.2 reads them, as perspective cameras;
# the tests check that each renders as its glTF twin when the job names it.
# They only read the files: they need no Blender.
import os

import bpy

here = os.path.dirname(os.path.abspath(__file__))
for name in ('Cube', 'Light'):
    bpy.data.objects.remove(bpy.data.objects[name])
bpy.ops.mesh.primitive_plane_add(size=4, location=(0, 0, -1))
bpy.data.objects['Camera'].data.clip_start = 0.5
bpy.ops.object.camera_add(location=(0.5, 0.25, 3.0), rotation=(0.0, 0.0, 0.0))
top = bpy.context.object
top.name = 'Top'
top.data.type = 'ORTHO'
top.data.ortho_scale = 5.0
top.data.clip_start = 0.25
bpy.ops.export_scene.gltf(filepath=os.path.join(here, 'two_cameras.glb'), export_format='GLB',
                          export_cameras=True)
bpy.ops.export_scene.fbx(filepath=os.path.join(here, 'two_cameras.fbx'))
