"""Import MuJoCo MJX without the messages of its optional Warp-backend probe.

``mujoco.mjx`` tries to import ``warp`` when it is first imported and *prints* "Failed to
import warp: ..." and "Failed to import mujoco_warp: ..." to standard output where it is
not installed (it is an optional extra). Every module of this project that imports MJX or
Brax imports this one first, so those two lines stay out of the user's terminal; any other
output of the import is passed through. With ``MJX_WARP_ENABLED`` set (the Warp backend
requested), nothing is filtered.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys

_PROBE_PREFIXES = ("Failed to import warp:", "Failed to import mujoco_warp:")


def import_mjx() -> None:
    """Import ``mujoco.mjx`` once, dropping its Warp probe's messages (see module doc)."""
    if "mujoco.mjx" in sys.modules or os.environ.get("MJX_WARP_ENABLED", "").lower() in (
        "1",
        "true",
    ):
        import mujoco.mjx

        return
    captured = io.StringIO()
    try:
        with contextlib.redirect_stdout(captured):
            import mujoco.mjx  # noqa: F401
    finally:
        for line in captured.getvalue().splitlines(keepends=True):
            if not line.startswith(_PROBE_PREFIXES):
                sys.stdout.write(line)


import_mjx()
