"""Noise levels and per-frame sampling seeds."""
import math
import zlib


def level_spp(n: int) -> dict:
    """Samples per pixel of each noise level for a base count n (paper section 6)."""
    if n < 4:
        raise ValueError("the base sample count must be at least 4")
    return {"high": n, "half": max(1, math.floor(n / math.e)), "low": 4}


def sampling_seed(scene_seed: int, level: str, frame: int) -> int:
    """An independent Cycles sampling seed for every (scene, level, frame)."""
    return zlib.crc32(f"{scene_seed}/{level}/{frame}".encode()) & 0x7FFFFFFF
