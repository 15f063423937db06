"""Command line: render one scene, or a whole dataset split, at radn's noise levels.

    python -m radn_datagen scene   --seed 7 --out data/sample --frames 1-9 --res 256x144 --spp 32 --reference-spp 1024
    python -m radn_datagen dataset --split train --scenes 40 --frames 1-16 --res 256x256 --out data/train
"""
import argparse
import os
import sys
import time

from . import LEVELS
from . import render, scene as scenes

# Disjoint seed ranges per split, so no scene is ever in two splits.
SPLIT_BASE = {"train": 1_000_000, "val": 2_000_000, "test": 3_000_000}


def parse_range(text):
    a, _, b = text.partition("-")
    return (int(a), int(b or a))


def parse_res(text):
    w, _, h = text.lower().partition("x")
    return (int(w), int(h))


def render_scene(seed, out, frames, res, spp, reference_spp, reference_frames, half, threads, layout=None,
                 calibration=False, levels=LEVELS, log=print):
    import bpy  # noqa: F401  (imported here so --help works without bpy)

    t0 = time.time()
    if calibration:
        desc = scenes.build_calibration(frames=frames, resolution=res)
    else:
        desc = scenes.build(seed, frames=frames, resolution=res, layout=layout)
    sc = scenes.bpy.context.scene
    render.configure(sc, exr_half=half, threads=threads)
    for lv in levels:
        if lv not in LEVELS:
            raise SystemExit(f"unknown level '{lv}'; known: {', '.join(LEVELS)}")
    done = render.render_levels(sc, out, seed, frames, spp, reference_spp, reference_frames, levels=levels, log=log)
    info = {
        "seed": seed,
        "frames": list(frames),
        "resolution": list(res),
        "levels": done,
        "reference_frames": list(reference_frames or frames) if reference_spp else [],
        "layout": "<scene>/<level>/frame_####.exr",
        "exr": "multilayer half PIZ" if half else "multilayer float ZIP",
        "renderer": f"Blender {scenes.bpy.app.version_string} Cycles (CPU)",
        "passes": ["Combined", "Denoising Albedo", "Denoising Normal", "Denoising Depth", "Vector", "Depth", "Normal"],
        "render_seconds_this_run": round(time.time() - t0, 1),
        "scene": desc,
    }
    return render.write_manifest(out, info)


def main(argv=None):
    p = argparse.ArgumentParser(prog="radn_datagen", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--frames", default="1-9", help="frame range, e.g. 1-16")
    common.add_argument("--res", default="256x256", help="resolution WxH")
    common.add_argument("--spp", type=int, default=32, help="n: samples of the 'high' level")
    common.add_argument("--reference-spp", type=int, default=0, help="also render a reference at this many spp")
    common.add_argument("--reference-frames", default=None, help="frame range of the reference (default: all)")
    common.add_argument("--half", action="store_true", help="write half-float PIZ EXRs (smaller)")
    common.add_argument("--threads", type=int, default=0, help="render threads (0: all cores)")
    common.add_argument("--layout", choices=["indoor", "outdoor"], default=None, help="force a layout")
    common.add_argument("--levels", default=",".join(LEVELS), help="noise levels to render (comma-separated)")
    s = sub.add_parser("scene", parents=[common], help="render one scene")
    s.add_argument("--seed", type=int, required=True)
    s.add_argument("--out", required=True, help="the scene's folder")
    s.add_argument("--calibration", action="store_true", help="the known-motion calibration scene")
    t = sub.add_parser("trim", help="copy a scene keeping only the passes radn reads (for the shipped sample)")
    t.add_argument("src")
    t.add_argument("dst")
    t.add_argument("--crop", default=None, help="x,y,w,h: keep only this region")
    d = sub.add_parser("dataset", parents=[common], help="render a split of S scenes")
    d.add_argument("--split", choices=sorted(SPLIT_BASE), required=True)
    d.add_argument("--scenes", type=int, required=True)
    d.add_argument("--out", required=True, help="the split's folder; scenes go in scene_<seed>/")
    a = p.parse_args(argv)
    if a.cmd == "trim":
        from .trim import trim_scene
        crop = tuple(int(v) for v in a.crop.split(",")) if a.crop else None
        print(f"wrote {trim_scene(a.src, a.dst, crop)}")
        return 0
    frames = parse_range(a.frames)
    res = parse_res(a.res)
    ref_frames = parse_range(a.reference_frames) if a.reference_frames else None
    if a.cmd == "scene":
        m = render_scene(a.seed, a.out, frames, res, a.spp, a.reference_spp, ref_frames, a.half, a.threads,
                         a.layout, a.calibration, levels=tuple(a.levels.split(",")))
        print(f"wrote {m}")
        return 0
    t0 = time.time()
    for i in range(a.scenes):
        seed = SPLIT_BASE[a.split] + i
        out = os.path.join(a.out, f"scene_{seed}")
        print(f"scene {i + 1}/{a.scenes} (seed {seed}) -> {out}   elapsed {time.time() - t0:.0f} s", flush=True)
        render_scene(seed, out, frames, res, a.spp, a.reference_spp, ref_frames, a.half, a.threads, a.layout,
                     levels=tuple(a.levels.split(",")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
