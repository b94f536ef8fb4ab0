"""pybullet, imported once with its build-time banner silenced.

pybullet's C extension writes ``pybullet build time: ...`` to the process's stderr when it
loads: into every role's log and every command's output. Importing it here, with file
descriptors 1 and 2 pointed at /dev/null for that moment, keeps the banner out (an import
error still raises as usual); every simulator module imports ``p`` from here.
"""

from __future__ import annotations

import os
import sys


def _import_quietly():
    try:
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        saved = [os.dup(1), os.dup(2)]
    except (OSError, ValueError, AttributeError):  # no usable stdio: nothing to keep clean
        import pybullet

        return pybullet
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
            os.dup2(null.fileno(), 2)
            import pybullet
    finally:
        for fd, copy in zip((1, 2), saved):
            os.dup2(copy, fd)
            os.close(copy)
    return pybullet


p = _import_quietly()
