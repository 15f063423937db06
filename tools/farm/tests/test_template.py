"""The farm template end to end with the Open Job Description CLI: it validates, its tasks split
a frame range into chunks (the last one shorter), the chunks together give exactly the result of
one `radn denoise` over the range, and a rerun skips every finished frame."""
import os
import re
import shutil
import subprocess

import numpy as np
import OpenEXR
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(os.path.dirname(HERE)))
TEMPLATE = os.path.join(REPO, "tools", "farm", "radn-denoise.template.yaml")
SAMPLE = os.path.join(REPO, "samples", "cycles-sample", "low", "frame_####.exr")
RADN = os.environ.get("RADN_BIN", os.path.join(REPO, "target", "release", "radn"))
OPENJD = shutil.which("openjd")


def require_tools():
    # scripts/test installs openjd-cli (scripts/setup) and builds radn (cargo test --release)
    if OPENJD is None:
        pytest.fail("openjd not found: run scripts/setup (installs tools/farm/requirements.txt)")
    if not os.access(RADN, os.X_OK):
        pytest.fail(f"{RADN} not found: cargo build --release -p radn (or set RADN_BIN)")


def run_template(out, first, last, per):
    cmd = [OPENJD, "run", TEMPLATE, "--step", "Denoise",
           "-p", f"Input={SAMPLE}", "-p", f"Output={out}/f_####.exr",
           "-p", f"FrameStart={first}", "-p", f"FrameEnd={last}", "-p", f"FramesPerTask={per}",
           "-p", f"RadnCommand={RADN}", "-p", "Threads=2"]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr
    return res.stdout


def pixels(path):
    with OpenEXR.File(str(path), separate_channels=True) as f:
        return {n: c.pixels.astype(np.float64) for n, c in f.channels().items()}


def test_template_is_valid():
    require_tools()
    res = subprocess.run([OPENJD, "check", TEMPLATE], capture_output=True, text=True)
    assert res.returncode == 0 and "passes validation" in res.stdout, res.stdout + res.stderr


def test_chunks_give_the_result_of_one_run_and_a_rerun_skips(tmp_path):
    require_tools()
    log = run_template(tmp_path / "farm", 3, 7, 2)
    # chunks 3-4, 5-6 and 7-7
    assert re.findall(r"--frames (\d+-\d+)", log) == ["3-4", "5-6", "7-7"], log
    one = subprocess.run([RADN, "--threads", "2", "denoise", "-i", SAMPLE,
                          "-o", str(tmp_path / "one" / "f_####.exr"), "--frames", "3-7"],
                         capture_output=True, text=True)
    assert one.returncode == 0, one.stderr
    written = sorted(os.listdir(tmp_path / "farm"))
    assert written == [f"f_{f:04d}.exr" for f in range(3, 8)], written
    for name in written:
        a, b = pixels(tmp_path / "farm" / name), pixels(tmp_path / "one" / name)
        assert a.keys() == b.keys()
        for ch in a:
            worst = np.max(np.abs(a[ch] - b[ch]) / np.maximum(np.abs(b[ch]), 1.0))
            assert worst <= 1e-6, f"{name} {ch}: farm chunks and one run differ by {worst}"
    # a retried job: every task finds its frames done and writes nothing
    stamps = {n: os.stat(tmp_path / "farm" / n).st_mtime_ns for n in written}
    log = run_template(tmp_path / "farm", 3, 7, 2)
    assert log.count("already done, skipped") == 3, log
    assert all(re.search(r"denoised 0 frames \(\d already done", line) for line in log.splitlines()
               if "already done" in line), log
    assert stamps == {n: os.stat(tmp_path / "farm" / n).st_mtime_ns for n in written}
