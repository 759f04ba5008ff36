# What bench/cycles/render_cornell.py and render_courtyard.py share: the
# importer's numpy shim, Cycles set up to render what dofarm renders, timed
# renders (optionally under perf's control FIFO) and PFM output. Imported
# by those scripts inside Blender (they put this folder on sys.path).
import struct
import time

import bpy


def patch_numpy():
    """Blender 3.4's glTF importer uses np.bool, which numpy >= 1.24 (Debian
    12's python3-numpy, which the importer needs) no longer has."""
    import numpy
    if not hasattr(numpy, "bool") or numpy.bool is not bool:
        try:
            numpy.bool = bool
        except AttributeError:
            pass


def configure_cycles(scene, width, height, threads, max_bounces, blender_clamp=False):
    """Cycles set to match dofarm's renderer: no denoising, no adaptive
    sampling, box pixel filter 1 pixel wide, no clamping, no glossy blur
    (blender_clamp: Blender's defaults, indirect clamp 10 and filter glossy
    1), caustics on, one tile for the whole image, a fixed number of
    threads, max_bounces for every kind of bounce, no volumes.

    Persistent data is off: with it, Blender 3.4 re-renders nothing when only
    the sample count changes and returns the previous image in a fraction of
    the time (found by comparing images). Without it each render syncs the
    scene again (about 0.01 s of a 0.2 s sample on the Cornell box)."""
    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x = width
    r.resolution_y = height
    r.resolution_percentage = 100
    r.threads_mode = "FIXED"
    r.threads = threads
    r.use_persistent_data = False
    r.film_transparent = False
    r.image_settings.file_format = "OPEN_EXR"
    r.image_settings.color_depth = "32"
    r.image_settings.exr_codec = "NONE"
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0

    c = scene.cycles
    c.device = "CPU"
    c.use_denoising = False
    c.use_adaptive_sampling = False
    c.use_auto_tile = False
    c.max_bounces = max_bounces
    c.diffuse_bounces = max_bounces
    c.glossy_bounces = max_bounces
    c.transmission_bounces = max_bounces
    c.volume_bounces = 0
    c.transparent_max_bounces = max_bounces
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 10.0 if blender_clamp else 0.0
    c.blur_glossy = 1.0 if blender_clamp else 0.0
    c.caustics_reflective = True
    c.caustics_refractive = True
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    c.film_exposure = 1.0


def perf_control(path, command):
    """Writes a command ("enable", "disable") to perf's control FIFO
    (perf record --delay=-1 --control=fifo:PATH); nothing if path is empty."""
    if path:
        with open(path, "w") as f:
            f.write(command + "\n")


def timed_render(scene, spp, seed, perf_ctl=""):
    """Renders at spp; returns (CPU s, wall s) of bpy.ops.render.render()
    alone. With perf_ctl, perf samples during the render only."""
    scene.cycles.samples = spp
    scene.cycles.seed = seed
    perf_control(perf_ctl, "enable")
    c0, w0 = time.process_time(), time.perf_counter()
    bpy.ops.render.render(write_still=False)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    perf_control(perf_ctl, "disable")
    return cpu, wall


def save_pfm(path, exr_path, width, height):
    """The last render as PFM (linear RGB, rows bottom-up), through an
    uncompressed float EXR at exr_path, which is removed."""
    import os
    bpy.data.images["Render Result"].save_render(exr_path)
    img = bpy.data.images.load(exr_path)
    px = list(img.pixels)  # RGBA floats, rows from the bottom up, as PFM
    bpy.data.images.remove(img)
    os.remove(exr_path)
    rgb = [0.0] * (width * height * 3)
    rgb[0::3] = px[0::4]
    rgb[1::3] = px[1::4]
    rgb[2::3] = px[2::4]
    with open(path, "wb") as f:
        f.write(b"PF\n%d %d\n-1.0\n" % (width, height))
        f.write(struct.pack("<%df" % len(rgb), *rgb))


def render_series(scene, spp_list, seed, out, width, height, perf_ctl=""):
    """A 1-spp warm-up render (untimed, not profiled), then one timed render
    per sample count: writes OUT<N>.pfm and prints
    "spp N cpu_s C wall_s W"."""
    import os
    timed_render(scene, 1, seed)
    for spp in spp_list:
        cpu, wall = timed_render(scene, spp, seed, perf_ctl)
        save_pfm(out + "%d.pfm" % spp, os.path.abspath(out + "%d.exr" % spp), width, height)
        print("spp %d cpu_s %.3f wall_s %.3f" % (spp, cpu, wall), flush=True)
