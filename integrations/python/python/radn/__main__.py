"""`python -m radn ARGS` runs the `radn` command that came with this package."""

import subprocess
import sys

from ._binary import binary_path

if __name__ == "__main__":
    sys.exit(subprocess.call([str(binary_path()), *sys.argv[1:]]))
