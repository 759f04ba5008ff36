# Blender script for bench/cycles/gltf_features_vs_cycles.sh: one small
# scene per glTF feature that Blender's exporter writes from a Principled
# BSDF, exported as glTF (Punctual Lights on) and rendered with Cycles into
# a PFM, seen from 5 m above with a black world:
#
#   specular    a 4 m plane (base colour 0.8, 0.4, 0.2, roughness 0.5) of the
#               given Specular and Specular Tint, 2 m below a 1000 W point
#               lamp (KHR_materials_specular); 64 x 64
#   specular_texture  the specular scene's plane (Specular from an 8 x 8
#               checker of 0 and 1, Non-Color, Closest: the exporter bakes a
#               specularColorTexture), 96 x 96
#   normal_map  a 4 m plane (base 0.7, roughness 1, Specular 0) whose normal
#               comes from a tangent-space map of bumps along both image
#               axes (Image Texture, Non-Color -> Normal Map node: the
#               exporter's normalTexture), a sun from the side; 96 x 96
#   normal_map_tangents  the same, exported with its tangents (TANGENT)
#   alpha_mask  a 2 m plane whose base colour texture's alpha is an 8 x 8
#               checker of 0 and 1 (Alpha Clip: alphaMode MASK), 1 m over
#               a 4 m blue plane, a sun from the side; 96 x 96
#   alpha_blend the same with alpha 0.4 and 0 (Alpha Blend: alphaMode BLEND)
#   clearcoat   the specular scene's plane (Specular 0.5) with Clearcoat 1 and
#               the given Clearcoat Roughness (KHR_materials_clearcoat); 64 x 64
#   clearcoat_normal  a 4 m plane (base 0.1, roughness 1, Specular 0) with
#               Clearcoat 1, Clearcoat Roughness 0.15 and the bumps map
#               feeding Clearcoat Normal through a Normal Map node
#               (clearcoatNormalTexture), the base flat, a sun 20 degrees
#               from overhead, so the pattern is the coat's highlights; 96 x 96
#   uv_map      a 4 m plane (base colour from an 8 x 8 checker, Closest) whose
#               texture is read through a UV Map node picking the mesh's
#               second UV map, an affine map of the first (texCoord 1 on
#               TEXCOORD_1), a sun from the side; 96 x 96
#   transmission  a glass sphere (Transmission 1, IOR 1.45, base 0.95, 0.9,
#               0.8, the given Roughness) of radius 0.6 m, 1.2 m over a 4 m
#               checkered floor (base colour texture, Closest interpolation)
#               (moved off centre by 0.17, 0.11 m), a sun from the side
#               and a grey world (0.3), so the sphere shows the floor
#               refracted (KHR_materials_transmission + KHR_materials_ior);
#               96 x 96
#   animation   a red 0.8 m cube keyed at frames 1 and 25 (Blender's default
#               Bezier keys) moving from (-1.2, -0.6) to (1.2, 0.6) while
#               turning 90 degrees about z, on a 4 m floor, and a 300 W
#               point lamp keyed from (-1.5, 1.5, 1.5) to (1.5, -1.5, 1.5),
#               a weak sun; rendered at frame 9 (the exporter samples every
#               frame and writes each at frame / fps seconds, the time of
#               dofarm's frame 9 at the same fps); 96 x 96
#   skinning    a green bar (radius 0.25 m, 2.4 m long, along x, 0.5 m over
#               the floor) deformed by a two-bone armature (automatic
#               weights), the second bone keyed from straight at frame 1
#               to bent 90 degrees about z at frame 25, the point lamp
#               and sun of the animation scene held still; rendered at
#               frame 13 (glTF skin, joints animated); 96 x 96
#   animation_spline, shape_keys_spline  the animation and shape_keys
#               scenes exported with their Bezier keys (export_force_sampling
#               off: CUBICSPLINE samplers with the keys' tangents), rendered
#               at frame 5
#   clipping    a 0.8 m red cube on the grey floor under an 8 m black plane
#               2.5 m up, the camera's Clip Start 3 m and Clip End 4.7 m (glTF
#               znear, zfar), a 100 W point lamp 1.2 m over the cube: camera
#               rays see only the cube's top, while the plane still shades
#               it from the sun; 96 x 96
#   camera      the animation scene's floor, lamps and cube, still, seen by
#               the camera of camera_spline, exported with a sample per frame
#   camera_spline  the animation scene's floor, lamps and cube, still,
#               seen by a camera keyed (Bezier) from (-1.5, -1, 5) rolled
#               -30 degrees to (1.5, 1, 5) rolled 30 degrees, exported with
#               its keys (CUBICSPLINE), rendered at frame 5
#   soft_lamps  a 0.8 m red cube on the grey floor under a 300 W point lamp
#               of Radius 0.25 m (Blender's default for a new lamp) and a
#               1 W/m^2 sun of Angle 10 degrees, whose sizes the exporter
#               drops: soft shadows in Cycles; 96 x 96
#   spot_cone   a 1000 W spot lamp 2 m over the grey floor pointing straight
#               down, Spot Size 90 degrees and Blend 0.5 (glTF outer cone
#               45 degrees, inner 22.5), Radius 0: the cone's edge and its
#               falloff on the floor; 96 x 96
#   spot_soft   the spot of spot_cone with Radius 0.25 m over the red cube:
#               the cone's edge and the cube's shadow both soft; 96 x 96
#   lamp_mirror the lamps of soft_lamps over a mirror: a metal sphere
#               (base colour 0.9, Roughness 0, radius 0.6 m) on the grey
#               floor, which shows the lamp's disk and the sun's disc (in
#               Cycles a lamp with a size is seen by every bounce ray,
#               never by the camera); 96 x 96
#   shape_keys  a blue ball (radius 0.6 m, 0.8 m over the floor) with a
#               shape key that stretches it to twice its width along x,
#               keyed from 0 at frame 1 to 1 at frame 25 (glTF morph
#               target with animated weights), the lamps of the skinning
#               scene; rendered at frame 13; 96 x 96
#
#   blender -b -noaudio --factory-startup -P feature_scene.py -- FEATURE OUT_DIR SPP [SPECULAR TINT | ROUGHNESS [DISTRIBUTION]]
#   (DISTRIBUTION: the glass's Principled distribution, GGX (Blender's
#   default) or MULTI_GGX; the exported file is the same)
#   -> OUT_DIR/scene.gltf (+ .bin, images), OUT_DIR/cycles.pfm (linear RGB, rows bottom-up)
import math
import os
import struct
import sys

