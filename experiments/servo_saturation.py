"""Probe: saturated wheel servos in MJX against a converged simulation of the same model.

A nominal O-rectangle robot at rest is commanded the six-modes spin (ωz = -5.5 rad/s) or
a forward step (vx = 1 m/s) through the inverse model's wheel rates, with a torque limit
low enough that the servos saturate. The *converged* run is C MuJoCo on the same fast
model at a 0.25 ms step (C MuJoCo leaves clamped actuators out of the implicit damping,
and at this step the servo is nearly explicit anyway). Against it, MJX at the
training environment's 4 ms and the description's 2 ms step, with

- ``mjx``: MJX's own velocity servo, which keeps the implicit ``-kp·Δω`` when clamped;
- ``chord``: the library's default (physics.Robot._chord_servo), gain limit/|error|
  while saturated.

Prints body ωz (or vx), the value the wheels imply without slip, every 20 ms, the RMS
difference from the converged run over the first 0.3 s, and the chassis' largest rise.
All runs use the same contact time constant (8 ms, the training environment's).

    .venv/bin/python experiments/servo_saturation.py [--limits 1 3] [--mode spin|forward]
"""

from __future__ import annotations

import argparse
import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.sim import mjcf, physics
from mecanum_jax.sim.description import RobotDescription, builtin_description

CONTROL = 0.02
SECONDS = 0.3
TIMECONST = 0.008
ROTOR = {"value": None}  # --rotor-inertia override (None: the description's)


def _desc(timestep: float, limit: float) -> RobotDescription:
    base = builtin_description("o_rectangle")
    if ROTOR["value"] is not None:
        base = dataclasses.replace(
            base, motors=dataclasses.replace(base.motors, rotor_inertia=ROTOR["value"])
        )
    return dataclasses.replace(
        base,
        sim=dataclasses.replace(base.sim, timestep=timestep, contact_timeconst=TIMECONST),
        actuators=dataclasses.replace(base.actuators, max_torque=limit, ki=0.0),
    )


def _command(mode: str) -> np.ndarray:
    return np.array([0.0, 0.0, -5.5]) if mode == "spin" else np.array([1.0, 0.0, 0.0])


def converged(limit: float, mode: str, timestep: float = 0.00025) -> np.ndarray:
    """(samples, 3): body value, wheel-implied value, max rise (mm) per 20 ms, C MuJoCo."""
    desc = _desc(timestep, limit)
    m = mujoco.MjModel.from_xml_string(mjcf.build_mjcf(desc, "fast"))
    _, index = mjcf.build_model(desc, "fast")
    geom = desc.build_geometry(warn_singular=False)
    rates = np.asarray(kinematics.inverse(geom, _command(mode)))
    F = np.asarray(kinematics.forward_matrix(geom))
    col = 2 if mode == "spin" else 0
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    z0 = d.qpos[index.free_qpos + 2]
    per = round(CONTROL / timestep)
    rows, rise = [], 0.0
    for t in range(round(SECONDS / timestep)):
        d.qpos[index.carrier_qpos] = 0.0
        d.ctrl[index.actuators] = rates
        mujoco.mj_step(m, d)
        rise = max(rise, d.qpos[index.free_qpos + 2] - z0)
        if (t + 1) % per == 0:
            R = d.xmat[index.chassis_body].reshape(3, 3)
            body = R.T @ d.qvel[index.free_dof : index.free_dof + 3]
            value = d.qvel[index.free_dof + 5] if mode == "spin" else body[0]
            rows.append((value, (F @ d.qvel[index.axle_dof])[col], 1000 * rise))
            rise = 0.0
    return np.array(rows)


def mjx_run(limit: float, mode: str, timestep: float, servo: physics.ServoModel) -> np.ndarray:
    """Like :func:`converged`, in MJX through physics.Robot."""
    robot = physics.Robot(_desc(timestep, limit), "fast", servo=servo)
    params = robot.nominal_params()
    rates = kinematics.inverse(robot.geometry, jnp.asarray(_command(mode)))
    F = np.asarray(kinematics.forward_matrix(robot.geometry))
    col = 2 if mode == "spin" else 0
    step = jax.jit(lambda s: robot.step(s, rates, params, 1))
    state = robot.reset(params)
    z0 = float(state.data.qpos[robot.index.free_qpos + 2])
    rows = []
    for _ in range(round(SECONDS / CONTROL)):
        rise = 0.0
        for _ in range(round(CONTROL / timestep)):
            state = step(state)
            rise = max(rise, float(state.data.qpos[robot.index.free_qpos + 2]) - z0)
        sens = robot.sensors(state)
        implied = float((F @ np.asarray(sens.wheel_rate))[col])
        rows.append((float(sens.twist[col]), implied, 1000 * rise))
    return np.array(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--limits", type=float, nargs="+", default=[1.0, 3.0])
    parser.add_argument("--mode", choices=["spin", "forward"], default="spin")
    parser.add_argument("--timesteps", type=float, nargs="+", default=[0.004, 0.002])
    parser.add_argument("--rotor-inertia", type=float, default=None, help="kg·m², motor side")
    args = parser.parse_args()
    ROTOR["value"] = args.rotor_inertia
    for limit in args.limits:
        if limit <= 0:
            parser.error(f"--limits: {limit} must be > 0 N·m")
        ref = converged(limit, args.mode)
        print(f"\n{args.mode}, torque limit {limit:g} N·m (every 20 ms)")
        print(f"  {'converged 0.25 ms':24s} body  " + " ".join(f"{v:6.2f}" for v in ref[:, 0]))
        print(f"  {'':24s} wheel " + " ".join(f"{v:6.2f}" for v in ref[:, 1]))
        print(f"  {'':24s} max rise {ref[:, 2].max():.2f} mm")
        for ts in args.timesteps:
            for servo in ("mjx", "chord"):
                rows = mjx_run(limit, args.mode, ts, servo)
                rms = float(np.sqrt(np.mean((rows[:, 0] - ref[:, 0]) ** 2)))
                label = f"MJX {ts * 1000:g} ms {servo}"
                print(f"  {label:24s} body  " + " ".join(f"{v:6.2f}" for v in rows[:, 0]))
                print(f"  {'':24s} wheel " + " ".join(f"{v:6.2f}" for v in rows[:, 1]))
                print(f"  {'':24s} RMS vs converged {rms:.3f}, max rise {rows[:, 2].max():.2f} mm")


if __name__ == "__main__":
    main()
