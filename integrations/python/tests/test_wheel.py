"""The `radn` wheel installed into a fresh virtual environment: its command, its Python API on
the shipped sample, its errors and its cancellation. Needs the wheel scripts/package builds
(target/dist/radn-*.whl; RADN_WHEEL names another)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import textwrap
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "samples" / "cycles-sample" / "low"


def _wheel() -> Path:
    named = os.environ.get("RADN_WHEEL")
    if named:
        return Path(named)
    found = sorted((ROOT / "target" / "dist").glob("radn-*.whl"))
    if not found:
        pytest.fail("no wheel in target/dist: run scripts/package first")
    return found[-1]


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    """A fresh venv with only the wheel installed (no index, no other package)."""
    root = tmp_path_factory.mktemp("venv")
    venv.EnvBuilder(with_pip=True, clear=True).create(root)
    py = root / ("Scripts/python.exe" if os.name == "nt" else "bin/python")
    subprocess.run(
        [str(py), "-m", "pip", "install", "--quiet", "--no-index", "--no-deps",
         "--disable-pip-version-check", str(_wheel())],
        check=True,
    )
    return root, py


def run_py(py: Path, code: str, cwd: Path) -> dict:
    """Runs `code` in the venv's Python; it prints one JSON object, returned here."""
    # outside the repository, so `import radn` can only find the installed package
    p = subprocess.run([str(py), "-c", textwrap.dedent(code)], cwd=cwd, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout.strip().splitlines()[-1])


def test_the_command_is_installed_and_runs(env, tmp_path):
    root, py = env
    exe = root / ("Scripts/radn.exe" if os.name == "nt" else "bin/radn")
    out = subprocess.run([str(exe), "--version"], capture_output=True, text=True, check=True)
    assert out.stdout.startswith("radn ")
    out = subprocess.run([str(py), "-m", "radn", "--version"], capture_output=True, text=True, check=True, cwd=tmp_path)
    assert out.stdout.startswith("radn ")


def test_inspect_gives_the_channels_and_errors_name_the_file(env, tmp_path):
    _, py = env
    bad = tmp_path / "truncated.exr"
    bad.write_bytes((SAMPLE / "frame_0001.exr").read_bytes()[:2000])
    r = run_py(py, f"""
        import json, radn
        info = radn.inspect({str(SAMPLE / 'frame_0001.exr')!r})
        try:
            radn.inspect({str(bad)!r})
            err = None
        except radn.RadnError as e:
            err = str(e)
        print(json.dumps({{"info": info, "err": err, "file": radn.__file__, "version": radn.__version__}}))
    """, tmp_path)
    assert "site-packages" in r["file"], "the installed package, not the source tree"
    text = json.dumps(r["info"])
    for name in ("ViewLayer.Combined.R", "ViewLayer.Denoising Albedo.G", "ViewLayer.Vector.X"):
        assert name in text
    assert r["err"] is not None and "truncated.exr" in r["err"]
    assert r["version"] == "0.1.0"


def test_denoise_writes_every_frame_with_progress_and_keeps_every_layer(env, tmp_path):
    _, py = env
    out = tmp_path / "out"
    r = run_py(py, f"""
        import json, radn
        calls = []
        res = radn.denoise({str(SAMPLE / 'frame_####.exr')!r}, {str(out / 'frame_####.exr')!r},
                           frames=range(3, 6), progress=lambda d, t: calls.append((d, t)))
        again = radn.denoise({str(SAMPLE / 'frame_####.exr')!r}, {str(out / 'frame_####.exr')!r}, frames=(3, 5))
        chans = [sorted(c["name"] for c in radn.inspect(f)["channels"])
                 for f in ({str(SAMPLE / 'frame_0004.exr')!r}, {str(out / 'frame_0004.exr')!r})]
        print(json.dumps({{"calls": calls, "written": res.written, "path": res.path,
                          "skipped_again": again.skipped, "chans": chans}}))
    """, tmp_path)
    assert sorted(p.name for p in out.iterdir()) == ["frame_0003.exr", "frame_0004.exr", "frame_0005.exr"]
    assert r["written"] == 3 and r["skipped_again"] == 3
    done = [d for d, _ in r["calls"]]
    assert done == sorted(done), "progress never goes back"
    assert r["calls"][-1] == [3.0, 3], r["calls"][-3:]
    assert r["chans"][0] == r["chans"][1], "every input layer is kept"
    if os.environ.get("RADN_REQUIRE_OIDN"):
        assert r["path"].startswith("guided path"), r["path"]


def test_denoise_errors_carry_radns_message(env, tmp_path):
    _, py = env
    seq = tmp_path / "seq"
    seq.mkdir()
    for f in (1, 2, 4):  # frame 3 missing
        shutil.copy(SAMPLE / f"frame_{f:04d}.exr", seq / f"frame_{f:04d}.exr")
    r = run_py(py, f"""
        import json, radn
        msgs = []
        for args, frames in ((({str(seq / 'frame_####.exr')!r}, {str(seq / 'frame_####.exr')!r}), "1-2"),
                             (({str(seq / 'frame_####.exr')!r}, {str(tmp_path / 'o' / 'f_####.exr')!r}), "1-4")):
            try:
                radn.denoise(*args, frames=frames)
                msgs.append(None)
            except radn.RadnError as e:
                msgs.append(str(e))
        print(json.dumps(msgs))
    """, tmp_path)
    assert r[0] is not None and "output" in r[0] and "input" in r[0], r[0]
    assert r[1] is not None and "frame_0003.exr" in r[1], r[1]
    assert sorted(p.name for p in seq.iterdir()) == ["frame_0001.exr", "frame_0002.exr", "frame_0004.exr"]


def test_a_cancelled_run_leaves_no_partial_file_and_resumes(env, tmp_path):
    _, py = env
    out = tmp_path / "out"
    r = run_py(py, f"""
        import json, threading, radn
        stop = threading.Event()
        def progress(done, total):
            if done >= 0.7 * total:  # in the last stage, which writes the outputs
                stop.set()
        try:
            radn.denoise({str(SAMPLE / 'frame_####.exr')!r}, {str(out / 'frame_####.exr')!r},
                         progress=progress, cancel=stop, threads=1)
            outcome = "finished"
        except radn.Cancelled as e:
            outcome = "cancelled: " + str(e)
        kept = sorted(p.name for p in __import__("pathlib").Path({str(out)!r}).iterdir())
        rest = radn.denoise({str(SAMPLE / 'frame_####.exr')!r}, {str(out / 'frame_####.exr')!r})
        print(json.dumps({{"outcome": outcome, "kept": kept, "resumed": [rest.written, rest.skipped]}}))
    """, tmp_path)
    assert r["outcome"].startswith("cancelled"), r
    # only whole frames, named as outputs: no temporary file, lock or scratch folder
    assert all(n.startswith("frame_") and n.endswith(".exr") for n in r["kept"]), r["kept"]
    assert 1 <= len(r["kept"]) < 9, r["kept"]
    assert r["resumed"] == [9 - len(r["kept"]), len(r["kept"])]
    assert sorted(p.name for p in out.iterdir()) == [f"frame_{f:04d}.exr" for f in range(1, 10)]
