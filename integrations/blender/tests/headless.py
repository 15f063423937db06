"""Headless check of the Blender extension, run by test_extension.py with `bpy` from PyPI:

    python3 headless.py EXTENSION_ZIP WORK_DIR     # prints one JSON line of findings

Installs and enables the extension from its zip, renders a five-frame camera move at low spp
with radn's panel option on (the extension turns on the passes it needs and denoises after the
animation), renders a high-spp reference of the same frames, runs per-frame OIDN (prefiltered
auxiliaries, pyoidn) for comparison, then runs the operator on demand, with a bad input, and a
cancelled job; then renders the animation again with motion blur on (no vectors: radn estimates
motion), with a motion-blurred reference and per-frame OIDN. The test asserts on what this
prints."""

from __future__ import annotations

import glob
import hashlib
import json
import math
import os
import sys
import time

import bpy
import numpy as np
import OpenEXR

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", ".."))
FRAMES = range(1, 6)
LOW_SPP, REF_SPP = 8, 256


def build_scene() -> bpy.types.Scene:
    """A small textured set with a glossy sphere and a camera that moves over five frames."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.use_animated_seed = True
    scene.cycles.max_bounces = 6
    scene.render.resolution_x, scene.render.resolution_y = 192, 108
    scene.render.resolution_percentage = 100
    scene.frame_start, scene.frame_end = FRAMES[0], FRAMES[-1]

    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.05, 0.06, 0.08, 1)
    scene.world = world

    def material(name, build):
        m = bpy.data.materials.new(name)
        m.use_nodes = True
        build(m.node_tree)
        return m

    def bricks(tree):
        nodes, links = tree.nodes, tree.links
        bsdf = nodes["Principled BSDF"]
        tex = nodes.new("ShaderNodeTexBrick")
        tex.inputs["Scale"].default_value = 12.0
        tex.inputs["Color1"].default_value = (0.6, 0.25, 0.15, 1)
        tex.inputs["Color2"].default_value = (0.35, 0.3, 0.28, 1)
        links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])

    def glossy(tree):
        bsdf = tree.nodes["Principled BSDF"]
        bsdf.inputs["Metallic"].default_value = 1.0
        bsdf.inputs["Roughness"].default_value = 0.15
        bsdf.inputs["Base Color"].default_value = (0.9, 0.7, 0.3, 1)

    def diffuse(tree):
        tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.1, 0.35, 0.7, 1)

    bpy.ops.mesh.primitive_plane_add(size=20)
    bpy.context.object.data.materials.append(material("bricks", bricks))
    bpy.ops.mesh.primitive_cube_add(size=1.5, location=(-1.6, 0.5, 0.75))
    bpy.context.object.data.materials.append(material("blue", diffuse))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.9, location=(0.8, -0.2, 0.9))
    bpy.ops.object.shade_smooth()
    bpy.context.object.data.materials.append(material("gold", glossy))
    bpy.ops.object.light_add(type="AREA", location=(2.5, -2.0, 4.0))
    bpy.context.object.data.energy = 600
    bpy.context.object.data.size = 1.0
    bpy.ops.object.light_add(type="POINT", location=(-3.0, 2.0, 2.0))
    bpy.context.object.data.energy = 150

    bpy.ops.object.camera_add(location=(0, -7, 3), rotation=(math.radians(70), 0, 0))
    cam = bpy.context.object
    scene.camera = cam
    for f, x in zip(FRAMES, np.linspace(-0.8, 0.8, len(FRAMES))):
        cam.location.x = float(x)
        cam.keyframe_insert("location", frame=f)
    return scene


def render(scene, folder, spp):
    """Renders the animation to folder/####.exr at `spp`."""
    scene.cycles.samples = spp
    scene.render.filepath = os.path.join(folder, "")
    bpy.ops.render.render(animation=True)


def beauty(path):
    """The beauty of a Cycles multilayer EXR (Combined, or Noisy Image where Cycles denoised)."""
    with OpenEXR.File(path, separate_channels=True) as f:
        ch = f.channels()
        rgb = [ch[f"ViewLayer.Combined.{c}"].pixels for c in "RGB"]
        return np.stack(rgb, -1).astype(np.float64), sorted(ch)


def tonemap(x):
    return np.clip(x, 0, 1) ** (1 / 2.2)


def scores(folder, ref):
    """PSNR (dB, tonemapped, mean over frames) and tMAE (temporal differences) against ref."""
    psnr, tmae, prev = [], [], None
    for f in FRAMES:
        a = tonemap(beauty(os.path.join(folder, f"{f:04d}.exr"))[0])
        r = tonemap(beauty(os.path.join(ref, f"{f:04d}.exr"))[0])
        psnr.append(10 * math.log10(1 / np.mean((a - r) ** 2)))
        if prev is not None:
            tmae.append(np.mean(np.abs((a - prev[0]) - (r - prev[1]))))
        prev = (a, r)
    return {"psnr": float(np.mean(psnr)), "tmae": float(np.mean(tmae))}


