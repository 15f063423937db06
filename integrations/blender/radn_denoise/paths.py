"""Where the render's frames are, where radn writes, and Blender's own OIDN library."""

from __future__ import annotations

import glob
import os
import re
import sys

import bpy


def render_sequence(scene: bpy.types.Scene) -> str:
    """The pattern (`####` for the frame) of the frames an animation render of `scene` writes.

    Blender replaces the last run of `#` in the file name with the frame number, or appends four
    digits when there is none, then adds the extension when "File Extensions" is on.
    """
    path = bpy.path.abspath(scene.render.filepath)
    folder, name = os.path.split(path)
    if "#" not in name:
        name += "####"
    if scene.render.use_file_extension:
        name += scene.render.file_extension
    return os.path.join(folder, name)


def default_output(input_pattern: str) -> str:
    """A `radn/` folder beside the input, the same file names: never over the render."""
    folder, name = os.path.split(input_pattern)
    return os.path.join(folder, "radn", name)


def resolve_output(setting: str, input_pattern: str) -> str:
    """The output pattern from the panel's setting: empty means [`default_output`]; a folder
    (ends with a separator) gets the input's file name; `//` is relative to the .blend file."""
    if not setting.strip():
        return default_output(input_pattern)
    out = bpy.path.abspath(setting)
    if out.endswith(("/", "\\")) or os.path.isdir(out):
        return os.path.join(out, os.path.basename(input_pattern))
    if "#" not in os.path.basename(out) and not re.search(r"%0?\d*d|\$F\d*", out):
        root, ext = os.path.splitext(out)
        out = root + "####" + (ext or ".exr")
    return out


def blender_oidn_library() -> str | None:
    """The Intel Open Image Denoise library this Blender ships (the one Cycles uses), if any."""
    names = {
        "linux": "libOpenImageDenoise.so*",
        "darwin": "libOpenImageDenoise*.dylib",
        "win32": "OpenImageDenoise.dll",
    }
    pattern = names.get(sys.platform, "libOpenImageDenoise.so*")
    roots = []
    if bpy.app.binary_path:  # Blender the application
        exe_dir = os.path.dirname(bpy.app.binary_path)
        roots += [
            os.path.join(exe_dir, "lib"),
            os.path.join(exe_dir, "blender.shared"),
            os.path.join(exe_dir, "..", "Resources", "lib"),
            exe_dir,
        ]
    # beside the versioned resources folder (<install>/4.5 -> <install>/lib); the `bpy` module
    # from PyPI keeps its libraries there too (bpy/4.5 -> bpy/lib)
    local = bpy.utils.resource_path("LOCAL")
    if local:
        roots.append(os.path.join(local, "..", "lib"))
    for root in roots:
        found = sorted(glob.glob(os.path.join(root, pattern)))
        # the soname link (libOpenImageDenoise.so.2) rather than a versioned file or a device
        found = [f for f in found if "device" not in os.path.basename(f)]
        if found:
            return os.path.abspath(min(found, key=len))
    return None
