"""PyBullet, imported without its build-time banner.

Importing pybullet prints "pybullet build time: ..." on stderr from C; every command of the project
keeps stderr for its own messages (one clear line on bad input), so the simulator's modules take
pybullet from here, imported once with stderr pointed at /dev/null.
"""

from __future__ import annotations

import os
import sys


def _import_quietly():
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            import pybullet
    finally:
        os.dup2(saved, 2)
        os.close(saved)
    return pybullet


p = _import_quietly()
