#!/usr/bin/env python3
"""Helpers of scripts/gpu-check, the prepared check of radn's CUDA build on a GPU machine.

    gpu_check.py tile SRC_DIR DST_DIR WIDTHxHEIGHT
        Repeats every frame of SRC_DIR (the shipped 176x100 sample) periodically into
        WIDTHxHEIGHT frames (the same repetition for every frame, so the motion vectors stay
        valid), written as ZIP-compressed EXRs with the same channels: a 1080p sequence for
        throughput, made on a machine that has no renderer and no network.
    gpu_check.py compare DIR_A DIR_B TOLERANCE
        Every channel of every frame of A against B (same names): the largest
        |a - b| / (|b| + 0.01) and the PSNR of a against b over the RGB channels (peak 1 after
        clamping). Prints a table and exits 1 when the largest relative difference exceeds
        TOLERANCE.

Needs numpy and the OpenEXR module (the check carries the OpenEXR wheel and puts it on the path).
"""
import math
import sys
from pathlib import Path

import numpy as np
import OpenEXR


def read(path):
    with OpenEXR.File(str(path), separate_channels=True) as f:
        part = f.parts[0]
        return {name: ch.pixels.copy() for name, ch in part.channels.items()}


def tile(src, dst, size):
    width, height = (int(v) for v in size.lower().split("x"))
    dst = Path(dst)
    dst.mkdir(parents=True, exist_ok=True)
    frames = sorted(Path(src).glob("*.exr"))
    if not frames:
        sys.exit(f"gpu_check: no EXR frames in {src}")
    for frame in frames:
        channels = read(frame)
        out = {}
        for name, pixels in channels.items():
            h, w = pixels.shape
            reps = (math.ceil(height / h), math.ceil(width / w))
            out[name] = np.ascontiguousarray(np.tile(pixels, reps)[:height, :width])
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        tmp = dst / (".tmp-" + frame.name)
        OpenEXR.File(header, out).write(str(tmp))
        tmp.rename(dst / frame.name)
    print(f"{len(frames)} frames of {width}x{height} in {dst}")


def compare(a_dir, b_dir, tolerance):
    tolerance = float(tolerance)
    a_frames = sorted(Path(a_dir).glob("*.exr"))
    if not a_frames:
        sys.exit(f"gpu_check: no EXR frames in {a_dir}")
    worst = 0.0
    print("| frame | channels | max relative difference | RGB PSNR (dB) |")
    print("|---|---:|---:|---:|")
    for fa in a_frames:
        fb = Path(b_dir) / fa.name
        if not fb.exists():
            sys.exit(f"gpu_check: {fb} is missing")
        a, b = read(fa), read(fb)
        if set(a) != set(b):
            sys.exit(f"gpu_check: {fa.name}: channels differ: {sorted(set(a) ^ set(b))}")
        rel = 0.0
        sq, n = 0.0, 0
        for name in a:
            x = a[name].astype(np.float64)
            y = b[name].astype(np.float64)
            rel = max(rel, float(np.max(np.abs(x - y) / (np.abs(y) + 0.01))))
            if name.rsplit(".", 1)[-1] in ("R", "G", "B"):
                d = np.clip(x, 0, 1) - np.clip(y, 0, 1)
                sq += float(np.sum(d * d))
                n += d.size
        mse = sq / max(n, 1)
        psnr = float("inf") if mse == 0 else 10 * math.log10(1 / mse)
        worst = max(worst, rel)
        print(f"| {fa.name} | {len(a)} | {rel:.2e} | {psnr:.1f} |")
    verdict = "within" if worst <= tolerance else "OVER"
    print(f"largest relative difference {worst:.2e}: {verdict} the tolerance {tolerance:.0e}")
    sys.exit(0 if worst <= tolerance else 1)


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "tile":
        tile(*sys.argv[2:])
    elif len(sys.argv) == 5 and sys.argv[1] == "compare":
        compare(*sys.argv[2:])
    else:
        sys.exit(__doc__)
