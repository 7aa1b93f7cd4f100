"""Probe: MJX against C MuJoCo on the same fast model, a torque-limited (1 N·m) spin-up.

MuJoCo C (and MuJoCo Warp) leave an actuator clamped by its force range out of the
implicit integrator's damping (mjd_actuator_vel); MJX 3.x (impl="jax", derivative.py
deriv_smooth_vel) always adds -kv. Prints body ωz, the wheels' implied ωz and wheel 0's
torque every 20 ms for both engines (docs/physics_model.md).

    .venv/bin/python experiments/mjx_vs_c_clamped_actuator.py
"""

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.sim import mjcf
from mecanum_jax.sim.description import builtin_description

base = builtin_description("o_rectangle")
desc = dataclasses.replace(
    base,
    sim=dataclasses.replace(base.sim, timestep=0.002),
    actuators=dataclasses.replace(base.actuators, max_torque=1.0),
)
m = mujoco.MjModel.from_xml_string(mjcf.build_mjcf(desc, "fast"))
names = ["left_front", "left_back", "right_back", "right_front"]
geom = desc.build_geometry(warn_singular=False)
rates = np.asarray(kinematics.inverse(geom, np.array([0.0, 0.0, -5.5])))
F = np.asarray(kinematics.forward_matrix(geom))
rq = np.array([m.jnt_qposadr[m.joint(f"{n}_roller").id] for n in names])
ad = np.array([m.jnt_dofadr[m.joint(f"{n}_axle").id] for n in names])
# C MuJoCo
d = mujoco.MjData(m)
mujoco.mj_forward(m, d)
c_rows = []
for t in range(150):
    d.qpos[rq] = 0
    d.ctrl[:] = rates
    mujoco.mj_step(m, d)
    if (t + 1) % 10 == 0:
        c_rows.append((d.qvel[5], (F @ d.qvel[ad])[2], d.actuator_force[0]))
# MJX
mx = mjx.put_model(m, impl="jax")
dx = mjx.make_data(mx)


@jax.jit
def step(dx):
    dx = dx.replace(qpos=dx.qpos.at[rq].set(0.0), ctrl=jnp.asarray(rates, jnp.float32))
    with jax.numpy_rank_promotion("allow"):
        return mjx.step(mx, dx)


with jax.numpy_rank_promotion("allow"):
    dx = jax.jit(mjx.forward)(mx, dx)
j_rows = []
for t in range(150):
    dx = step(dx)
    if (t + 1) % 10 == 0:
        qv = np.asarray(dx.qvel)
        j_rows.append((qv[5], (F @ qv[ad])[2], float(dx.actuator_force[0])))
for lab, rows in (("C  ", c_rows), ("MJX", j_rows)):
    print(lab, "body ", " ".join(f"{r[0]:6.2f}" for r in rows))
    print(lab, "wheel", " ".join(f"{r[1]:6.2f}" for r in rows))
    print(lab, "tau  ", " ".join(f"{r[2]:6.2f}" for r in rows))
