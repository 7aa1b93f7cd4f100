"""What limits the fast fidelity's physics steps/s: MJX options side by side, one process.

Each variant is the fast O-rectangle robot (chord servo, 2 ms step) with one change to
the simulated model; all are timed by ``mecanum_jax.bench.time_physics`` (a jitted,
vmapped scan of ``--steps`` physics steps, median of ``--repeats``) on the same device in
one run, so their ratios are comparable. ``unstable`` counts robots that went
non-finite during the timed calls (a variant that is fast but unstable is no option).

    python experiments/physics_speed_sweep.py [--sizes 65536] [--variants default strip ...]
        [--json-out FILE]

Variants (``strip`` = the draw-only geoms removed, ``Robot(strip_visual=True)``):
``default`` (all geoms simulated), ``strip``, ``newton3``/``newton4``/``newton6``/``newton8``
(3, 4, 6, 8 Newton iterations instead of the description's 12),
``cg6``/``cg10`` (conjugate gradient, 6/10 iterations), ``elliptic`` (elliptic friction
cone), ``sparse`` (sparse constraint Jacobian), ``ls1`` (1 line-search iteration), and
``nocontact``/``noconstraint`` (contacts or the whole constraint solver off: upper bounds
that show what the solver costs, not usable models).
"""

from __future__ import annotations

import argparse
import datetime
import json
from pathlib import Path
from typing import Any

import jax
import mujoco
from mujoco import mjx

from mecanum_jax.bench import time_physics
from mecanum_jax.sim import physics
from mecanum_jax.sim.description import builtin_description

VARIANTS: dict[str, tuple[bool, dict[str, Any]]] = {
    "default": (False, {}),
    "strip": (True, {}),
    "newton3": (True, {"iterations": 3}),
    "newton4": (True, {"iterations": 4}),
    "newton6": (True, {"iterations": 6}),
    "newton8": (True, {"iterations": 8}),
    "cg6": (True, {"solver": int(mujoco.mjtSolver.mjSOL_CG), "iterations": 6}),
    "cg10": (True, {"solver": int(mujoco.mjtSolver.mjSOL_CG), "iterations": 10}),
    "elliptic": (True, {"cone": int(mujoco.mjtCone.mjCONE_ELLIPTIC)}),
    "sparse": (True, {"jacobian": int(mujoco.mjtJacobian.mjJAC_SPARSE)}),
    "ls1": (True, {"ls_iterations": 1}),
    "nocontact": (True, {"disableflags": int(mujoco.mjtDisableBit.mjDSBL_CONTACT)}),
    "noconstraint": (True, {"disableflags": int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)}),
}


def make_robot(name: str, robot_name: str = "o_rectangle") -> physics.Robot:
    strip, options = VARIANTS[name]
    robot = physics.Robot(builtin_description(robot_name), "fast", strip_visual=strip)
    if options:
        m = robot.sim_model
        for key, value in options.items():
            if key == "disableflags":
                value = int(m.opt.disableflags) | value
            setattr(m.opt, key, value)
        robot.mjx_model = mjx.put_model(m, impl="jax")
    return robot


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[65536])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json-out", type=Path)
    args = ap.parse_args()
    if any(n < 1 for n in args.sizes) or args.steps < 1 or args.repeats < 1:
        ap.error(f"--sizes {args.sizes}, --steps {args.steps}, --repeats {args.repeats}: need >= 1")
    dev = jax.devices()[0]
    print(f"device: {dev.platform}: {dev.device_kind}, jax {jax.__version__}")
    rows = []
    for name in args.variants:
        robot = make_robot(name)
        for row in time_physics(robot, args.sizes, args.steps, args.repeats):
            rows.append({"variant": name, **row})
            print(
                f"{name:12s} batch {row['size']:7d}: {row['steps_per_s']:11.4g} steps/s "
                f"({1e3 * row['seconds_per_call'] / args.steps:.3f} ms/step, compile "
                f"{row['compile_s']:.1f} s, unstable {row['unstable']})",
                flush=True,
            )
    if args.json_out:
        args.json_out.parent.mkdir(parents=True, exist_ok=True)
        args.json_out.write_text(
            json.dumps(
                {
                    "benchmark": "physics_speed_sweep",
                    "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
                    "device": f"{dev.platform}: {dev.device_kind}",
                    "jax": jax.__version__,
                    "steps": args.steps,
                    "results": rows,
                },
                indent=2,
            )
        )


if __name__ == "__main__":
    main()
