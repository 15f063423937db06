"""Rendering a scene's frames at several sample counts into radn's generic EXR layout:
`R,G,B,A`, `albedo.R/G/B` and `N.X/Y/Z` (averaged over each pixel's samples, box filter),
`Z` (distance along the centre ray), `motion.X/Y` and `motion_next.X/Y` (exact, see motion.py), and
with `variance=True` `variance.R/G/B`: the variance of each pixel's mean, from the second moment
of its samples (what production renderers write as variance AOVs for denoisers).
Every file is written to a temporary name and renamed, so a stopped run leaves only whole frames
and a re-run skips them."""

from __future__ import annotations

import json
import os
import time

import numpy as np
import OpenEXR

from . import motion
from .backend import mitsuba

#: bumped when the same seed would render differently (a split must not mix versions)
GENERATOR_VERSION = 2


def seed_of(scene_seed: int, level: str, frame: int) -> int:
    """The sampler seed of one render: independent across scenes, levels and frames."""
    h = 1469598103934665603
    for v in (scene_seed, sum(map(ord, level)) * 131 + len(level), frame):
        h = ((h ^ v) * 1099511628211) % (1 << 64)
    return h % (1 << 32)


def write_exr(path: str, channels: dict) -> None:
    """Writes `channels` (name → H×W array) atomically, ZIP-compressed."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.tmp")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    chans = {k: OpenEXR.Channel(np.ascontiguousarray(v)) for k, v in channels.items()}
    OpenEXR.File(header, chans).write(tmp)
    os.replace(tmp, path)


def aux_and_motion(spec, frame):
    """Depth and motion towards both neighbours for `frame` (channels), and per pixel the
    radiance of the light its centre ray sees (NaN elsewhere). Null-material shapes, smoke's
    bounds, are left out: rays pass through them."""
    mi = mitsuba()
    d = spec.dict_at(frame, aovs=False)
    for key, value in list(d.items()):
        if isinstance(value, dict) and value.get("bsdf", {}).get("type") == "null":
            del d[key]
    scene = mi.load_dict(d)
    points, keys, dist = motion.visible_points(spec, frame, scene)
    h, w = spec.height, spec.width
    prev = motion.motion_to(spec, frame, frame - 1, points, keys)
    nxt = motion.motion_to(spec, frame, frame + 1, points, keys)
    emitted = np.full((h * w, 3), np.nan, np.float32)
    for key in set(keys) - {""}:
        radiance = spec.emission(key)
        if radiance is not None:
            emitted[keys == key] = radiance
    return {
        "Z": dist.reshape(h, w).astype(np.float32),
        "motion.X": prev[..., 0].astype(np.float32), "motion.Y": prev[..., 1].astype(np.float32),
        "motion_next.X": nxt[..., 0].astype(np.float32), "motion_next.Y": nxt[..., 1].astype(np.float32),
    }, emitted.reshape(h, w, 3)


def denoiser_albedo(albedo, normal, environment, emitted):
    """The albedo as renderers write it for denoisers (Cycles' Denoising Albedo, OIDN's
    convention): reflectance on surfaces, the environment's colour where rays hit nothing, the
    emitted radiance on visible lights. Mitsuba's albedo AOV is 0 for both; a pixel's share of
    missed rays is 1 − |mean shading normal| (misses add a zero normal)."""
    coverage = np.clip(np.linalg.norm(normal, axis=-1, keepdims=True), 0.0, 1.0)
    out = albedo + (1.0 - coverage) * np.asarray(environment, np.float32)
    lit = ~np.isnan(emitted[..., :1])
    return np.where(lit, emitted, out).astype(np.float32)


def render_layers(scene, spp: int, seed: int, environment=(0.0, 0.0, 0.0), emitted=None) -> dict:
    """Beauty, albedo and shading normal of one render, as generic-layout channels (`emitted`:
    per pixel the radiance of the light its centre ray sees, NaN elsewhere); and the variance of
    the beauty's pixel means where `scene` was loaded with SceneSpec.dict_at(variance=True)."""
    mi = mitsuba()
    mi.render(scene, spp=spp, seed=seed)
    layers = {k: np.array(v, dtype=np.float32) for k, v in scene.sensors()[0].film().bitmap().split()}
    moment = "m.img" in layers  # wrapped in the moment integrator: its layers carry a prefix
    pre = "m." if moment else ""
    beauty = layers[f"{pre}img"][..., :3] if moment else layers["<root>"]
    albedo = layers[f"{pre}albedo"]
    normal = layers[f"{pre}nn"]
    if emitted is None:
        emitted = np.full(beauty.shape, np.nan, np.float32)
    albedo = denoiser_albedo(albedo, normal, environment, emitted)
    out = {c: beauty[..., i] for i, c in enumerate("RGB")}
    out["A"] = np.ones(beauty.shape[:2], np.float32)
    out.update({f"albedo.{c}": albedo[..., i] for i, c in enumerate("RGB")})
    out.update({f"N.{c}": normal[..., i] for i, c in enumerate("XYZ")})
    bad = sum(int((~np.isfinite(v)).sum()) for v in out.values())
    if bad:  # rare fireflies of NaN in Mitsuba's output: zero them, as a renderer's film would
        out = {k: np.nan_to_num(v, nan=0.0, posinf=0.0, neginf=0.0) for k, v in out.items()}
    out = {k: v.astype(np.float16) for k, v in out.items()}
    if moment:
        # unbiased sample variance of the pixel's samples over spp: the variance of its mean
        # (the box filter weighs a pixel's samples equally); float32, small values matter
        second = layers["m2_m.img"][..., :3]
        var = np.maximum(second - beauty * beauty, 0.0) / max(spp - 1, 1)
        var = np.nan_to_num(var, nan=0.0, posinf=0.0, neginf=0.0)
        out.update({f"variance.{c}": var[..., i].astype(np.float32) for i, c in enumerate("RGB")})
    return out


