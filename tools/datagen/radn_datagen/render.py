"""Rendering a built scene at radn's noise levels into the dataset layout.

Layout: ``<out>/<scene>/<level>/frame_####.exr`` with level in ``high`` (n spp), ``half``
(floor(n/e) spp), ``low`` (4 spp) and ``ref`` (optional high-sample reference), plus
``<out>/<scene>/manifest.json``. Files already present are skipped, so an interrupted run
continues where it stopped.
"""
import json
import os
import time

import bpy

from . import LEVELS, REFERENCE
from .levels import level_spp, sampling_seed


def configure(scene, exr_half=False, clamp_indirect=10.0, threads=0, cycles_denoise=False, motion_blur=False):
    """Cycles on the CPU with radn's passes, no adaptive sampling, no motion blur unless
    `motion_blur` (a half-frame shutter centred on the frame; Cycles then writes its Vector pass
    as zeros, and radn finds the motion itself), and no denoising unless `cycles_denoise`: then
    Cycles' own OIDN runs (albedo + normal prefiltered to "accurate") and, with the denoising
    data stored, each file holds the noisy beauty as "Noisy Image" and Cycles' denoised one as
    "Combined" (radn's `--guide denoised`)."""
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.use_denoising = bool(cycles_denoise)
    if cycles_denoise:
        scene.cycles.denoiser = "OPENIMAGEDENOISE"
        scene.cycles.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        scene.cycles.denoising_prefilter = "ACCURATE"
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_animated_seed = False
    scene.cycles.sample_clamp_indirect = clamp_indirect
    scene.cycles.time_limit = 0
    scene.render.use_motion_blur = bool(motion_blur)
    if motion_blur:
        scene.render.motion_blur_shutter = 0.5
        scene.render.motion_blur_position = "CENTER"
    scene.render.film_transparent = False
    if threads:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = threads
    vl = scene.view_layers[0]
    vl.use_pass_combined = True
    vl.use_pass_vector = True
    vl.use_pass_z = True
    vl.use_pass_normal = True
    vl.cycles.denoising_store_passes = True  # Denoising Albedo / Normal / Depth
    s = scene.render.image_settings
    s.file_format = "OPEN_EXR_MULTILAYER"
    s.color_depth = "16" if exr_half else "32"
    s.exr_codec = "PIZ" if exr_half else "ZIP"
    scene.render.use_file_extension = False


def frame_path(out_dir, level, frame):
    return os.path.join(out_dir, level, f"frame_{frame:04d}.exr")


def render_frame(scene, path, spp, seed, frame):
    """Renders one frame to `path` atomically (temporary file, then rename). Returns seconds."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = path + ".tmp"
    scene.cycles.samples = spp
    scene.cycles.seed = seed
    scene.frame_set(frame)
    scene.render.filepath = tmp
    t0 = time.time()
    bpy.ops.render.render(write_still=True)
    os.replace(tmp, path)
    return time.time() - t0


def render_levels(scene, out_dir, scene_seed, frames, spp, reference_spp=0, reference_frames=None,
                  levels=LEVELS, extra=None, extra_frames=None, log=print, before_first_render=None):
    """Renders every frame at every level (and the reference frames), skipping existing files.
    `extra` maps further level names to their sample counts (higher input levels, the teacher
    render); each is an independent render with its own sampling seed. `extra_frames` limits the
    extra levels to a sub-range of `frames` (a cleaner, independent reference of a few frames:
    the scene is still built over all of `frames`, since its camera shake depends on the range).
    `before_first_render` is called once, before the first frame this run renders."""
    jobs = [(lv, n, f) for lv, n in level_spp(spp).items() if lv in levels for f in range(frames[0], frames[1] + 1)]
    ef = extra_frames or frames
    if not (frames[0] <= ef[0] <= ef[1] <= frames[1]):
        raise ValueError(f"extra frames {ef[0]}-{ef[1]} are not within the frames {frames[0]}-{frames[1]}")
    jobs += [(lv, n, f) for lv, n in (extra or {}).items() for f in range(ef[0], ef[1] + 1)]
    spps = {lv: n for lv, n, _ in jobs}
    if reference_spp:
        rf = reference_frames or frames
        spps[REFERENCE] = reference_spp
        jobs += [(REFERENCE, reference_spp, f) for f in range(rf[0], rf[1] + 1)]
    timings = {}
    done = 0
    for level, n, f in jobs:
        path = frame_path(out_dir, level, f)
        done += 1
        if os.path.exists(path):
            continue
        if before_first_render is not None:
            before_first_render()
            before_first_render = None
        secs = render_frame(scene, path, n, sampling_seed(scene_seed, level, f), f)
        timings.setdefault(level, []).append(secs)
        log(f"[{done}/{len(jobs)}] {path}: {n} spp in {secs:.1f} s")
    return {lv: {"spp": n, "seconds_per_frame": (sum(t) / len(t) if (t := timings.get(lv)) else None)}
            for lv, n in spps.items()}


def write_manifest(out_dir, info):
    """Writes (or updates) the scene's manifest.json atomically."""
    path = os.path.join(out_dir, "manifest.json")
    old = {}
    if os.path.exists(path):
        with open(path) as f:
            old = json.load(f)
    # keep timings measured by an earlier, interrupted run
    for lv, v in old.get("levels", {}).items():
        new = info.get("levels", {}).get(lv)
        if new is not None and new.get("seconds_per_frame") is None:
            new["seconds_per_frame"] = v.get("seconds_per_frame")
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(info, f, indent=2, sort_keys=True)
    os.replace(tmp, path)
    return path
