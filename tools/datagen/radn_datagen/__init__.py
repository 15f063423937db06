"""radn's training-data generator: procedural animated scenes rendered by Blender Cycles at
the paper's three noise levels (n, floor(n/e) and 4 samples per pixel) plus an optional
high-sample reference."""

LEVELS = ("high", "half", "low")
REFERENCE = "ref"