import bpy
import mathutils


def image(name, size, texel, path, colour_space):
    """A size x size image from texel(x, y) -> RGBA (x right, y up, in [0, 1)), saved as PNG."""
    img = bpy.data.images.new(name, size, size, alpha=True)
    # Before the pixels: changing a generated image's colour space regenerates it.
    img.colorspace_settings.name = colour_space
    px = [0.0] * (size * size * 4)
    for j in range(size):
        for i in range(size):
            px[4 * (j * size + i):4 * (j * size + i) + 4] = texel((i + 0.5) / size, (j + 0.5) / size)
    img.pixels = px
    img.filepath_raw = path
    img.file_format = "PNG"
    img.save()
    return img


def bumps(x, y):
    # h = a sin(4 pi x) sin(6 pi y); n = (-dh/dx, -dh/dy, 1), stored as
    # (n + 1) / 2 (OpenGL convention: green is up).
    a = 0.08
    dx = a * 4 * math.pi * math.cos(4 * math.pi * x) * math.sin(6 * math.pi * y)
    dy = a * 6 * math.pi * math.sin(4 * math.pi * x) * math.cos(6 * math.pi * y)
    l = math.sqrt(dx * dx + dy * dy + 1)
    return [(-dx / l + 1) / 2, (-dy / l + 1) / 2, (1 / l + 1) / 2, 1.0]


def checker(x, y, alpha=1.0):
    on = (int(x * 8) + int(y * 8)) % 2 == 0
    return [0.9, 0.6, 0.1, alpha if on else 0.0]


def bump_map(mat, socket, out):
    """The bumps image (Non-Color) through a tangent-space Normal Map node into socket."""
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image("bumps", 128, bumps, os.path.join(out, "bumps.png"), "Non-Color")
    nmap = nodes.new("ShaderNodeNormalMap")
    nmap.space = "TANGENT"
    links.new(tex.outputs["Color"], nmap.inputs["Color"])
    links.new(nmap.outputs["Normal"], socket)


def opaque_checker(x, y):
    # checker() with its holes dark grey instead of transparent.
    return checker(x, y)[:3] + [1.0] if checker(x, y)[3] else [0.1, 0.1, 0.1, 1.0]


def checker_texture(mat, out):
    """An Image Texture node of the opaque checker (sRGB, Closest) in mat."""
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = image("checker", 64, opaque_checker, os.path.join(out, "checker.png"), "sRGB")
    tex.interpolation = "Closest"
    return tex


