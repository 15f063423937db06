"""Cycles settings, seeds and the dataset layout: `<scene>/<level>/frame_####.exr` (Cycles'
multilayer passes, radn's `cycles` preset) and `<scene>/manifest.json`. Files already present are
skipped, so an interrupted run continues where it stopped."""
import hashlib
import json
import os
import time

import bpy

from . import REFERENCE


def sampling_seed(scene_seed: int, level: str, frame: int) -> int:
    """An independent Cycles seed per scene, level and frame (every render's noise is its own)."""
    h = hashlib.blake2s(f"heldout/{scene_seed}/{level}/{frame}".encode(), digest_size=4)
    return int.from_bytes(h.digest(), "little") & 0x7FFFFFFF


def configure(scene, pattern: str, clamp_indirect: float, motion_blur: bool = False):
    """CPU Cycles with the passes radn reads, no adaptive sampling and no denoising; float EXR.
    With `motion_blur` a half-frame shutter centred on the frame: Cycles then writes its Vector
    pass as zeros, and radn finds the motion itself."""
    c = scene.cycles
    scene.render.engine = "CYCLES"
    c.device = "CPU"
    c.use_denoising = False
    c.use_adaptive_sampling = False
    c.sampling_pattern = pattern
    c.sample_clamp_indirect = clamp_indirect
    c.max_bounces = 8
    scene.render.use_motion_blur = motion_blur
    if motion_blur:
        scene.render.motion_blur_shutter = 0.5
        scene.render.motion_blur_position = "CENTER"
    scene.render.film_transparent = False
    vl = scene.view_layers[0]
    for p in ("combined", "vector", "z", "normal"):
        setattr(vl, f"use_pass_{p}", True)
    vl.cycles.denoising_store_passes = True
    im = scene.render.image_settings
    im.file_format = "OPEN_EXR_MULTILAYER"
    im.color_depth = "32"
    im.exr_codec = "ZIP"
    scene.render.use_file_extension = False


def render_scene(scene, out_dir, seed, frames, levels, reference_spp, reference_frames, log=print):
    """Every frame at every level, then the reference frames; returns seconds per frame per level."""
    jobs = [(lv, n, f) for lv, n in levels.items() for f in range(frames[0], frames[1] + 1)]
    if reference_spp:
        jobs += [(REFERENCE, reference_spp, f) for f in range(reference_frames[0], reference_frames[1] + 1)]
    timings = {}
    for i, (level, spp, f) in enumerate(jobs, 1):
        path = os.path.join(out_dir, level, f"frame_{f:04d}.exr")
        if os.path.exists(path):
            continue
        os.makedirs(os.path.dirname(path), exist_ok=True)
        scene.cycles.samples = spp
        scene.cycles.seed = sampling_seed(seed, level, f)
        scene.frame_set(f)
        scene.render.filepath = path + ".tmp"
        t0 = time.time()
        bpy.ops.render.render(write_still=True)
        os.replace(path + ".tmp", path)
        timings.setdefault(level, []).append(time.time() - t0)
        log(f"[{i}/{len(jobs)}] {path}: {spp} spp in {timings[level][-1]:.1f} s")
    return {lv: sum(t) / len(t) for lv, t in timings.items()}


def write_manifest(out_dir, info):
    """The scene's manifest.json, written atomically and merged with what an earlier run wrote."""
    path = os.path.join(out_dir, "manifest.json")
    old = {}
    if os.path.exists(path):
        with open(path) as f:
            old = json.load(f)
    seconds = {**old.get("seconds_per_frame", {}), **info.pop("seconds_per_frame", {})}
    old.update(info, seconds_per_frame=seconds)
    with open(path + ".tmp", "w") as f:
        json.dump(old, f, indent=1, sort_keys=True)
    os.replace(path + ".tmp", path)
