"""The held-out Cycles generator: every family renders radn's Cycles passes, a seed gives the same
scene, and Cycles' motion vectors carry the previous frame onto this one."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

HERE = Path(__file__).resolve().parent
PASSES = ("Combined", "Denoising Albedo", "Denoising Normal.X", "Denoising Depth.Z", "Vector.X", "Vector.Y")


def render(out: Path, family: str, seed=5, frames="1-1", spp=1, res="48x32", extra=()):
    subprocess.run([sys.executable, "-m", "radn_heldout", "scene", "--seed", str(seed), "--family", family,
                    "--res", res, "--frames", frames, "--levels", f"low:{spp}", "--reference-spp", "0",
                    "--out", str(out), *extra], cwd=HERE.parent, check=True, capture_output=True)


def layers(path: Path) -> dict:
    ch = OpenEXR.File(str(path)).parts[0].channels
    return {k.removeprefix("ViewLayer."): v.pixels for k, v in ch.items()}


@pytest.mark.parametrize("family", ["shelves", "facade", "tabletop", "haze"])
def test_every_family_renders_the_passes_radn_reads(tmp_path, family):
    render(tmp_path / family, family)
    ls = layers(tmp_path / family / "low" / "frame_0001.exr")
    for p in PASSES:
        assert p in ls, f"{family}: no {p} pass"
        assert np.isfinite(ls[p]).all()
    assert ls["Combined"].shape[:2] == (32, 48)
    assert ls["Combined"][..., :3].mean() > 1e-3, "the scene is lit"
    m = json.loads((tmp_path / family / "manifest.json").read_text())
    assert m["family"] == family and m["generator"] == "radn_heldout"


def test_a_seed_gives_the_same_scene(tmp_path):
    for run in ("a", "b"):
        render(tmp_path / run, "shelves", seed=11)
    a, b = (json.loads((tmp_path / r / "manifest.json").read_text()) for r in ("a", "b"))
    assert a["scene"] == b["scene"] and a["sampling_pattern"] == b["sampling_pattern"]
    za, zb = (layers(tmp_path / r / "low" / "frame_0001.exr")["Depth.Z"] for r in ("a", "b"))
    assert np.array_equal(za, zb), "the same geometry and camera"


def test_the_previous_frame_warped_by_the_motion_vectors_matches_this_one(tmp_path):
    # the turntable and the orbiting camera move every pixel; albedo is nearly noise-free
    render(tmp_path / "t", "tabletop", seed=2, frames="1-2", spp=16, res="96x64")
    a1, l2 = (layers(tmp_path / "t" / "low" / f"frame_000{f}.exr") for f in (1, 2))
    prev, cur = a1["Denoising Albedo"][..., :3], l2["Denoising Albedo"][..., :3]
    h, w = cur.shape[:2]
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    # Cycles' Vector.X/Y: position in the previous frame minus position in this one, pixels, +Y up
    px = np.clip(np.rint(x + l2["Vector.X"]), 0, w - 1).astype(int)
    py = np.clip(np.rint(y - l2["Vector.Y"]), 0, h - 1).astype(int)
    moved = np.hypot(l2["Vector.X"], l2["Vector.Y"]).mean()
    assert moved > 0.3, f"the scene moves ({moved:.2f} px per frame)"
    warped = np.abs(prev[py, px] - cur).mean()
    still = np.abs(prev - cur).mean()
    assert warped < 0.6 * still, f"warped {warped:.4f} vs not warped {still:.4f}"


def test_motion_blur_writes_no_vectors_and_a_fast_camera_moves_further(tmp_path):
    render(tmp_path / "blur", "facade", frames="1-2", extra=["--motion-blur"])
    m = json.loads((tmp_path / "blur" / "manifest.json").read_text())
    assert m["motion_blur"].startswith("half-frame shutter") and m["camera_speed"] == 1.0
    ls = layers(tmp_path / "blur" / "low" / "frame_0002.exr")
    assert not np.any(ls["Vector.X"]) and not np.any(ls["Vector.Y"]), "Cycles writes zeros with motion blur"
    motion = {}
    for speed in (1, 3):
        render(tmp_path / f"s{speed}", "facade", frames="1-2", extra=["--camera-speed", str(speed)])
        v = layers(tmp_path / f"s{speed}" / "low" / "frame_0002.exr")
        motion[speed] = float(np.abs(v["Vector.X"]).mean() + np.abs(v["Vector.Y"]).mean())
    assert motion[3] > 2.5 * motion[1] > 0, motion


def test_two_scenes_join_into_a_sequence_with_a_cut(tmp_path):
    render(tmp_path / "a", "shelves", seed=3, frames="1-2")
    render(tmp_path / "b", "haze", seed=4, frames="1-2")
    out = tmp_path / "ab"
    subprocess.run([sys.executable, "-m", "radn_heldout", "join", "--out", str(out), str(tmp_path / "a"),
                    str(tmp_path / "b")], cwd=HERE.parent, check=True, capture_output=True)
    assert sorted(p.name for p in (out / "low").iterdir()) == [f"frame_000{f}.exr" for f in range(1, 5)]
    assert (out / "low" / "frame_0003.exr").read_bytes() == (tmp_path / "b" / "low" / "frame_0001.exr").read_bytes()
    assert json.loads((out / "manifest.json").read_text())["cut_after"] == 2
    again = subprocess.run([sys.executable, "-m", "radn_heldout", "join", "--out", str(out), str(tmp_path / "a"),
                            str(tmp_path / "b")], cwd=HERE.parent, capture_output=True, text=True)
    assert again.returncode != 0 and "exists" in again.stderr
    render(tmp_path / "c", "haze", seed=4, frames="1-2", res="64x32")
    other = subprocess.run([sys.executable, "-m", "radn_heldout", "join", "--out", str(tmp_path / "ac"),
                            str(tmp_path / "a"), str(tmp_path / "c")], cwd=HERE.parent, capture_output=True, text=True)
    assert other.returncode != 0 and "48x32" in other.stderr and "64x32" in other.stderr
    assert not (tmp_path / "ac").exists()
