"""The export's self-check on the robot: ``python mecanum_robot.zip [POLICY ...]``.

Packed into the export's archive as ``__main__.py``, so that, run in the folder holding
the export, the archive loads each policy file (default: ``policy.npz`` and
``policy.onnx``, those present), ticks its control loop 500 times with the sensors frozen
at rest, and prints the setpoints and the time a tick takes on this machine, against the
control period. NumPy alone (onnxruntime for ``.onnx``), like the loop itself.

Exit code 0 when every file ran, 1 when a backend's module is missing (onnxruntime), 2
for a file that is missing or not an export.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

if __package__:  # inside the mecanum_jax package
    from mecanum_jax.deploy.loop import Controller
    from mecanum_jax.deploy.policy import ExportError
else:  # pragma: no cover - the archive's __main__.py, beside mecanum_loop.py in it
    from mecanum_loop import Controller  # type: ignore[no-redef]
    from mecanum_policy import ExportError  # type: ignore[no-redef]

TICKS = 500
DEFAULT = ("policy.npz", "policy.onnx")


def run(path: str, ticks: int = TICKS) -> str:
    """``ticks`` of the loop for the export at ``path``, the sensors frozen at rest and a
    fixed command: a report of two lines."""
    ctrl = Controller.load(path)
    ctrl.reset()
    command, wheel_rate, accel = [0.3, 0.0, 0.5], np.zeros(ctrl.n_wheels), [0.0, 0.0, 9.81]
    t0 = time.perf_counter()
    for _ in range(ticks):
        setpoints, action = ctrl.step(command, wheel_rate, 0.0, accel)
    tick_ms = (time.perf_counter() - t0) / ticks * 1e3
    period_ms = float(ctrl.policy.meta["control_dt"]) * 1e3
    return (
        f"{path} ({ctrl.backend}): setpoints {np.round(setpoints, 2)} rad/s for command "
        f"{command}, action {np.round(action, 3)}\n"
        f"  {tick_ms:.2f} ms a tick of the {period_ms:.0f} ms control period"
    )


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    paths = args or [p for p in DEFAULT if Path(p).exists()]
    if not paths:
        print(f"no policy file given and none of {', '.join(DEFAULT)} here", file=sys.stderr)
        return 2
    code = 0
    for path in paths:
        try:
            print(run(path), flush=True)
        except ImportError as err:
            print(f"{path}: {err} (the .onnx backend needs onnxruntime)", file=sys.stderr)
            code = max(code, 1)
        except (OSError, ExportError) as err:
            print(f"{path}: {err}", file=sys.stderr)
            code = 2
    return code


__all__ = ["main", "run"]

if __name__ == "__main__":
    sys.exit(main())