def principled(name, base, roughness, specular=0.5, tint=0.0):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    p = mat.node_tree.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = base + (1.0,)
    p.inputs["Roughness"].default_value = roughness
    p.inputs["Specular"].default_value = specular
    p.inputs["Specular Tint"].default_value = tint
    return mat, p


def plane(size, z, mat):
    bpy.ops.mesh.primitive_plane_add(size=size, location=(0.0, 0.0, z))
    obj = bpy.context.active_object
    obj.data.materials.append(mat)
    return obj


def grey_floor():
    """A 4 m Lambert-like floor of base colour 0.8 (roughness 1, Specular 0)."""
    floor, _ = principled("floor", (0.8, 0.8, 0.8), 1.0, specular=0.0)
    plane(4.0, 0.0, floor)


def red_cube(location):
    """A 0.8 m cube of base colour (0.8, 0.1, 0.1) (roughness 1, Specular 0)."""
    red, _ = principled("box", (0.8, 0.1, 0.1), 1.0, specular=0.0)
    bpy.ops.mesh.primitive_cube_add(size=0.8, location=location)
    box = bpy.context.active_object
    box.data.materials.append(red)
    return box


def light(scene, kind, energy, location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0)):
    data = bpy.data.lights.new(kind.lower(), type=kind)
    data.energy = energy
    if kind == "SUN":
        data.angle = 0.0
    else:
        data.shadow_soft_size = 0.0
    obj = bpy.data.objects.new(kind.lower(), data)
    obj.location = location
    obj.rotation_euler = rotation
    scene.collection.objects.link(obj)
    return obj


# The frame the animation and skinning features render (feature_compare.py
# ANIMATION_FRAME). The _spline features are the animation and shape_keys
# scenes exported with their keys (Blender's Bezier keyframes: glTF
# CUBICSPLINE samplers) instead of a sample per frame, rendered at frame 5,
# a sixth of the way, where the spline and a straight line between the keys
# are far apart.
ANIMATION_FRAME = {"animation": 9, "skinning": 13, "shape_keys": 13, "animation_spline": 5,
                   "shape_keys_spline": 5, "camera": 5, "camera_spline": 5}


