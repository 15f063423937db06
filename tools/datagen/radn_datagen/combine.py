"""Combines independent renders of the same frames into one cleaner reference: the mean of
their beauty weighted by samples per pixel, which is what one render with all their samples
would converge to. For references cleaner than one render can afford in a session, and for
measuring a reference's own noise (two renders kept apart, `radn eval --second-reference`)."""
import os

import numpy as np
import OpenEXR

from .hair_record import HairMismatch, check_same_hair

BEAUTY = "Combined"


class CombineError(Exception):
    """A source folder lacks a frame, or a frame lacks the beauty, or sizes differ."""


def _beauty(path):
    with OpenEXR.File(path, separate_channels=True) as f:
        header = dict(f.header())
        ch = {n: c.pixels.astype(np.float64) for n, c in f.channels().items()
              if n.split(".")[-2:-1] == [BEAUTY]}
    if not ch:
        raise CombineError(f"'{path}' has no {BEAUTY} channels")
    return header, ch


def combine_frame(paths_spp, dst):
    """Writes `dst` (float32, ZIP) with the spp-weighted mean of the beauty channels of every
    `(path, spp)`; header attributes of the first file kept."""
    total = sum(n for _, n in paths_spp)
    acc, header = None, None
    for path, n in paths_spp:
        h, ch = _beauty(path)
        if acc is None:
            header, acc = h, {k: v * (n / total) for k, v in ch.items()}
            continue
        if set(ch) != set(acc) or any(ch[k].shape != acc[k].shape for k in acc):
            raise CombineError(f"'{path}': its {BEAUTY} channels or size differ from '{paths_spp[0][0]}'")
        for k in acc:
            acc[k] += ch[k] * (n / total)
    for k in ("channels", "dataWindow", "displayWindow"):
        header.pop(k, None)
    header["compression"] = OpenEXR.ZIP_COMPRESSION
    os.makedirs(os.path.dirname(dst) or ".", exist_ok=True)
    tmp = dst + ".tmp"
    with OpenEXR.File(header, {k: OpenEXR.Channel(np.ascontiguousarray(v.astype(np.float32)))
                               for k, v in acc.items()}) as out:
        out.write(tmp)
    os.replace(tmp, dst)


def combine_folders(sources, dst):
    """Combines every frame of the first source folder with the same file in the others.
    `sources` is a list of `(folder, spp)`; returns the number of frames written."""
    if len(sources) < 2:
        raise CombineError("give at least two source folders")
    names = sorted(n for n in os.listdir(sources[0][0]) if n.endswith(".exr"))
    if not names:
        raise CombineError(f"'{sources[0][0]}' holds no EXR")
    for folder, _ in sources[1:]:
        for n in names:
            if not os.path.exists(os.path.join(folder, n)):
                raise CombineError(f"'{os.path.join(folder, n)}' does not exist (it is in '{sources[0][0]}')")
    try:  # each level folder's scene folder records its hair, where it has any
        check_same_hair([os.path.dirname(os.path.normpath(os.path.abspath(f))) for f, _ in sources])
    except HairMismatch as e:
        raise CombineError(str(e))
    for n in names:
        combine_frame([(os.path.join(f, n), s) for f, s in sources], os.path.join(dst, n))
    return len(names)
