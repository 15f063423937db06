"""Finding the `radn` binary that came with this package."""

from __future__ import annotations

import os
import shutil
import stat
import sys
import sysconfig
from pathlib import Path

_EXE = "radn.exe" if os.name == "nt" else "radn"


def _candidates() -> list[Path]:
    """Where a wheel's binary can be, most specific first."""
    here = Path(__file__).resolve().parent
    site = here.parent
    out: list[Path] = []
    override = os.environ.get("RADN_BINARY")
    if override:
        out.append(Path(override))
    # Blender's extension installer leaves a wheel's scripts in `radn-X.data/scripts/` beside
    # the package instead of a `bin/` folder
    out.extend(sorted(site.glob("radn-*.data/scripts/" + _EXE), reverse=True))
    for scheme in (None, f"{os.name}_user"):
        try:
            scripts = sysconfig.get_path("scripts", scheme) if scheme else sysconfig.get_path("scripts")
        except KeyError:
            continue
        if scripts:
            out.append(Path(scripts) / _EXE)
    # `pip install --target DIR` puts scripts in DIR/bin
    out.append(site / "bin" / _EXE)
    # a virtual environment's or prefix's bin, from site-packages (lib/pythonX.Y/site-packages)
    out.append(site.parent.parent.parent / ("Scripts" if os.name == "nt" else "bin") / _EXE)
    on_path = shutil.which("radn")
    if on_path:
        out.append(Path(on_path))
    return out


def _make_executable(path: Path) -> None:
    """Zip extraction (Blender's wheel installer) drops the executable bit: restore it."""
    if os.name == "nt" or os.access(path, os.X_OK):
        return
    mode = path.stat().st_mode
    path.chmod(mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)


def binary_path() -> Path:
    """The `radn` binary this package runs (`RADN_BINARY` overrides).

    Raises FileNotFoundError naming the places searched when there is none.
    """
    tried = _candidates()
    for path in tried:
        if path.is_file():
            _make_executable(path)
            return path
    places = "\n  ".join(str(p) for p in tried)
    raise FileNotFoundError(
        f"the radn binary is missing (looked in:\n  {places})\n"
        f"reinstall the wheel (pip install --force-reinstall radn) or set RADN_BINARY; "
        f"Python {sys.version.split()[0]} at {sys.prefix}"
    )
