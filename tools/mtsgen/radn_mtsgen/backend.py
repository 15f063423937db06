"""Mitsuba 3 with its LLVM backend: the vectorised variant every ray cast and render here uses.
Its JIT needs a shared libLLVM 16 or newer (Debian: `apt-get install libllvm19`)."""

from __future__ import annotations

import glob
import os

VARIANT = "llvm_ad_rgb"


class BackendError(RuntimeError):
    """Mitsuba or the LLVM library it needs is missing."""


def _find_llvm() -> str | None:
    for pattern in ("/usr/lib/x86_64-linux-gnu/libLLVM-*.so", "/usr/lib/aarch64-linux-gnu/libLLVM-*.so",
                    "/usr/lib/llvm-*/lib/libLLVM*.so", "/usr/local/lib/libLLVM*.so"):
        found = []
        for f in glob.glob(pattern):
            digits = "".join(c if c.isdigit() else " " for c in os.path.basename(f)).split()
            if digits and int(digits[0]) >= 16:
                found.append((int(digits[0]), f))
        if found:
            return max(found)[1]
    return None


def mitsuba():
    """The `mitsuba` module with the LLVM variant set (imported once)."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        lib = _find_llvm()
        if lib is None:
            raise BackendError("Mitsuba's LLVM backend needs libLLVM 16 or newer: apt-get install libllvm19 "
                               "(or set DRJIT_LIBLLVM_PATH)")
        os.environ["DRJIT_LIBLLVM_PATH"] = lib
    try:
        import mitsuba as mi
    except ImportError as e:
        raise BackendError(f"mitsuba is not installed ({e}): pip install -r tools/mtsgen/requirements.txt") from None
    if mi.variant() != VARIANT:
        mi.set_variant(VARIANT)
    return mi
