#!/usr/bin/env python3
# Writes the matched-material variant of the bundled Cornell box for
# bench/cycles_vs_dofarm.sh: every material metallic 0 with its base colour,
# emission kept, and a job file that renders it with the camera of
# cornell_dof.toml. Neither renderer reads that file as Lambert by itself
# (dofarm reads a missing IOR, and IOR 1, as 1.5, which gives every
# material a specular layer; Blender's importer makes a Principled BSDF,
# whose diffuse part is Disney's), so each is told: bench/render_spp
# --lambert sets IOR 1 on every material after loading (no specular
# interface: the Lambertian base alone, bsdf.h), render_cornell.py
# --lambert puts a Diffuse BSDF (roughness 0: Cycles' Lambert closure) in
# place of the Principled BSDF. Both then render one model.
#
#   lambert_scene.py OUT_DIR   -> OUT_DIR/cornell_lambert.{gltf,bin,toml}
import json
import os
import shutil
import sys

here = os.path.dirname(os.path.abspath(__file__))
root = os.path.dirname(os.path.dirname(here))


def main():
    if len(sys.argv) != 2:
        raise SystemExit("usage: lambert_scene.py OUT_DIR")
    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    src = os.path.join(root, "jobs", "scenes", "cornell.gltf")
    with open(src) as f:
        gltf = json.load(f)
    for m in gltf["materials"]:
        pbr = m.setdefault("pbrMetallicRoughness", {})
        for key in ("baseColorTexture", "metallicRoughnessTexture"):
            if key in pbr:
                raise SystemExit("%s: material %s is textured" % (src, m.get("name")))
        pbr["metallicFactor"] = 0.0
        pbr["roughnessFactor"] = 1.0  # unused without a specular lobe
        m.get("extensions", {}).pop("KHR_materials_ior", None)
    for b in gltf["buffers"]:
        shutil.copy(os.path.join(os.path.dirname(src), b["uri"]), os.path.join(out, b["uri"]))
    with open(os.path.join(out, "cornell_lambert.gltf"), "w") as f:
        json.dump(gltf, f, indent=1)
    with open(os.path.join(here, "cornell_dof.toml")) as f:
        job = f.read()
    old = 'scene = "../../jobs/scenes/cornell.gltf"'
    if old not in job:
        raise SystemExit("cornell_dof.toml: no line %s" % old)
    with open(os.path.join(out, "cornell_lambert.toml"), "w") as f:
        f.write(job.replace(old, 'scene = "cornell_lambert.gltf"'))


main()
