# Regenerates lamps_and_texture.glb (and tex.png) with Blender 3.4's glTF
# exporter, default settings plus "Punctual Lights":
#   blender -b --python tests/data/blender/make_lamps_and_texture.py
# A 2 m plane whose base colour is tex.png behind a Mapping node (location
# (0.25, 0.5), rotation 0.3, scale (2, 3)), a 1000 W point lamp at z = 2, a
# 500 W spot lamp (size 60 degrees, blend 0.25) at (1, 0, 3) and a 3 W/m^2
# sun turned 0.5 rad about x. The tests only read the files: they need no
# Blender.
import math
import os
import struct
import zlib

import bpy

here = os.path.dirname(os.path.abspath(__file__))


def png(w, h, pix):
    raw = b''.join(b'\x00' + bytes(pix[y * w * 3:(y + 1) * w * 3]) for y in range(h))

    def chunk(t, d):
        return struct.pack('>I', len(d)) + t + d + struct.pack('>I', zlib.crc32(t + d) & 0xffffffff)
    return (b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', struct.pack('>IIBBBBB', w, h, 8, 2, 0, 0, 0)) +
            chunk(b'IDAT', zlib.compress(raw)) + chunk(b'IEND', b''))


with open(os.path.join(here, 'tex.png'), 'wb') as f:
    f.write(png(2, 2, [255, 0, 0, 0, 255, 0, 0, 0, 255, 128, 128, 128]))

bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.mesh.primitive_plane_add(size=2)
plane = bpy.context.active_object
mat = bpy.data.materials.new("tex")
mat.use_nodes = True
nt = mat.node_tree
bsdf = nt.nodes["Principled BSDF"]
tn = nt.nodes.new("ShaderNodeTexImage")
tn.image = bpy.data.images.load(os.path.join(here, 'tex.png'))
mp = nt.nodes.new("ShaderNodeMapping")
mp.inputs["Location"].default_value = (0.25, 0.5, 0)
mp.inputs["Rotation"].default_value = (0, 0, 0.3)
mp.inputs["Scale"].default_value = (2, 3, 1)
tc = nt.nodes.new("ShaderNodeTexCoord")
nt.links.new(tc.outputs["UV"], mp.inputs["Vector"])
nt.links.new(mp.outputs["Vector"], tn.inputs["Vector"])
nt.links.new(tn.outputs["Color"], bsdf.inputs["Base Color"])
plane.data.materials.append(mat)


def lamp(name, kind, setup, location=(0, 0, 0), rotation=(0, 0, 0)):
    data = bpy.data.lights.new(name[0], kind)
    setup(data)
    obj = bpy.data.objects.new(name, data)
    obj.location = location
    obj.rotation_euler = rotation
    bpy.context.scene.collection.objects.link(obj)


lamp("Point", "POINT", lambda l: setattr(l, "energy", 1000), location=(0, 0, 2))


def spot(l):
    l.energy = 500
    l.spot_size = math.radians(60)
    l.spot_blend = 0.25


lamp("Spot", "SPOT", spot, location=(1, 0, 3))
lamp("Sun", "SUN", lambda l: setattr(l, "energy", 3), rotation=(0.5, 0, 0))
bpy.ops.export_scene.gltf(filepath=os.path.join(here, "lamps_and_texture.glb"),
                          export_format='GLB', export_lights=True)
