"""Noise levels, per-scene sample counts and resolutions, and per-frame sampling seeds."""
import math
import random
import zlib


def level_spp(n: int) -> dict:
    """Samples per pixel of each noise level for a base count n (paper section 6)."""
    if n < 4:
        raise ValueError("the base sample count must be at least 4")
    return {"high": n, "half": max(1, math.floor(n / math.e)), "low": 4}


def extra_level(spp: int) -> str:
    """The folder name of an extra input level rendered at `spp` (e.g. `spp0064`)."""
    return f"spp{spp:04d}"


def per_scene_choice(scene_seed: int, what: str, choices):
    """One of `choices` for a scene, fixed by its seed and independent of everything else
    drawn for it (so e.g. its sample count and its resolution do not correlate)."""
    choices = list(choices)
    return random.Random(zlib.crc32(f"{scene_seed}/{what}".encode())).choice(choices)


def sampling_seed(scene_seed: int, level: str, frame: int) -> int:
    """An independent Cycles sampling seed for every (scene, level, frame)."""
    return zlib.crc32(f"{scene_seed}/{level}/{frame}".encode()) & 0x7FFFFFFF
