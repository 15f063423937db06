"""Copies a rendered scene keeping only the passes radn reads, to make the small sample
sequence that ships in the repository."""
import json
import os
import shutil

import numpy as np
import OpenEXR

KEEP = ("Combined", "Denoising Albedo", "Denoising Normal", "Vector", "Depth")
REFERENCE_KEEP = ("Combined",)
# Quantisation steps of the auxiliary passes (far below what warping and confidence resolve);
# the beauty is stored exactly (as half).
QUANTUM = {"Vector": 1 / 128, "Denoising Normal": 1 / 1024, "Denoising Albedo": 1 / 1024}


def trim_file(src, dst, keep, crop=None):
    """Writes `dst` with the channels of `src` whose pass is in `keep`, as half floats (ZIP),
    header attributes kept. Half precision turns the background depth (1e10) into +Inf,
    which radn reads as "infinitely far"."""
    with OpenEXR.File(src, separate_channels=True) as f:
        header = dict(f.header())
        # Cycles names channels "<ViewLayer>.<Pass>.<Channel>"
        channels = {name: ch for name, ch in f.channels().items() if name.split(".")[-2] in keep}
    for k in ("channels", "dataWindow", "displayWindow"):
        header.pop(k, None)
    header["compression"] = OpenEXR.ZIP_COMPRESSION
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    tmp = dst + ".tmp"
    def prepare(name, px):
        if crop:
            x, y, w, h = crop
            px = px[y:y + h, x:x + w]
        step = QUANTUM.get(name.split(".")[-2])
        if step:
            px = np.round(px.astype(np.float32) / step) * step
        return OpenEXR.Channel(np.ascontiguousarray(px.astype(np.float16)))

    with OpenEXR.File(header, {n: prepare(n, c.pixels) for n, c in channels.items()}) as out:
        out.write(tmp)
    os.replace(tmp, dst)
    return sorted(channels)


def trim_scene(src, dst, crop=None):
    """Trims every level of a scene folder (optionally cropping to x, y, w, h) and copies its
    manifest, noting what was kept."""
    kept = {}
    for level in sorted(os.listdir(src)):
        d = os.path.join(src, level)
        if not os.path.isdir(d):
            continue
        keep = REFERENCE_KEEP if level == "ref" else KEEP
        for name in sorted(os.listdir(d)):
            if name.endswith(".exr"):
                kept[level] = trim_file(os.path.join(d, name), os.path.join(dst, level, name), keep, crop)
    with open(os.path.join(src, "manifest.json")) as f:
        manifest = json.load(f)
    if crop:
        manifest["rendered_resolution"] = manifest["resolution"]
        manifest["resolution"] = [crop[2], crop[3]]
    manifest["trimmed"] = {"kept_channels": kept, "storage": "half float, ZIP", "crop_xywh": list(crop) if crop else None,
                           "quantum": QUANTUM,
                           "note": "made by `python -m radn_datagen trim`; other passes dropped to keep the sample small"}
    with open(os.path.join(dst, "manifest.json"), "w") as f:
        json.dump(manifest, f, indent=2, sort_keys=True)
    return dst
