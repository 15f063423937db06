"""Copies a rendered scene keeping only the passes radn reads, to make the small sample
sequence that ships in the repository."""
import json
import os
import shutil

import numpy as np
import OpenEXR

KEEP = ("Combined", "Denoising Albedo", "Denoising Normal", "Vector", "Depth")
REFERENCE_KEEP = ("Combined",)


def trim_file(src, dst, keep):
    """Writes `dst` with the channels of `src` whose pass is in `keep`, as half floats (ZIP),
    header attributes kept. Half precision turns the background depth (1e10) into +Inf,
    which radn reads as "infinitely far"."""
    with OpenEXR.File(src, separate_channels=True) as f:
        header = dict(f.header())
        # Cycles names channels "<ViewLayer>.<Pass>.<Channel>"
        channels = {name: ch for name, ch in f.channels().items() if name.split(".")[-2] in keep}
    header.pop("channels", None)
    header["compression"] = OpenEXR.ZIP_COMPRESSION
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    tmp = dst + ".tmp"
    with OpenEXR.File(header, {n: OpenEXR.Channel(np.ascontiguousarray(c.pixels.astype(np.float16)))
                                  for n, c in channels.items()}) as out:
        out.write(tmp)
    os.replace(tmp, dst)
    return sorted(channels)


def trim_scene(src, dst):
    """Trims every level of a scene folder and copies its manifest, noting what was kept."""
    kept = {}
    for level in sorted(os.listdir(src)):
        d = os.path.join(src, level)
        if not os.path.isdir(d):
            continue
        keep = REFERENCE_KEEP if level == "ref" else KEEP
        for name in sorted(os.listdir(d)):
            if name.endswith(".exr"):
                kept[level] = trim_file(os.path.join(d, name), os.path.join(dst, level, name), keep)
    with open(os.path.join(src, "manifest.json")) as f:
        manifest = json.load(f)
    manifest["trimmed"] = {"kept_channels": kept, "storage": "half float, ZIP",
                           "note": "made by `python -m radn_datagen trim`; other passes dropped to keep the sample small"}
    with open(os.path.join(dst, "manifest.json"), "w") as f:
        json.dump(manifest, f, indent=2, sort_keys=True)
    return dst
