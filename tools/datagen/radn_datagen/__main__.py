"""Command line: render one scene, or a whole dataset split, at radn's noise levels.

    python -m radn_datagen scene   --seed 7 --out data/sample --frames 1-9 --res 256x144 --spp 32 --reference-spp 1024
    python -m radn_datagen dataset --split train --scenes 40 --frames 1-16 --res 256x256 --out data/train
    python -m radn_datagen dataset --split detail-train --scenes 90 --spp 32,64,128,256 --teacher-spp 1x ...
    python -m radn_datagen oidn IN_DIR OUT_DIR      # OIDN 2.5 on every frame of a folder
    python -m radn_datagen oidn IN_DIR OUT_DIR --mode noisy-aux --timings t.json
    python -m radn_datagen combine ref:512 spp2048:2048 --out ref3072   # one cleaner reference
"""
import argparse
import os
import sys
import time

from . import LEVELS
from . import hair_record, render, scene as scenes
from .levels import extra_level, level_spp, per_scene_choice
from .oidn import MODES as OIDN_MODES

# Disjoint seed ranges per split, so no scene is ever in two splits. The detail splits hold
# scenes with fine detail (`detail.py`); detail-test is held aside: never used for training or
# model selection. The fur splits hold scenes with fur and grass (`fur.py`); fur-test is held aside.
# The contact splits add glass standing on a textured floor (`contact.py`); contact-test is held aside.
SPLIT_BASE = {"train": 1_000_000, "val": 2_000_000, "test": 3_000_000,
              "detail-test": 4_000_000, "detail-train": 5_000_000, "detail-val": 6_000_000,
              "fur-train": 7_000_000, "fur-val": 8_000_000, "fur-test": 9_000_000,
              "contact-train": 10_000_000, "contact-val": 11_000_000, "contact-test": 12_000_000}
TEACHER = "teacher"
TEACHER_OIDN = "oidn"


def parse_range(text):
    a, _, b = text.partition("-")
    return (int(a), int(b or a))


def parse_res(text):
    w, _, h = text.lower().partition("x")
    return (int(w), int(h))


def parse_spp_list(text):
    return [int(v) for v in str(text).split(",") if v.strip()]


def teacher_spp(text, high):
    """`--teacher-spp`: a count, or `Kx` for K times the scene's highest input level."""
    text = str(text).strip().lower()
    if text.endswith("x"):
        return int(round(float(text[:-1]) * high))
    return int(text)


def scene_settings(seed, spp_choices, res, res_scales, extra_spp):
    """The scene's base sample count and resolution (drawn per scene from the choices)."""
    spp = per_scene_choice(seed, "spp", spp_choices)
    scale = per_scene_choice(seed, "resolution", res_scales)
    if scale != 1:
        # scaled sizes on a multiple of 8 (the given size itself is kept exactly)
        res = tuple(max(8, int(round(v * scale / 8)) * 8) for v in res)
    extra = sorted({n for n in extra_spp if n not in level_spp(spp).values()})
    return spp, res, extra