def render_scene(spec, out_dir: str, frames, levels: dict, log=print, variance: bool = False) -> dict:
    """Renders `frames` of `spec` at each level (name → spp) into out_dir/<level>/frame_####.exr,
    with `variance.R/G/B` where `variance`; returns the manifest it writes
    (out_dir/manifest.json)."""
    mi = mitsuba()
    manifest_path = os.path.join(out_dir, "manifest.json")
    manifest = {"seed": spec.seed, "generator_version": GENERATOR_VERSION, "renderer": f"mitsuba {mi.__version__} {mi.variant()}",
                "layout": "<scene>/<level>/frame_####.exr (radn's generic preset)",
                "resolution": [spec.width, spec.height], "frames": [min(frames), max(frames)],
                "shot_frames": spec.frames, "scene": spec.description, "levels": {}}
    if os.path.exists(manifest_path):
        old = json.load(open(manifest_path))
        if old.get("generator_version") != GENERATOR_VERSION:
            raise SystemExit(f"{out_dir}: rendered by generator version {old.get('generator_version', 1)}, "
                             f"this is {GENERATOR_VERSION}: render the scene again whole (remove the folder)")
        manifest["levels"] = old.get("levels", {})
        if old.get("levels") and bool(old.get("variance")) != variance:
            raise SystemExit(f"{out_dir}: rendered {'with' if old.get('variance') else 'without'} variance "
                             f"channels, this run {'with' if variance else 'without'}: use another folder")
    manifest["variance"] = variance
    for frame in frames:
        todo = {lv: spp for lv, spp in levels.items()
                if not os.path.exists(os.path.join(out_dir, lv, f"frame_{frame:04d}.exr"))}
        if not todo:
            continue
        aux, emitted = aux_and_motion(spec, frame)
        scene = mi.load_dict(spec.dict_at(frame, variance=variance))
        for lv, spp in todo.items():
            t = time.perf_counter()
            chans = render_layers(scene, spp, seed_of(spec.seed, lv, frame), spec.environment(), emitted)
            chans.update(aux)
            write_exr(os.path.join(out_dir, lv, f"frame_{frame:04d}.exr"), chans)
            secs = time.perf_counter() - t
            info = manifest["levels"].setdefault(lv, {"spp": spp, "seconds": 0.0, "frames": 0})
            info["seconds"] += secs
            info["frames"] += 1
            log(f"scene {spec.seed} frame {frame} {lv} ({spp} spp): {secs:.1f} s")
        tmp = manifest_path + ".tmp"
        with open(tmp, "w") as f:
            json.dump(manifest, f, indent=1, sort_keys=True)
        os.replace(tmp, manifest_path)
    return manifest
