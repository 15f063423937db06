#!/usr/bin/env python3
"""Denoises every frame of a Cycles EXR folder with Intel Open Image Denoise, for the comparison
row of docs/benchmarks.md (scripts/bench-compare with OIDN=1).

OIDN is what radn's users compare against, but it is not part of radn: install its Python
bindings yourself (`pip install pyoidn OpenEXR`). Each output frame is the input file with the
beauty's RGB replaced by OIDN's result (HDR, "high" quality, Cycles' noisy denoising albedo and
normal as auxiliary images, prefiltered by OIDN), written to a temporary file and renamed.

usage: oidn_denoise.py IN_DIR OUT_DIR
"""
import glob
import os
import sys

import numpy as np
import OpenEXR
import pyoidn

BEAUTY = "ViewLayer.Combined"
ALBEDO = "ViewLayer.Denoising Albedo"
NORMAL = "ViewLayer.Denoising Normal"


def denoise_file(src, dst):
    f = OpenEXR.File(src, separate_channels=True)
    ch = f.channels()
    try:
        color = np.stack([ch[f"{BEAUTY}.{c}"].pixels for c in "RGB"], axis=-1)
        albedo = np.stack([ch[f"{ALBEDO}.{c}"].pixels for c in "RGB"], axis=-1)
        normal = np.stack([ch[f"{NORMAL}.{c}"].pixels for c in "XYZ"], axis=-1)
    except KeyError as e:
        sys.exit(f"{src}: missing channel {e} (expected Cycles' beauty, denoising albedo and normal)")
    color = np.ascontiguousarray(np.maximum(color, 0.0), dtype=np.float32)
    albedo = np.ascontiguousarray(np.clip(albedo, 0.0, 1.0), dtype=np.float32)
    normal = np.ascontiguousarray(np.clip(normal, -1.0, 1.0), dtype=np.float32)
    out = pyoidn.denoise(color, albedo, normal, hdr=True, quality="high")
    for i, c in enumerate("RGB"):
        ch[f"{BEAUTY}.{c}"] = OpenEXR.Channel(np.ascontiguousarray(out[..., i]))
    tmp = os.path.join(os.path.dirname(dst), f".{os.path.basename(dst)}.tmp")
    OpenEXR.File(f.header(), ch).write(tmp)
    os.replace(tmp, dst)


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    src_dir, dst_dir = sys.argv[1:]
    files = sorted(glob.glob(os.path.join(src_dir, "*.exr")))
    if not files:
        sys.exit(f"{src_dir}: no .exr files")
    os.makedirs(dst_dir, exist_ok=True)
    for src in files:
        dst = os.path.join(dst_dir, os.path.basename(src))
        if os.path.abspath(dst) == os.path.abspath(src):
            sys.exit(f"{dst}: output would overwrite the input")
        denoise_file(src, dst)


if __name__ == "__main__":
    main()