def render_scene(seed, out, frames, res, spp, reference_spp, reference_frames, half, threads, layout=None,
                 calibration=False, levels=LEVELS, log=print, detail=False, extra_spp=(), teacher=None,
                 cycles_denoise=False, fur=False, contact=False, extra_frames=None, motion_blur=False):
    """Renders one scene: the input levels (`levels` and `extra_spp`, the latter only on
    `extra_frames` when given), the optional reference, and the optional teacher render
    (`teacher` spp) with its OIDN pseudo-reference."""
    import bpy  # noqa: F401  (imported here so --help works without bpy)

    t0 = time.time()
    if calibration:
        desc = scenes.build_calibration(frames=frames, resolution=res)
    else:
        desc = scenes.build(seed, frames=frames, resolution=res, layout=layout, detail=detail, fur=fur,
                            contact=contact)
    sc = scenes.bpy.context.scene
    render.configure(sc, exr_half=half, threads=threads, cycles_denoise=cycles_denoise, motion_blur=motion_blur)
    hair = None if calibration else scenes.hair_fingerprint()
    for lv in levels:
        if lv not in LEVELS:
            raise SystemExit(f"unknown level '{lv}'; known: {', '.join(LEVELS)}")
    extra = {extra_level(n): n for n in extra_spp}
    if teacher:
        extra[TEACHER] = teacher
    try:
        done = render.render_levels(sc, out, seed, frames, spp, reference_spp, reference_frames, levels=levels,
                                    extra=extra, extra_frames=extra_frames, log=log,
                                    before_first_render=lambda: hair_record.claim_hair(out, hair))
    except hair_record.HairMismatch as e:
        raise SystemExit(str(e))
    if teacher:
        from .oidn import denoise_folder

        denoise_folder(os.path.join(out, TEACHER), os.path.join(out, TEACHER_OIDN), log=log)
        done[TEACHER_OIDN] = {"spp": teacher, "denoiser": "Intel Open Image Denoise 2.5 (pyoidn), HDR, "
                              "albedo + normal prefiltered (their own RT filters, then cleanAux), quality high",
                              "source": TEACHER}
    info = {
        "seed": seed,
        "frames": list(frames),
        "resolution": list(res),
        "levels": done,
        "reference_frames": list(reference_frames or frames) if reference_spp else [],
        "hair_fingerprint": hair_record.recorded_hair(out) or hair,
        "extra_frames": list(extra_frames or frames) if extra else [],
        "layout": "<scene>/<level>/frame_####.exr",
        "exr": "multilayer half PIZ" if half else "multilayer float ZIP",
        "renderer": f"Blender {scenes.bpy.app.version_string} Cycles (CPU)",
        "passes": ["Combined", "Denoising Albedo", "Denoising Normal", "Denoising Depth", "Vector", "Depth", "Normal"]
        + (["Noisy Image"] if cycles_denoise else []),
        "cycles_denoising": ("Cycles' OIDN: Combined is denoised, Noisy Image the noisy beauty"
                             if cycles_denoise else "off"),
        "motion_blur": ("half-frame shutter centred on the frame; the Vector pass is all zero"
                        if motion_blur else "off"),
        "render_seconds_this_run": round(time.time() - t0, 1),
        "detail": bool(detail),
        "fur": bool(fur),
        "contact": bool(contact),
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
    common.add_argument("--spp", default="32",
                        help="n: samples of the 'high' level; a list (32,64,128) draws one per scene")
    common.add_argument("--extra-spp", default="",
                        help="further input levels, e.g. 64,128 (folders spp0064, spp0128)")
    common.add_argument("--teacher-spp", default="0",
                        help="also render an independent teacher level at this many spp (or Kx: K times "
                             "n) and denoise it with OIDN into oidn/ (the teacher pseudo-reference)")
    common.add_argument("--res-scales", default="1",
                        help="resolution scales drawn per scene, e.g. 1,0.75,0.5 (detail 1-2 px wide)")
    common.add_argument("--detail", action="store_true",
                        help="add fine detail (implied by the detail-* splits)")
    common.add_argument("--fur", action="store_true",
                        help="add furry objects and grass in view (implied by the fur-* splits)")
    common.add_argument("--contact", action="store_true",
                        help="add glass standing on a textured floor in view, lit to throw caustics "
                             "(implied by the contact-* splits)")
    common.add_argument("--reference-spp", type=int, default=0, help="also render a reference at this many spp")
    common.add_argument("--reference-frames", default=None, help="frame range of the reference (default: all)")
    common.add_argument("--extra-frames", default=None,
                        help="render the --extra-spp and teacher levels only on this sub-range of --frames, "
                             "e.g. an independent, cleaner reference of frames 4-5 (default: all frames); "
                             "the scene is still built over --frames, so it is the same scene")
    common.add_argument("--half", action="store_true", help="write half-float PIZ EXRs (smaller)")
    common.add_argument("--threads", type=int, default=0, help="render threads (0: all cores)")
    common.add_argument("--layout", choices=["indoor", "outdoor"], default=None, help="force a layout")
    common.add_argument("--levels", default=",".join(LEVELS), help="noise levels to render (comma-separated)")
    common.add_argument("--motion-blur", action="store_true",
                        help="render with motion blur (every level and the reference; Cycles then writes no "
                             "usable Vector pass)")
    common.add_argument("--cycles-denoise", action="store_true",
                        help="run Cycles' own denoiser too: Combined is then denoised and the noisy beauty is "
                             "written as Noisy Image (for radn's --guide denoised)")
    s = sub.add_parser("scene", parents=[common], help="render one scene")
    s.add_argument("--seed", type=int, required=True)
    s.add_argument("--out", required=True, help="the scene's folder")
    s.add_argument("--calibration", action="store_true", help="the known-motion calibration scene")
    o = sub.add_parser("oidn", help="denoise every frame of a folder with Intel Open Image Denoise 2.5")
    o.add_argument("src")
    o.add_argument("dst")
    o.add_argument("--mode", choices=OIDN_MODES, default=OIDN_MODES[0],
                   help="prefiltered: albedo and normal denoised first, then the beauty with cleanAux "
                        "(default); noisy-aux: the beauty filter alone on the noisy auxiliaries")
    o.add_argument("--threads", type=int, default=0, help="OIDN worker threads (default: all cores)")
    o.add_argument("--timings", default=None,
                   help="write the seconds spent reading, denoising and writing (JSON) to this file")
    t = sub.add_parser("trim", help="copy a scene keeping only the passes radn reads (for the shipped sample)")
    t.add_argument("src")
    t.add_argument("dst")
    t.add_argument("--crop", default=None, help="x,y,w,h: keep only this region")
    c = sub.add_parser("combine", help="combine independent renders of the same frames into one cleaner "
                                       "reference (the beauty's mean weighted by spp)")
    c.add_argument("sources", nargs="+", metavar="FOLDER:SPP",
                   help="a folder of renders and its samples per pixel, e.g. ref:512 spp2048:2048")
    c.add_argument("--out", required=True, help="the folder to write the combined frames to")
    d = sub.add_parser("dataset", parents=[common], help="render a split of S scenes")
    d.add_argument("--split", choices=sorted(SPLIT_BASE), required=True)
    d.add_argument("--scenes", type=int, required=True)
    d.add_argument("--out", required=True, help="the split's folder; scenes go in scene_<seed>/")
    d.add_argument("--with-hair", action="store_true",
                   help="only the split's scenes with particle hair (fur): the first S such seeds, in order")
    d.add_argument("--with-glass", action="store_true",
                   help="only the split's glass-heavy scenes (caustics through glass): the first S such "
                        "seeds, in order")
    d.add_argument("--with-wires", action="store_true",
                   help="only the split's scenes with thin wires under a moving camera: the first S such "
                        "seeds, in order")
    a = p.parse_args(argv)
    if a.cmd == "trim":
        from .trim import trim_scene
        crop = tuple(int(v) for v in a.crop.split(",")) if a.crop else None
        print(f"wrote {trim_scene(a.src, a.dst, crop)}")
        return 0
    if a.cmd == "combine":
        from .combine import CombineError, combine_folders

        sources = []
        for spec in a.sources:
            folder, _, spp = spec.rpartition(":")
            if not folder or not spp.isdigit() or int(spp) <= 0:
                raise SystemExit(f"'{spec}' must be FOLDER:SPP with SPP a positive whole number")
            sources.append((folder, int(spp)))
        try:
            n = combine_folders(sources, a.out)
        except CombineError as e:
            raise SystemExit(str(e))
        print(f"wrote {n} frames to {a.out}")
        return 0
    if a.cmd == "oidn":
        from .oidn import OidnInputError, denoise_folder

        timings = {}
        try:
            n = denoise_folder(a.src, a.dst, skip_existing=False, log=lambda _: None, mode=a.mode,
                               threads=a.threads, timings=timings)
        except OidnInputError as e:
            raise SystemExit(str(e))
        if a.timings:
            import json

            with open(a.timings, "w") as f:
                json.dump({"frames": n, "mode": a.mode, **timings}, f)
        print(f"wrote {n} frames to {a.dst}")
        return 0
    frames = parse_range(a.frames)
    res = parse_res(a.res)
    ref_frames = parse_range(a.reference_frames) if a.reference_frames else None
    extra_frames = parse_range(a.extra_frames) if a.extra_frames else None
    if extra_frames and not (frames[0] <= extra_frames[0] <= extra_frames[1] <= frames[1]):
        raise SystemExit(f"--extra-frames {a.extra_frames} is not within --frames {a.frames}")
    spp_choices = parse_spp_list(a.spp)
    res_scales = [float(v) for v in a.res_scales.split(",")]
    extra_spp = parse_spp_list(a.extra_spp)
    levels = tuple(a.levels.split(","))

    def one(seed, out, detail, fur, contact, calibration=False):
        spp, scene_res, extra = scene_settings(seed, spp_choices, res, res_scales, extra_spp)
        teacher = teacher_spp(a.teacher_spp, spp) or None
        return render_scene(seed, out, frames, scene_res, spp, a.reference_spp, ref_frames, a.half, a.threads,
                            a.layout, calibration, levels=levels, detail=detail, extra_spp=extra, teacher=teacher,
                            cycles_denoise=a.cycles_denoise, fur=fur, contact=contact, extra_frames=extra_frames,
                            motion_blur=a.motion_blur)

    if a.cmd == "scene":
        print(f"wrote {one(a.seed, a.out, a.detail, a.fur, a.contact, a.calibration)}")
        return 0
    t0 = time.time()
    detail = a.detail or a.split.startswith("detail")
    fur = a.fur or a.split.startswith("fur")
    contact = a.contact or a.split.startswith("contact")
    if a.with_hair + a.with_glass + a.with_wires > 1:
        raise SystemExit("--with-hair, --with-glass and --with-wires pick different scenes: give one")
    if a.with_hair:
        seeds = scenes.seeds_with_hair(SPLIT_BASE[a.split], a.scenes, frames, res, a.layout)
    elif a.with_glass:
        seeds = scenes.seeds_with_glass(SPLIT_BASE[a.split], a.scenes, frames, res, a.layout)
    elif a.with_wires:
        seeds = scenes.seeds_with_wires(SPLIT_BASE[a.split], a.scenes, frames, res, a.layout)
    else:
        seeds = [SPLIT_BASE[a.split] + i for i in range(a.scenes)]
    for i, seed in enumerate(seeds):
        out = os.path.join(a.out, f"scene_{seed}")
        print(f"scene {i + 1}/{a.scenes} (seed {seed}) -> {out}   elapsed {time.time() - t0:.0f} s", flush=True)
        one(seed, out, detail, fur, contact)
    return 0


if __name__ == "__main__":
    sys.exit(main())
