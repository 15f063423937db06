"""radn_mtsgen: render Mitsuba 3 scenes in radn's generic layout.

    python3 -m radn_mtsgen scene --seed 9000000 --out DIR [--frames 1-12] [--res 256x144] \\
        [--levels low:4,half:16,high:64] [--reference-spp 2048 --reference-frames 4-9]
    python3 -m radn_mtsgen dataset --split test --scenes 4 --out DIR [...]

Splits use their own seed ranges (train 7 000 000+i, val 8 000 000+i, test 9 000 000+i), so no
scene is in two; re-running skips frames already written.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys

import numpy as np

from . import scenes
from .render import render_scene

SPLIT_BASE = {"train": 7_000_000, "val": 8_000_000, "test": 9_000_000}
#: widths a dataset scene draws from (128 to 512), with 16:9, 3:2 or 4:3 frames
WIDTHS = (128, 192, 256, 320, 384, 512)


def _range(text: str) -> range:
    a, _, b = text.partition("-")
    return range(int(a), int(b or a) + 1)


def _levels(text: str) -> dict:
    out = {}
    for part in text.split(","):
        name, _, spp = part.partition(":")
        out[name.strip()] = int(spp)
    return out


def _res(text: str):
    w, _, h = text.lower().partition("x")
    return int(w), int(h)


def scene_resolution(seed: int):
    """A resolution drawn from the seed: 128 to 512 wide."""
    r = np.random.default_rng(seed ^ 0x5EED)
    w = int(r.choice(WIDTHS))
    aspect = float(r.choice([16 / 9, 3 / 2, 4 / 3]))
    return w, int(round(w / aspect / 2) * 2)


def render_one(seed, out, frames, res, levels, ref_spp, ref_frames, family=None, sampler=None, variance=False):
    shot = max(frames)
    tex = os.path.join(out, "textures")
    spec = scenes.build(seed, shot, res, family=family, tex_dir=tex, sampler=sampler)
    render_scene(spec, out, frames, levels, variance=variance)
    if ref_spp:
        render_scene(spec, out, ref_frames or frames, {"ref": ref_spp}, variance=variance)
    shutil.rmtree(tex, ignore_errors=True)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="radn_mtsgen", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--frames", default="1-12", help="frame range, e.g. 1-12")
    common.add_argument("--res", default=None, help="WxH (default: drawn from the seed, 128 to 512 wide)")
    common.add_argument("--levels", default="low:4,half:16,high:64", help="level:spp,... to render")
    common.add_argument("--reference-spp", type=int, default=0, help="also render a reference at this many spp")
    common.add_argument("--reference-frames", default=None, help="frame range of the reference (default: all)")
    common.add_argument("--family", choices=scenes.FAMILIES, default=None, help="force a scene family")
    common.add_argument("--sampler", choices=["independent", "ldsampler"], default=None,
                        help="force the sampler (default: drawn from the seed)")
    common.add_argument("--variance", action="store_true",
                        help="also write variance.R/G/B, the variance of each pixel's mean")
    s = sub.add_parser("scene", parents=[common], help="render one scene")
    s.add_argument("--seed", type=int, required=True)
    s.add_argument("--out", required=True)
    d = sub.add_parser("dataset", parents=[common], help="render a split: scenes <base+i>")
    d.add_argument("--split", choices=sorted(SPLIT_BASE), required=True)
    d.add_argument("--scenes", type=int, required=True)
    d.add_argument("--first", type=int, default=0, help="first scene index")
    d.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    frames = _range(a.frames)
    ref_frames = _range(a.reference_frames) if a.reference_frames else None
    levels = _levels(a.levels)
    seeds = [a.seed] if a.cmd == "scene" else [SPLIT_BASE[a.split] + i for i in range(a.first, a.first + a.scenes)]
    for seed in seeds:
        out = a.out if a.cmd == "scene" else os.path.join(a.out, f"scene_{seed}")
        res = _res(a.res) if a.res else scene_resolution(seed)
        render_one(seed, out, frames, res, levels, a.reference_spp, ref_frames, a.family, a.sampler, a.variance)
    return 0


if __name__ == "__main__":
    sys.exit(main())
