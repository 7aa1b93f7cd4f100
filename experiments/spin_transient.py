"""Probe: the fast model's body yaw rate against its wheels during a spin start.

A nominal O-rectangle robot at rest is commanded the spin of seed 000's six-modes
scenario (ωz = -5.5 rad/s, the inverse model's wheel rates). For each physics timestep it
prints, per 20 ms control step, the body's ωz, the ωz its wheel rates imply (least-squares
forward kinematics, i.e. no slip), and the chassis' rise above its resting height.

Finding (2026-11-22, CPU): the chassis hops at spin-up, and the yaw rate changes only in
impacts (it is constant while airborne). At the training environment's 4 ms step it hops
about 3 mm and the body spins at -8.65 rad/s while the wheels imply -4.2: a 1.6x overshoot
of the command for ~0.1 s, which a real robot with slipping wheels could not do. At 2 ms
the hops are about 1 mm and there is no overshoot. See docs/physics_model.md.
Those figures were taken with MJX's own servo; since 2026-11-22 the default chord servo
(physics.Robot._chord_servo) removes the over-spin, the 3 N·m / 4 ms hop remains (3.5 mm).

    .venv/bin/python experiments/spin_transient.py [--timesteps 0.002 0.004] [--wz -5.5]
"""

from __future__ import annotations

import argparse
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.sim import physics
from mecanum_jax.sim.description import builtin_description


def probe(timestep: float, wz: float, control_steps: int = 12) -> list[tuple[float, float, float]]:
    """(body ωz, wheel-implied ωz, max rise in mm) per control step of 20 ms."""
    base = builtin_description("o_rectangle")
    sim = dataclasses.replace(
        base.sim, timestep=timestep, contact_timeconst=max(0.008, 2 * timestep)
    )
    robot = physics.Robot(dataclasses.replace(base, sim=sim), "fast")
    params = robot.nominal_params()
    rates = kinematics.inverse(robot.geometry, jnp.array([0.0, 0.0, wz]))
    forward = np.asarray(kinematics.forward_matrix(robot.geometry))
    substeps = round(0.02 / robot.dt)
    step = jax.jit(lambda s: robot.step(s, rates, params, 1))
    state = robot.reset(params)
    z0 = float(state.data.qpos[2])
    out = []
    for _ in range(control_steps):
        rise = 0.0
        for _ in range(substeps):
            state = step(state)
            rise = max(rise, float(state.data.qpos[2]) - z0)
        sens = robot.sensors(state)
        implied = float((forward @ np.asarray(sens.wheel_rate))[2])
        out.append((float(sens.twist[2]), implied, 1000 * rise))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=float, nargs="+", default=[0.002, 0.004])
    parser.add_argument("--wz", type=float, default=-5.5)
    args = parser.parse_args()
    for ts in args.timesteps:
        if not 0 < ts <= 0.01:
            parser.error(f"--timesteps: {ts} must be in (0, 0.01] s")
        rows = probe(ts, args.wz)
        print(f"timestep {ts * 1000:g} ms, command ωz {args.wz} rad/s")
        print("  body ωz   " + " ".join(f"{r[0]:6.2f}" for r in rows))
        print("  wheels ωz " + " ".join(f"{r[1]:6.2f}" for r in rows))
        print("  rise mm   " + " ".join(f"{r[2]:6.2f}" for r in rows))


if __name__ == "__main__":
    main()
