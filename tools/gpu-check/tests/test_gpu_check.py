"""Tests of the GPU check's helpers (tools/gpu-check/gpu_check.py) on the shipped sample."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenEXR

ROOT = Path(__file__).resolve().parents[3]
HELPER = ROOT / "tools" / "gpu-check" / "gpu_check.py"
SAMPLE = ROOT / "samples" / "cycles-sample" / "low"

sys.path.insert(0, str(HELPER.parent))
import gpu_check  # noqa: E402


def run(*args):
    return subprocess.run([sys.executable, str(HELPER), *map(str, args)], capture_output=True, text=True)


def test_tiling_repeats_every_channel_periodically_at_the_asked_size(tmp_path):
    out = tmp_path / "tiled"
    r = run("tile", SAMPLE, out, "400x230")
    assert r.returncode == 0, r.stderr
    names = sorted(p.name for p in SAMPLE.glob("*.exr"))
    assert sorted(p.name for p in out.glob("*.exr")) == names
    src = gpu_check.read(SAMPLE / names[0])
    got = gpu_check.read(out / names[0])
    assert set(got) == set(src)
    for name, pixels in src.items():
        h, w = pixels.shape
        tiled = got[name]
        assert tiled.shape == (230, 400)
        assert tiled.dtype == pixels.dtype
        # every copy equals the source, including the cut-off ones at the right and bottom
        assert np.array_equal(tiled[:h, :w], pixels)
        assert np.array_equal(tiled[h : 2 * h, w : 2 * w], pixels)
        assert np.array_equal(tiled[2 * h :, 2 * w :], pixels[: 230 - 2 * h, : 400 - 2 * w])


def write_copy(src_dir, dst_dir, change=None):
    dst_dir.mkdir()
    for frame in sorted(src_dir.glob("*.exr"))[:2]:
        channels = {k: v.astype(np.float32) for k, v in gpu_check.read(frame).items()}
        if change:
            change(channels)
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        OpenEXR.File(header, channels).write(str(dst_dir / frame.name))


def test_compare_accepts_rounding_and_refuses_real_differences(tmp_path):
    write_copy(SAMPLE, tmp_path / "a")

    def rounding(ch):
        for v in ch.values():
            v *= 1 + 1e-5

    def a_few_flips(ch):  # 5 samples of 264,000 off by 2%: under 0.01% over the tolerance
        ch["ViewLayer.Combined.R"].flat[1000:1005] *= 1.02

    def blur(ch):  # every sample off by 1%
        for v in ch.values():
            v *= 1.01

    write_copy(SAMPLE, tmp_path / "rounding", rounding)
    write_copy(SAMPLE, tmp_path / "flips", a_few_flips)
    write_copy(SAMPLE, tmp_path / "blur", blur)
    assert run("compare", tmp_path / "rounding", tmp_path / "a", "1e-3").returncode == 0
    r = run("compare", tmp_path / "flips", tmp_path / "a", "1e-3")
    assert r.returncode == 0 and "| 5 of 264000 |" in r.stdout, r.stdout
    r = run("compare", tmp_path / "blur", tmp_path / "a", "1e-3")
    assert r.returncode == 1 and "DISAGREE" in r.stdout, r.stdout
