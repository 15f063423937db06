"""python3 -m radn_heldout scene|dataset: render held-out Cycles scenes in radn's layout."""
import argparse
import json
import os
import sys
import time

import numpy as np

from . import LEVELS, REFERENCE
from .families import BUILDERS
from .render import configure, render_scene, write_manifest
from .scenes import FAMILIES, reset

GENERATOR_VERSION = 1
PATTERNS = ("AUTOMATIC", "TABULATED_SOBOL", "BLUE_NOISE")
WIDTHS = (160, 192, 224, 256, 320)


def span(text):
    a, _, b = text.partition("-")
    return int(a), int(b or a)


def levels(text):
    out = {}
    for item in text.split(","):
        name, _, spp = item.partition(":")
        out[name] = int(spp)
    return out


def build_and_render(seed, out, frames, lv, ref_spp, ref_frames, family=None, res=None, log=print,
                     motion_blur=False, camera_speed=1.0):
    """Builds scene `seed` (its family, size, sampler and clamp drawn from the seed unless given)
    and renders it into `out`, with motion blur and a camera `camera_speed` times as fast where
    asked."""
    rng = np.random.default_rng(seed)
    family = family or FAMILIES[seed % len(FAMILIES)]
    w = int(rng.choice(WIDTHS))
    res = res or (w, int(round(w * float(rng.choice([9 / 16, 2 / 3, 3 / 4])) / 2) * 2))
    pattern, clamp = str(rng.choice(PATTERNS)), float(rng.choice([0.0, 20.0, 50.0]))
    reset()
    import bpy
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    scene.render.resolution_x, scene.render.resolution_y = res
    scene.render.resolution_percentage = 100
    scene["radn_camera_speed"] = camera_speed
    drawn = BUILDERS[family](rng, frames)
    configure(scene, pattern, clamp, motion_blur)
    t0 = time.time()
    secs = render_scene(scene, out, seed, frames, lv, ref_spp, ref_frames, log=log)
    write_manifest(out, {
        "generator": "radn_heldout", "generator_version": GENERATOR_VERSION, "seed": seed, "family": family,
        "resolution": list(res), "frames": list(frames), "levels": lv, "reference_spp": ref_spp,
        "reference_frames": list(ref_frames), "sampling_pattern": pattern, "clamp_indirect": clamp,
        "renderer": f"Blender {bpy.app.version_string} Cycles (CPU)", "scene": drawn,
        "layout": "<scene>/<level>/frame_####.exr (Cycles multilayer passes)",
        "motion_blur": "half-frame shutter centred on the frame; the Vector pass is all zero" if motion_blur
        else "off", "camera_speed": camera_speed,
        "seconds_per_frame": secs, "render_seconds_this_run": round(time.time() - t0, 1)})


def join(out, first, second):
    """A sequence with a cut: every level folder the two scenes share, the first scene's frames
    then the second's, numbered on (where both have references, the first up to its last
    reference frame and the second from its first); returns the last frame before the cut."""
    import shutil

    def frames_of(folder):
        return sorted(int(n[6:10]) for n in os.listdir(folder) if n.startswith("frame_") and n.endswith(".exr"))

    shared = sorted(set(os.listdir(first)) & set(os.listdir(second)))
    shared = [lv for lv in shared if os.path.isdir(os.path.join(first, lv))]
    if not shared:
        raise SystemExit(f"{first} and {second} share no level folder")
    if os.path.exists(out):
        raise SystemExit(f"{out} exists; choose a new folder")
    # an edit cuts between shots of one format: radn refuses sequences whose frames differ in size
    sizes = [json.load(open(os.path.join(s, "manifest.json"))).get("resolution") for s in (first, second)]
    if sizes[0] != sizes[1]:
        raise SystemExit(f"{first} is {'x'.join(map(str, sizes[0]))} and {second} is "
                         f"{'x'.join(map(str, sizes[1]))}: render the second at the first's size "
                         "(radn_heldout scene --res)")
    # where both have references, the first scene ends on its last reference frame and the
    # second starts on its first, so the frames beside the cut can be scored
    refs = REFERENCE in shared
    last = max(frames_of(os.path.join(first, REFERENCE if refs else shared[0])))
    start = min(frames_of(os.path.join(second, REFERENCE if refs else shared[0])))
    for lv in shared:
        os.makedirs(os.path.join(out, lv))
        for f in frames_of(os.path.join(first, lv)):
            if f <= last:
                shutil.copy(os.path.join(first, lv, f"frame_{f:04d}.exr"),
                            os.path.join(out, lv, f"frame_{f:04d}.exr"))
        for f in frames_of(os.path.join(second, lv)):
            if f >= start:
                shutil.copy(os.path.join(second, lv, f"frame_{f:04d}.exr"),
                            os.path.join(out, lv, f"frame_{last + 1 + f - start:04d}.exr"))
    write_manifest(out, {"generator": "radn_heldout", "join": [os.path.abspath(first), os.path.abspath(second)],
                         "cut_after": last, "levels": shared,
                         "layout": "<scene>/<level>/frame_####.exr (Cycles multilayer passes)"})
    return last


def main(argv=None):
    ap = argparse.ArgumentParser(prog="radn_heldout", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    j = sub.add_parser("join", help="a sequence with a cut: two rendered scenes one after the other")
    j.add_argument("--out", required=True)
    j.add_argument("first")
    j.add_argument("second")
    for name in ("scene", "dataset"):
        p = sub.add_parser(name)
        p.add_argument("--motion-blur", action="store_true",
                       help="render with motion blur (Cycles then writes no usable Vector pass)")
        p.add_argument("--camera-speed", type=float, default=1.0,
                       help="the camera runs this many times as far along its path in the same frames")
        p.add_argument("--out", required=True)
        p.add_argument("--frames", type=span, default=(1, 10))
        p.add_argument("--levels", type=levels, default=dict(LEVELS))
        p.add_argument("--reference-spp", type=int, default=1024)
        p.add_argument("--reference-frames", type=span, default=(4, 7))
        if name == "scene":
            p.add_argument("--seed", type=int, required=True)
            p.add_argument("--family", choices=FAMILIES)
            p.add_argument("--res", type=lambda s: tuple(int(v) for v in s.split("x")))
        else:
            p.add_argument("--scenes", type=int, default=4)
            p.add_argument("--first-seed", type=int, default=11_000_000)
    a = ap.parse_args(argv)
    if a.cmd == "join":
        print(f"cut after frame {join(a.out, a.first, a.second)} -> {a.out}")
        return 0
    if a.cmd == "scene":
        build_and_render(a.seed, a.out, a.frames, a.levels, a.reference_spp, a.reference_frames, a.family, a.res,
                         motion_blur=a.motion_blur, camera_speed=a.camera_speed)
        return 0
    for i in range(a.scenes):
        seed = a.first_seed + i
        out = os.path.join(a.out, f"scene_{seed}")
        print(f"scene {seed} -> {out}", flush=True)
        build_and_render(seed, out, a.frames, a.levels, a.reference_spp, a.reference_frames,
                         motion_blur=a.motion_blur, camera_speed=a.camera_speed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
