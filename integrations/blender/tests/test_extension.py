"""The Blender extension, headless, with `bpy` from PyPI: installed from the zip scripts/package
builds (target/dist/radn_denoise-*.zip), enabled, run after an animation render, on demand, on a
bad input and cancelled (headless.py does the Blender side in its own process)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]

try:
    import bpy  # noqa: F401  (only to know whether this Python has Blender)

    HAVE_BPY = True
except ImportError:
    HAVE_BPY = False


@pytest.fixture(scope="module")
def findings(tmp_path_factory):
    if not HAVE_BPY:
        pytest.skip("needs bpy (Python 3.11, scripts/setup installs it)")
    found = sorted((ROOT / "target" / "dist").glob("radn_denoise-*.zip"))
    if not found:
        pytest.fail("no extension zip in target/dist: run scripts/package first")
    work = tmp_path_factory.mktemp("blender")
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(work / "user"))
    # the extension must find radn in its own bundled wheel, not elsewhere
    env.pop("RADN_BINARY", None)
    (work / "out").mkdir()
    p = subprocess.run(
        [sys.executable, str(Path(__file__).with_name("headless.py")), str(found[-1]), str(work / "out")],
        capture_output=True, text=True, env=env, timeout=900,
    )
    assert p.returncode == 0, p.stderr[-4000:]
    return json.loads(p.stdout.strip().splitlines()[-1])


def test_installs_from_its_zip_and_turns_on_the_passes_radn_needs(findings):
    assert findings["installed"] == ["FINISHED"] and findings["enabled"]
    assert findings["passes_on"] == [True, True, "OPEN_EXR_MULTILAYER"]
    assert "bpy" in findings["oidn_library"], "guided by Blender's own OIDN"


def test_an_animation_render_is_denoised_beside_it_with_every_layer(findings):
    assert findings["denoised_frames"] == [f"{f:04d}.exr" for f in range(1, 6)]
    assert findings["layers_kept"]
    assert findings["render_untouched"]
    assert findings["reference_not_denoised"], "off means off"


def test_better_than_per_frame_oidn_against_a_high_spp_render(findings):
    # measured: noisy 28.38 dB, OIDN (prefiltered auxiliaries) 34.36 dB, radn 35.41 dB;
    # tMAE 0.0313 / 0.0145 / 0.0125
    radn, oidn, noisy = findings["radn"], findings["oidn"], findings["noisy"]
    assert radn["psnr"] > oidn["psnr"] + 0.5, findings
    assert radn["tmae"] < 0.95 * oidn["tmae"], findings
    assert oidn["psnr"] > noisy["psnr"]


def test_on_demand_errors_and_cancel(findings):
    assert findings["on_demand"] == [["FINISHED"], ["0002.exr", "0003.exr", "0004.exr"]]
    assert isinstance(findings["bad_input"], str) and "missing" in findings["bad_input"]
    c = findings["cancel"]
    assert c["done"] and c["cancelled"], c
    assert all(n.endswith(".exr") and not n.startswith(".") for n in c["left"]), c


def test_with_motion_blur_on_it_estimates_motion_and_beats_per_frame_oidn(findings):
    assert findings["blur_motion_source"] == "Motion: estimated from the frames (motion blur is on)"
    assert findings["blur_problems"] == [], "motion blur no longer stands in radn's way"
    assert findings["blur_denoised_frames"] == [f"{f:04d}.exr" for f in range(1, 6)]
    b = findings["blur"]
    assert b["radn"]["psnr"] > b["oidn"]["psnr"], b
    assert b["radn"]["tmae"] < b["oidn"]["tmae"], b
