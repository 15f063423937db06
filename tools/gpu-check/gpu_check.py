#!/usr/bin/env python3
"""Helpers of scripts/gpu-check, the prepared check of radn's CUDA build on a GPU machine.

    gpu_check.py tile SRC_DIR DST_DIR WIDTHxHEIGHT
        Repeats every frame of SRC_DIR (the shipped 176x100 sample) periodically into
        WIDTHxHEIGHT frames (the same repetition for every frame, so the motion vectors stay
        valid), written as ZIP-compressed EXRs with the same channels: a 1080p sequence for
        throughput, made on a machine that has no renderer and no network.
    gpu_check.py compare DIR_A DIR_B TOLERANCE
        Every channel of every frame of A against B (same names): the relative difference
        |a - b| / (|b| + 0.01) of every sample, and the PSNR of a against b over the RGB
        channels (peak 1 after clamping). Prints a table; exits 1 unless at most 0.01% of the
        samples differ by more than TOLERANCE and every frame's PSNR is at least 60 dB. (The
        kernels' threshold is a step: a weight that lands on the threshold in one run and just
        below it in the other is kept in one and dropped in the other, so a few samples may
        differ by more than float rounding.)

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
    worst, over, samples, worst_psnr = 0.0, 0, 0, float("inf")
    print("| frame | channels | max relative difference | samples over tolerance | RGB PSNR (dB) |")
    print("|---|---:|---:|---:|---:|")
    for fa in a_frames:
        fb = Path(b_dir) / fa.name
        if not fb.exists():
            sys.exit(f"gpu_check: {fb} is missing")
        a, b = read(fa), read(fb)
        if set(a) != set(b):
            sys.exit(f"gpu_check: {fa.name}: channels differ: {sorted(set(a) ^ set(b))}")
        rel, frame_over, frame_samples = 0.0, 0, 0
        sq, n = 0.0, 0
        for name in a:
            x = a[name].astype(np.float64)
            y = b[name].astype(np.float64)
            r = np.abs(x - y) / (np.abs(y) + 0.01)
            rel = max(rel, float(np.max(r)))
            frame_over += int(np.count_nonzero(r > tolerance))
            frame_samples += r.size
            if name.rsplit(".", 1)[-1] in ("R", "G", "B"):
                d = np.clip(x, 0, 1) - np.clip(y, 0, 1)
                sq += float(np.sum(d * d))
                n += d.size
        mse = sq / max(n, 1)
        psnr = float("inf") if mse == 0 else 10 * math.log10(1 / mse)
        worst = max(worst, rel)
        worst_psnr = min(worst_psnr, psnr)
        over += frame_over
        samples += frame_samples
        print(f"| {fa.name} | {len(a)} | {rel:.2e} | {frame_over} of {frame_samples} | {psnr:.1f} |")
    share = over / max(samples, 1)
    ok = share <= 1e-4 and worst_psnr >= 60
    print(
        f"largest relative difference {worst:.2e}; {share:.4%} of the samples over {tolerance:.0e} "
        f"(at most 0.01% allowed); lowest PSNR {worst_psnr:.1f} dB (at least 60 allowed): "
        + ("agree" if ok else "DISAGREE")
    )
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "tile":
        tile(*sys.argv[2:])
    elif len(sys.argv) == 5 and sys.argv[1] == "compare":
        compare(*sys.argv[2:])
    else:
        sys.exit(__doc__)
