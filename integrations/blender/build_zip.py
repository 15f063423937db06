"""Builds the Blender extension zip: the add-on's files, its manifest completed with the bundled
radn wheel and the platform that wheel runs on. Used by scripts/package.

    python3 integrations/blender/build_zip.py WHEEL OUT_DIR   # prints the zip's path
"""

from __future__ import annotations

import re
import sys
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "radn_denoise"

#: wheel platform tag (its end) -> Blender's platform name
PLATFORMS = (
    (re.compile(r"(manylinux|musllinux|linux).*_x86_64$"), "linux-x64"),
    (re.compile(r"(manylinux|musllinux|linux).*_aarch64$"), "linux-arm64"),
    (re.compile(r"macosx_.*_(arm64|universal2)$"), "macos-arm64"),
    (re.compile(r"macosx_.*_x86_64$"), "macos-x64"),
    (re.compile(r"win_amd64$"), "windows-x64"),
    (re.compile(r"win_arm64$"), "windows-arm64"),
)


def platform_of(wheel: Path) -> str:
    """Blender's name for the platform a wheel's tag says it runs on."""
    tag = wheel.stem.split("-")[-1]
    for part in tag.split("."):
        for pattern, name in PLATFORMS:
            if pattern.search(part):
                return name
    raise SystemExit(f"{wheel.name}: no Blender platform for the wheel tag '{tag}'")


def manifest_with(wheel: Path, text: str) -> str:
    """The manifest with `platforms` and `wheels` for the bundled wheel (before [permissions])."""
    if re.search(r"^\s*(wheels|platforms)\s*=", text, re.M):
        raise SystemExit("blender_manifest.toml already lists wheels or platforms: scripts/package adds them")
    lines = f'platforms = ["{platform_of(wheel)}"]\nwheels = ["./wheels/{wheel.name}"]\n\n'
    at = text.find("[permissions]")
    return text[:at] + lines + text[at:] if at >= 0 else text + "\n" + lines


def version_of(manifest: str) -> str:
    """The extension's version from its manifest."""
    m = re.search(r'^version\s*=\s*"([^"]+)"', manifest, re.M)
    if not m:
        raise SystemExit("blender_manifest.toml has no version")
    return m.group(1)


def build(wheel: Path, out_dir: Path) -> Path:
    """Writes radn_denoise-VERSION-PLATFORM.zip into out_dir; returns its path."""
    manifest = (SOURCE / "blender_manifest.toml").read_text()
    version = version_of(manifest)
    out_dir.mkdir(parents=True, exist_ok=True)
    out = out_dir / f"radn_denoise-{version}-{platform_of(wheel).replace('-', '_')}.zip"
    tmp = out.with_suffix(".zip.tmp")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(SOURCE.rglob("*")):
            if f.is_dir() or "__pycache__" in f.parts or f.suffix == ".pyc":
                continue
            rel = f.relative_to(SOURCE).as_posix()
            if rel == "blender_manifest.toml":
                z.writestr(rel, manifest_with(wheel, manifest))
            else:
                z.write(f, rel)
        # stored as is: a wheel is a zip already
        z.write(wheel, f"wheels/{wheel.name}", compress_type=zipfile.ZIP_STORED)
    tmp.replace(out)
    return out


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    print(build(Path(sys.argv[1]), Path(sys.argv[2])))
