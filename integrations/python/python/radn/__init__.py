"""radn: temporal Monte Carlo denoising of rendered EXR sequences.

The wheel carries the compiled `radn` command; this package runs it. See :func:`denoise` and
:func:`inspect`.
"""

from ._binary import binary_path
from ._run import Cancelled, DenoiseResult, RadnError, denoise, inspect

try:
    from importlib.metadata import version as _version

    __version__ = _version("radn")
except Exception:  # not installed as a distribution (a source checkout)
    __version__ = "0+unknown"

__all__ = ["denoise", "inspect", "DenoiseResult", "RadnError", "Cancelled", "binary_path", "__version__"]
