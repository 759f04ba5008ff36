# Regenerates cycles_48x40.exr with Blender 3.4's Cycles (CPU):
#   blender -b --factory-startup --python tests/data/cycles/make_cycles_frame.py
# A noisy 8-spp render, 48 x 40 pixels, saved as a multilayer OpenEXR (half
# floats, ZIP) with the passes a denoiser takes: Combined, Depth (Z) and the
# denoising data (Denoising Normal, Denoising Albedo), as Blender names them.
# Lens metadata is stamped into the header ("Lens") as Blender does.
#
# The scene gives the tests known answers: the camera at (1, -4, 2) looks at
# (0, 0, 1) with a 50 mm lens on a 36 mm sensor at f/2, focused at 3 m; a
# backdrop plane perpendicular to the viewing axis 6 m in front of it fills
# the frame behind a sphere (radius 0.6) centred 3 m along the axis and a
# cube further off. On the backdrop the view-space depth is exactly 6 and
# the normal faces the camera. The tests only read the file: they need no
# Blender.
import os

import bpy
from mathutils import Vector

here = os.path.dirname(os.path.abspath(__file__))

bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.engine = 'CYCLES'
scene.cycles.device = 'CPU'
scene.cycles.samples = 8
scene.cycles.use_denoising = False
scene.cycles.seed = 7
scene.render.resolution_x = 48
scene.render.resolution_y = 40
scene.render.resolution_percentage = 100

world = bpy.data.worlds.new("World")
world.use_nodes = True
world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.3, 0.35, 0.4, 1)
scene.world = world

cam_pos = Vector((1.0, -4.0, 2.0))
forward = (Vector((0.0, 0.0, 1.0)) - cam_pos).normalized()
rot = forward.to_track_quat('-Z', 'Y')  # Blender cameras look down their local -Z

cam_data = bpy.data.cameras.new("Camera")
cam_data.lens = 50.0
cam_data.sensor_width = 36.0
cam_data.sensor_fit = 'AUTO'
cam_data.dof.use_dof = True
cam_data.dof.aperture_fstop = 2.0
cam_data.dof.focus_distance = 3.0
cam = bpy.data.objects.new("Camera", cam_data)
cam.location = cam_pos
cam.rotation_mode = 'QUATERNION'
cam.rotation_quaternion = rot
scene.collection.objects.link(cam)
scene.camera = cam


def material(name, colour):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    m.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = colour + (1,)
    return m


# Backdrop: a plane's normal is its local +Z; with the camera's rotation it
# faces the camera, perpendicular to the viewing axis.
bpy.ops.mesh.primitive_plane_add(size=40, location=cam_pos + 6.0 * forward)
backdrop = bpy.context.active_object
backdrop.rotation_mode = 'QUATERNION'
backdrop.rotation_quaternion = rot
backdrop.data.materials.append(material("backdrop", (0.8, 0.7, 0.5)))

bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=cam_pos + 3.0 * forward)
bpy.context.active_object.data.materials.append(material("sphere", (0.2, 0.5, 0.8)))
bpy.ops.object.shade_smooth()

bpy.ops.mesh.primitive_cube_add(size=0.8, location=cam_pos + 4.5 * forward + Vector((1.2, 0, 0.3)))
bpy.context.active_object.data.materials.append(material("cube", (0.7, 0.2, 0.2)))

sun_data = bpy.data.lights.new("Sun", 'SUN')
sun_data.energy = 3.0
sun = bpy.data.objects.new("Sun", sun_data)
sun.rotation_euler = (0.6, 0.2, 0.4)
scene.collection.objects.link(sun)

layer = scene.view_layers[0]
layer.use_pass_z = True
layer.cycles.denoising_store_passes = True

render = scene.render
render.image_settings.file_format = 'OPEN_EXR_MULTILAYER'
render.image_settings.color_depth = '16'
render.image_settings.exr_codec = 'ZIP'
# Metadata Blender stamps into the header: keep what describes the shot,
# drop what changes from run to run (date, render time, memory, host).
render.use_stamp_date = False
render.use_stamp_time = False
render.use_stamp_render_time = False
render.use_stamp_memory = False
render.use_stamp_hostname = False
render.use_stamp_frame = True
render.use_stamp_camera = True
render.use_stamp_lens = True
render.use_stamp_scene = True
render.use_stamp_filename = False
render.filepath = os.path.join(here, "cycles_48x40.exr")
bpy.ops.render.render(write_still=True)