def digest(folder):
    return {os.path.basename(p): hashlib.sha256(open(p, "rb").read()).hexdigest()
            for p in sorted(glob.glob(os.path.join(folder, "*.exr")))}


def main(zip_path, work):
    out = {}
    scene = build_scene()
    r = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
    out["installed"] = sorted(r)
    out["enabled"] = "bl_ext.user_default.radn_denoise" in bpy.context.preferences.addons
    scene = bpy.context.scene
    scene.radn.after_animation = True  # turns on Denoising Data, Vector, multilayer EXR
    layer = scene.view_layers[0]
    out["passes_on"] = [layer.cycles.denoising_store_passes, layer.use_pass_vector,
                        scene.render.image_settings.file_format]

    low = os.path.join(work, "render")
    t = time.perf_counter()
    render(scene, low, LOW_SPP)  # the extension denoises into render/radn/ when it completes
    out["render_and_denoise_s"] = time.perf_counter() - t
    before = digest(low)
    denoised = os.path.join(low, "radn")
    out["denoised_frames"] = sorted(os.listdir(denoised)) if os.path.isdir(denoised) else []
    out["layers_kept"] = all(
        beauty(os.path.join(low, n))[1] == beauty(os.path.join(denoised, n))[1] for n in out["denoised_frames"]
    )

    scene.radn.after_animation = False
    ref = os.path.join(work, "ref")
    t = time.perf_counter()
    render(scene, ref, REF_SPP)
    out["reference_s"] = time.perf_counter() - t
    out["reference_not_denoised"] = not os.path.exists(os.path.join(ref, "radn"))

    sys.path.insert(0, os.path.join(ROOT, "tools", "datagen"))
    from radn_datagen.oidn import denoise_folder

    oidn = os.path.join(work, "oidn")
    denoise_folder(low, oidn, log=lambda *_: None)
    out["noisy"] = scores(low, ref)
    out["oidn"] = scores(oidn, ref)
    out["radn"] = scores(denoised, ref)

    # on demand, over an existing sequence, with a frame range and an output folder
    ondemand = os.path.join(work, "ondemand", "")
    res = bpy.ops.radn.denoise_sequence(input=os.path.join(low, "####.exr"), output=ondemand, frames="2-4")
    out["on_demand"] = [sorted(res), sorted(os.listdir(ondemand))]
    # a bad input is reported as an error (which a script calling the operator gets raised)
    try:
        res = bpy.ops.radn.denoise_sequence(input=os.path.join(work, "missing", "####.exr"), output=ondemand)
        out["bad_input"] = sorted(res)
    except RuntimeError as e:
        out["bad_input"] = str(e)

    # a cancelled run (the operator's background job) leaves no partial file
    from bl_ext.user_default.radn_denoise import job as radn_job
    from bl_ext.user_default.radn_denoise import operators

    cancelled = os.path.join(work, "cancelled")
    request = operators.request_for(scene, os.path.join(low, "####.exr"), None)
    request.output = os.path.join(cancelled, "####.exr")
    holder = {}

    def stop_soon(done, total):
        holder["job"].cancel()

    job = holder["job"] = radn_job.DenoiseJob(request, on_progress=stop_soon)
    job.start()
    job.wait(120)
    out["cancel"] = {"done": job.done, "cancelled": job.cancelled, "error": job.error,
                     "left": sorted(os.listdir(cancelled)) if os.path.isdir(cancelled) else []}
    out["render_untouched"] = digest(low) == before
    out["oidn_library"] = request.oidn_library

    # motion blur on: Cycles writes no usable vectors, and the extension has radn estimate motion
    from bl_ext.user_default.radn_denoise import passes as radn_passes

    scene.render.use_motion_blur = True
    scene.radn.after_animation = True
    out["blur_motion_source"] = radn_passes.motion_source(scene)
    out["blur_problems"] = radn_passes.problems(scene)
    blur = os.path.join(work, "blur")
    render(scene, blur, LOW_SPP)
    scene.radn.after_animation = False
    blur_ref = os.path.join(work, "blur-ref")
    render(scene, blur_ref, REF_SPP)
    blur_oidn = os.path.join(work, "blur-oidn")
    denoise_folder(blur, blur_oidn, log=lambda *_: None)
    blur_radn = os.path.join(blur, "radn")
    out["blur_denoised_frames"] = sorted(os.listdir(blur_radn)) if os.path.isdir(blur_radn) else []
    out["blur"] = {"noisy": scores(blur, blur_ref), "oidn": scores(blur_oidn, blur_ref),
                   "radn": scores(blur_radn, blur_ref)}
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
