"""Procedural textures as arrays (height × width × 3, linear RGB in [0, 1]), from a seed: bricks,
planks, value noise, stripes, checks and rows of glyphs (small text)."""

from __future__ import annotations

import numpy as np


def _palette(rng: np.random.Generator, n: int) -> np.ndarray:
    hue = rng.uniform(0, 1)
    cols = []
    for i in range(n):
        h = (hue + rng.uniform(-0.08, 0.08) + i * rng.choice([0.0, 0.5])) % 1.0
        s, v = rng.uniform(0.2, 0.8), rng.uniform(0.15, 0.85)
        k = (np.array([5, 3, 1]) + h * 6) % 6
        cols.append(v - v * s * np.clip(np.minimum(k, 4 - k), 0, 1))
    return np.array(cols, dtype=np.float32)


def value_noise(rng: np.random.Generator, size: int, octaves: int = 5) -> np.ndarray:
    """Fractal value noise in [0, 1], size × size."""
    out = np.zeros((size, size), np.float32)
    amp, total = 1.0, 0.0
    for o in range(octaves):
        cells = 2 ** (o + 2)
        grid = rng.uniform(0, 1, (cells + 1, cells + 1)).astype(np.float32)
        grid[-1, :], grid[:, -1] = grid[0, :], grid[:, 0]  # tileable
        t = np.linspace(0, cells, size, endpoint=False)
        i = t.astype(int)
        f = t - i
        f = f * f * (3 - 2 * f)
        a = grid[i][:, i] * (1 - f)[None, :] + grid[i][:, i + 1] * f[None, :]
        b = grid[i + 1][:, i] * (1 - f)[None, :] + grid[i + 1][:, i + 1] * f[None, :]
        out += amp * (a * (1 - f)[:, None] + b * f[:, None])
        total += amp
        amp *= 0.55
    return out / total


def bricks(rng, size=512):
    rows = int(rng.integers(6, 20))
    h = size / rows
    w = h * rng.uniform(1.8, 3.0)
    mortar = rng.uniform(0.04, 0.12)
    y, x = np.mgrid[0:size, 0:size].astype(np.float32)
    row = (y // h).astype(int)
    xs = x + (row % 2) * w / 2
    fy, fx = (y % h) / h, (xs % w) / w
    is_mortar = (fy < mortar) | (fx < mortar * h / w)
    brick_id = row * 1000 + (xs // w).astype(int)
    pal = _palette(rng, 3)
    tint = np.random.default_rng(int(rng.integers(1 << 30))).uniform(0.75, 1.15, brick_id.max() + 1)
    col = pal[0][None, None, :] * tint[brick_id][..., None]
    col = col * (0.85 + 0.3 * value_noise(rng, size)[..., None])
    col[is_mortar] = pal[2] * 0.5 + 0.35
    return np.clip(col, 0, 1)


def planks(rng, size=512):
    n = int(rng.integers(4, 12))
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    plank = (y * n).astype(int)
    noise = value_noise(rng, size, 4)
    rings = 0.5 + 0.5 * np.sin((x * rng.uniform(20, 60) + noise * rng.uniform(4, 12) + plank * 1.7) * np.pi)
    pal = _palette(rng, 2)
    col = pal[0] * (0.6 + 0.4 * rings[..., None]) * (0.9 + 0.2 * ((plank * 37) % 5 / 5.0))[..., None]
    col[((y * n) % 1.0) < 0.02] *= 0.3
    return np.clip(col, 0, 1)


def noise(rng, size=512):
    pal = _palette(rng, 2)
    v = value_noise(rng, size, 6)[..., None]
    return np.clip(pal[0] * (1 - v) + pal[1] * v, 0, 1)


def stripes(rng, size=512):
    n = int(rng.integers(8, 60))
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    angle = rng.uniform(0, np.pi)
    s = ((x * np.cos(angle) + y * np.sin(angle)) * n) % 1.0 < rng.uniform(0.2, 0.6)
    pal = _palette(rng, 2)
    return np.where(s[..., None], pal[0], pal[1]).astype(np.float32)


def checks(rng, size=512):
    n = int(rng.integers(4, 32))
    y, x = np.mgrid[0:size, 0:size] * n // size
    pal = _palette(rng, 2)
    return np.where(((x + y) % 2 == 0)[..., None], pal[0], pal[1]).astype(np.float32)


def glyphs(rng, size=512):
    """Rows of random 5×7 glyphs: small text on a label."""
    cell = int(rng.integers(6, 14))
    col = np.ones((size, size, 3), np.float32) * rng.uniform(0.6, 0.95)
    ink = _palette(rng, 1)[0] * 0.2
    for gy in range(0, size - 8 * cell // 7, int(cell * 1.6)):
        for gx in range(0, size - cell, cell):
            if rng.uniform() < 0.15:
                continue  # a space
            bits = rng.uniform(size=(7, 5)) < 0.45
            px = cell // 7 + 1
            for (by, bx) in zip(*np.nonzero(bits)):
                col[gy + by * px: gy + (by + 1) * px, gx + bx * px: gx + (bx + 1) * px] = ink
    return col


KINDS = {"bricks": bricks, "planks": planks, "noise": noise, "stripes": stripes, "checks": checks,
         "glyphs": glyphs}


def make(kind: str, rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """A texture of `kind` (one of KINDS)."""
    return KINDS[kind](rng, size)