def main():
    argv = sys.argv[sys.argv.index("--") + 1:]
    if len(argv) not in (3, 4, 5):
        raise SystemExit(
            "usage: feature_scene.py -- FEATURE OUT_DIR SPP [SPECULAR TINT | ROUGHNESS [DISTRIBUTION]]")
    feature, out, spp = argv[0], argv[1], int(argv[2])
    spline = feature.endswith("_spline")
    scene_kind = feature[:-len("_spline")] if spline else feature
    os.makedirs(out, exist_ok=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    # Light from +x, +y and above: a frame turned wrongly in either axis shows.
    sun_rotation = (math.radians(-50.0), math.radians(35.0), 0.0)
    if feature == "specular":
        size = 64
        mat, _ = principled("plane", (0.8, 0.4, 0.2), 0.5, float(argv[3]), float(argv[4]))
        plane(4.0, 0.0, mat)
        light(scene, "POINT", 1000.0, location=(0.0, 0.0, 2.0))
    elif feature == "specular_texture":
        size = 96
        mat, p = principled("plane", (0.8, 0.4, 0.2), 0.5)
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = image("spec", 64, lambda x, y: [float(checker(x, y)[3])] * 3 + [1.0],
                          os.path.join(out, "spec.png"), "Non-Color")
        tex.interpolation = "Closest"
        links.new(tex.outputs["Color"], p.inputs["Specular"])
        plane(4.0, 0.0, mat)
        light(scene, "POINT", 1000.0, location=(0.0, 0.0, 2.0))
    elif feature == "clearcoat":
        size = 64
        mat, p = principled("plane", (0.8, 0.4, 0.2), 0.5)
        p.inputs["Clearcoat"].default_value = 1.0
        p.inputs["Clearcoat Roughness"].default_value = float(argv[3])
        plane(4.0, 0.0, mat)
        light(scene, "POINT", 1000.0, location=(0.0, 0.0, 2.0))
    elif feature in ("normal_map", "normal_map_tangents"):
        size = 96
        mat, p = principled("bumpy", (0.7, 0.7, 0.7), 1.0, specular=0.0)
        bump_map(mat, p.inputs["Normal"], out)
        plane(4.0, 0.0, mat)
        light(scene, "SUN", 3.0, rotation=sun_rotation)
    elif feature in ("alpha_mask", "alpha_blend"):
        size = 96
        back, _ = principled("back", (0.1, 0.3, 0.8), 1.0, specular=0.0)
        plane(4.0, 0.0, back)
        mat, p = principled("leaf", (1.0, 1.0, 1.0), 1.0, specular=0.0)
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        tex = nodes.new("ShaderNodeTexImage")
        alpha = 1.0 if feature == "alpha_mask" else 0.4
        tex.image = image("checker", 64, lambda x, y: checker(x, y, alpha),
                          os.path.join(out, "checker.png"), "sRGB")
        tex.interpolation = "Closest"
        links.new(tex.outputs["Color"], p.inputs["Base Color"])
        links.new(tex.outputs["Alpha"], p.inputs["Alpha"])
        mat.blend_method = "CLIP" if feature == "alpha_mask" else "BLEND"
        mat.alpha_threshold = 0.5
        plane(2.0, 1.0, mat)
        light(scene, "SUN", 3.0, rotation=sun_rotation)
    elif feature == "clearcoat_normal":
        size = 96
        mat, p = principled("lacquer", (0.1, 0.1, 0.1), 1.0, specular=0.0)
        p.inputs["Clearcoat"].default_value = 1.0
        p.inputs["Clearcoat Roughness"].default_value = 0.15
        bump_map(mat, p.inputs["Clearcoat Normal"], out)
        plane(4.0, 0.0, mat)
        light(scene, "SUN", 3.0, rotation=(math.radians(-15.0), math.radians(12.0), 0.0))
    elif feature == "uv_map":
        size = 96
        mat, p = principled("decal", (1.0, 1.0, 1.0), 1.0, specular=0.0)
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        tex = checker_texture(mat, out)
        uv = nodes.new("ShaderNodeUVMap")
        uv.uv_map = "second"
        links.new(uv.outputs["UV"], tex.inputs["Vector"])
        links.new(tex.outputs["Color"], p.inputs["Base Color"])
        me = plane(4.0, 0.0, mat).data
        first, second = me.uv_layers[0], me.uv_layers.new(name="second")
        for loop in me.loops:
            u, v = first.data[loop.index].uv
            second.data[loop.index].uv = (0.6 * v + 0.13, 0.45 * u + 0.31)
        light(scene, "SUN", 3.0, rotation=sun_rotation)
    elif feature == "transmission":
        size = 96
        floor, fp = principled("floor", (1.0, 1.0, 1.0), 1.0, specular=0.0)
        # Closest (glTF magFilter NEAREST): the glass magnifies a few texels
        # of the floor many times, and Cycles blends 8-bit sRGB texels
        # before decoding them (dofarm after), which would show there.
        tex = checker_texture(floor, out)
        floor.node_tree.links.new(tex.outputs["Color"], fp.inputs["Base Color"])
        # Off centre, so that the floor under the sphere is no symmetric
        # checker corner (which looks the same refracted or not).
        plane(4.0, 0.0, floor).location = (0.17, 0.11, 0.0)
        glass, p = principled("glass", (0.95, 0.9, 0.8), float(argv[3]))
        p.inputs["Transmission"].default_value = 1.0
        if len(argv) == 5:
            p.distribution = argv[4]
        p.inputs["IOR"].default_value = 1.45
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(0.0, 0.0, 1.2), segments=64,
                                             ring_count=32)
        bpy.ops.object.shade_smooth()
        bpy.context.active_object.data.materials.append(glass)
        light(scene, "SUN", 3.0, rotation=sun_rotation)
    elif scene_kind == "animation":
        size = 96
        grey_floor()
        box = red_cube((-1.2, -0.6, 0.4))
        lamp = light(scene, "POINT", 300.0, location=(-1.5, 1.5, 1.5))
        for frame, sign in ((1, -1.0), (25, 1.0)):
            box.location = (1.2 * sign, 0.6 * sign, 0.4)
            box.rotation_euler = (0.0, 0.0, math.radians(45.0 + 45.0 * sign))
            lamp.location = (1.5 * sign, -1.5 * sign, 1.5)
            box.keyframe_insert("location", frame=frame)
            box.keyframe_insert("rotation_euler", frame=frame)
            lamp.keyframe_insert("location", frame=frame)
        light(scene, "SUN", 0.5, rotation=sun_rotation)
    elif feature == "skinning":
        size = 96
        grey_floor()
        green, _ = principled("bar", (0.1, 0.7, 0.2), 1.0, specular=0.0)
        bpy.ops.mesh.primitive_cylinder_add(radius=0.25, depth=2.4, location=(0.0, 0.0, 0.5),
                                            rotation=(0.0, math.radians(90.0), 0.0), vertices=24)
        bar = bpy.context.active_object
        bar.data.materials.append(green)
        bpy.ops.object.mode_set(mode="EDIT")
        bpy.ops.mesh.select_all(action="SELECT")
        bpy.ops.mesh.subdivide(number_cuts=15)
        bpy.ops.object.mode_set(mode="OBJECT")
        bpy.ops.object.armature_add(enter_editmode=True, location=(0.0, 0.0, 0.0))
        rig = bpy.context.active_object
        bones = rig.data.edit_bones
        first = bones[0]
        first.head, first.tail = (-1.2, 0.0, 0.5), (0.0, 0.0, 0.5)
        second = bones.new("second")
        second.head, second.tail = (0.0, 0.0, 0.5), (1.2, 0.0, 0.5)
        second.parent = first
        second.use_connect = True
        bpy.ops.object.mode_set(mode="OBJECT")
        bpy.ops.object.select_all(action="DESELECT")
        bar.select_set(True)
        rig.select_set(True)
        bpy.context.view_layer.objects.active = rig
        bpy.ops.object.parent_set(type="ARMATURE_AUTO")
        pose = rig.pose.bones["second"]
        pose.rotation_mode = "QUATERNION"
        # World z in the bone's own frame, so the bend shows from above.
        axis = rig.data.bones["second"].matrix_local.to_3x3().inverted() @ mathutils.Vector((0, 0, 1))
        for frame, angle in ((1, 0.0), (25, 90.0)):
            pose.rotation_quaternion = mathutils.Quaternion(axis, math.radians(angle))
            pose.keyframe_insert("rotation_quaternion", frame=frame)
        light(scene, "POINT", 300.0, location=(-1.5, 1.5, 1.5))
        light(scene, "SUN", 0.5, rotation=sun_rotation)
    elif feature == "clipping":
        size = 96
        grey_floor()
        red_cube((0.3, 0.2, 0.4))
        # Black, and the lamp straight over the cube: light meeting the
        # cube's top at grazing angles is where Blender 3.4's Principled
        # (Disney) diffuse is furthest from Lambert (+13% with the animation
        # scene's lamp), which would swamp what this scene compares.
        black, _ = principled("wall", (0.0, 0.0, 0.0), 1.0, specular=0.0)
        plane(8.0, 2.5, black)
        light(scene, "POINT", 100.0, location=(0.3, 0.2, 2.0))
        light(scene, "SUN", 0.5, rotation=sun_rotation)
    elif feature == "soft_lamps":
        size = 96
        grey_floor()
        red_cube((0.0, 0.0, 0.4))
        lamp = light(scene, "POINT", 300.0, location=(-1.0, 0.8, 1.6))
        lamp.data.shadow_soft_size = 0.25
        sun = light(scene, "SUN", 1.0, rotation=sun_rotation)
        sun.data.angle = math.radians(10.0)
    elif feature in ("spot_cone", "spot_soft"):
        size = 96
        grey_floor()
        spot = light(scene, "SPOT", 1000.0, location=(0.0, 0.0, 2.0))
        spot.data.spot_size = math.radians(90.0)
        spot.data.spot_blend = 0.5
        if feature == "spot_soft":
            red_cube((0.3, 0.2, 0.4))
            spot.data.shadow_soft_size = 0.25
    elif feature == "lamp_mirror":
        size = 96
        grey_floor()
        mirror, p = principled("mirror", (0.9, 0.9, 0.9), 0.0)
        p.inputs["Metallic"].default_value = 1.0
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(0.0, 0.0, 0.6), segments=64,
                                             ring_count=32)
        bpy.ops.object.shade_smooth()
        bpy.context.active_object.data.materials.append(mirror)
        lamp = light(scene, "POINT", 300.0, location=(-1.0, 0.8, 1.6))
        lamp.data.shadow_soft_size = 0.25
        sun = light(scene, "SUN", 1.0, rotation=sun_rotation)
        sun.data.angle = math.radians(10.0)
    elif feature in ("ortho", "ortho_dof"):
        size = 96
        grey_floor()
        red_cube((0.3, 0.2, 0.4))
        light(scene, "POINT", 300.0, location=(-1.5, 1.5, 1.5))
        light(scene, "SUN", 0.5, rotation=sun_rotation)
    elif scene_kind == "camera":
        size = 96
        grey_floor()
        red_cube((0.0, 0.0, 0.4))
        light(scene, "POINT", 300.0, location=(-1.5, 1.5, 1.5))
        light(scene, "SUN", 0.5, rotation=sun_rotation)
    elif scene_kind == "shape_keys":
        size = 96
        grey_floor()
        blue, _ = principled("ball", (0.1, 0.2, 0.8), 1.0, specular=0.0)
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(0.0, 0.0, 0.8), segments=48,
                                             ring_count=24)
        bpy.ops.object.shade_smooth()
        ball = bpy.context.active_object
        ball.data.materials.append(blue)
        ball.shape_key_add(name="Basis")
        stretch = ball.shape_key_add(name="stretch")
        for point in stretch.data:
            point.co.x *= 2.0
        for frame, value in ((1, 0.0), (25, 1.0)):
            stretch.value = value
            stretch.keyframe_insert("value", frame=frame)
        light(scene, "POINT", 300.0, location=(-1.5, 1.5, 1.5))
        light(scene, "SUN", 0.5, rotation=sun_rotation)
    else:
        raise SystemExit("feature_scene.py: unknown feature " + feature)
    if feature in ANIMATION_FRAME:
        scene.frame_start, scene.frame_end = 1, 25
        scene.render.fps = 24
        scene.frame_set(ANIMATION_FRAME[feature])

    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    cam.location = (0.0, 0.0, 5.0)  # looks down its -z
    scene.collection.objects.link(cam)
    if feature == "clipping":
        # The wall 2.5 m below the camera lies before Clip Start, the floor
        # 5 m below beyond Clip End; the cube's top, 4.2 m below, between.
        cam.data.clip_start = 3.0
        cam.data.clip_end = 4.7
    if feature in ("ortho", "ortho_dof"):
        # Orthographic, 3 m across, looking down on the cube from 5 m.
        cam.data.type = "ORTHO"
        cam.data.ortho_scale = 3.0
    if feature == "ortho_dof":
        # Focused on the cube's top (view depth 4.2), the floor 0.8 m
        # behind it; f/0.8. Clip Start 1 m: were Cycles' focus distance
        # counted from Clip Start, the focal plane would lie 1 m deeper.
        cam.data.clip_start = 1.0
        cam.data.dof.use_dof = True
        cam.data.dof.focus_distance = 4.2
        cam.data.dof.aperture_fstop = 0.8
    if scene_kind == "camera":
        # Across the cube from (-1.5, -1, 5) to (1.5, 1, 5), rolling 60 degrees.
        for frame, sign in ((1, -1.0), (25, 1.0)):
            cam.location = (1.5 * sign, 1.0 * sign, 5.0)
            cam.rotation_euler = (0.0, 0.0, math.radians(30.0 * sign))
            cam.keyframe_insert("location", frame=frame)
            cam.keyframe_insert("rotation_euler", frame=frame)
    scene.camera = cam
    scene.world = bpy.data.worlds.new("world")
    scene.world.use_nodes = False
    # Black, but grey where glass needs something to refract and reflect.
    scene.world.color = (0.3, 0.3, 0.3) if feature == "transmission" else (0.0, 0.0, 0.0)
    scene.render.engine = "CYCLES"
    scene.render.resolution_x = size
    scene.render.resolution_y = size
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
    c.transmission_bounces = 8
    if feature == "lamp_mirror":
        # The floor is lit by the lamps through the mirror too (a caustic),
        # which Blender's default indirect clamp of 10 and Filter Glossy
        # would cut and blur; dofarm does neither.
        c.sample_clamp_indirect = 0.0
        c.blur_glossy = 0.0

    bpy.ops.export_scene.gltf(filepath=os.path.join(out, "scene.gltf"),
                              export_format="GLTF_SEPARATE", export_lights=True,
                              export_cameras=True,
                              export_tangents=feature == "normal_map_tangents",
                              export_force_sampling=not spline)
    exr = os.path.join(out, "cycles.exr")
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = exr
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(exr)
    px = list(img.pixels)  # RGBA, rows bottom-up, as PFM
    rgb = [0.0] * (size * size * 3)
    for k in range(3):
        rgb[k::3] = px[k::4]
    with open(os.path.join(out, "cycles.pfm"), "wb") as f:
        f.write(b"PF\n%d %d\n-1.0\n" % (size, size))
        f.write(struct.pack("<%df" % len(rgb), *rgb))


main()
