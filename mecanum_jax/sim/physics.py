"""Batched MJX physics of a mecanum robot: reset, step, sensors, per-robot parameters.

The functions here simulate **one** robot; batch them with ``jax.vmap`` (see
:meth:`Robot.batched`; on the CPU in chunks, :mod:`mecanum_jax.sim.batching`). Per-robot
physical parameters (:class:`~mecanum_jax.sim.state.RobotParams`: floor
friction per wheel, payload mass and centre of mass, wheel-radius error, torque limit,
servo gains, setpoint slew limit) are arguments, so domain randomisation varies them per
robot without rebuilding the model: they are written into that robot's copy of the
``mjx.Model`` inside the vmapped step.

Actuation, as on seed 004's robot: each wheel has a speed servo with a torque limit
(:mod:`mecanum_jax.sim.servo`). Commands are wheel-rate setpoints in rad/s.

Sensors (:func:`Robot.sensors`): wheel encoders (angle, rate), an IMU (gyro z and the
accelerometer's specific force, finite-differenced over the control step, body frame),
and, for evaluation only, the true pose and body twist.

A robot whose state turns non-finite is reset to its initial state in the same step and
its ``unstable`` counter incremented, so it never poisons the batch; see
:func:`~mecanum_jax.sim.state.unstable_robots` to report which robots and with which
parameters.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from mecanum_jax.kinematics.geometry import WheelGeometry
from mecanum_jax.precision import HIGHEST
from mecanum_jax.sim import mjcf
from mecanum_jax.sim.batching import chunked_vmap, cpu_chunk
from mecanum_jax.sim.description import RobotDescription, require_impl
from mecanum_jax.sim.servo import (
    CHORD_WARP_RANGE,
    ServoModel,
    axle_inverse_inertia,
    chord_servo,
    servo_control,
)
from mecanum_jax.sim.state import GRAVITY, RobotParams, Sensors, SimState
from mecanum_jax.sim.warp_cache import leave_the_persistent_cache
from mecanum_jax.sim.warp_streams import pin_external_streams

if TYPE_CHECKING:
    import numpy.typing as npt

MAX_ABS_QVEL = 2.0e3  # rad/s or m/s: beyond this a state counts as unstable
TIPPED_UP_Z = 0.7  # a chassis whose up axis has a world z below this (tilt > 45.6°) has tipped
MAX_ABS_QPOS = 1.0e5  # m or rad (wheel angles accumulate; 1e5 rad is > 1 h at 20 rad/s)


def _quat_to_yaw(q: jax.Array) -> jax.Array:
    w, x, y, z = q[0], q[1], q[2], q[3]
    return jnp.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def _quat_to_mat(q: jax.Array) -> jax.Array:
    w, x, y, z = q[0], q[1], q[2], q[3]
    return jnp.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


class Robot:
    """A compiled robot at one fidelity: the host model, its MJX model, and its index."""

    def __init__(
        self,
        desc: RobotDescription,
        fidelity: mjcf.Fidelity = "fast",
        servo: ServoModel = "chord",
        strip_visual: bool = True,
        robots: int = 1,
    ):
        """``strip_visual``: simulate a copy of the model without its draw-only geoms
        (:func:`mjcf.build_model`, same dynamics, fewer poses per step); ``mj_model``
        keeps them for rendering.

        ``robots``: with ``desc.sim.impl == "warp"``, the most robots one batched call
        simulates (all vmapped axes together): MuJoCo Warp's contact buffer is one for the
        whole batch, sized :data:`WARP_CONTACTS` per wheel and robot. The ``jax``
        implementation ignores it."""
        if servo not in ("chord", "mjx"):
            raise ValueError(f"servo = {servo!r}: must be 'chord' or 'mjx'")
        if not isinstance(robots, int) or robots < 1:
            raise ValueError(f"robots = {robots!r}: must be an integer >= 1")
        self.desc = desc
        self.fidelity = fidelity
        self.servo = servo
        self.impl = desc.sim.impl
        require_impl(self.impl)
        if self.impl == "warp":
            leave_the_persistent_cache()
            pin_external_streams()  # Warp's "unknown stream" (warp_streams.py)
        self._chord_on_warp = servo == "chord" and self.impl == "warp"
        self.robots = robots
        self.mj_model, self.index = mjcf.build_model(desc, fidelity)
        self.sim_model = self.mj_model
        if strip_visual:  # geom indices change: the index must be the simulated model's
            self.sim_model, self.index = mjcf.build_model(desc, fidelity, visual=False)
        # MJX's default device is jax.devices()[0], which another process of a
        # jax.distributed run cannot address; this process's first device always works
        self.mjx_model = mjx.put_model(
            self.sim_model, device=jax.local_devices()[0], impl=self.impl
        )
        if self.impl == "warp":
            self.mjx_model = _quiet_solver_limits(self.mjx_model)
        self.geometry: WheelGeometry = desc.build_geometry(warn_singular=False)
        self.n_wheels = self.geometry.n_wheels
        self.dt = float(self.mj_model.opt.timestep)
        per_robot = WARP_CONTACTS[fidelity] * self.n_wheels
        self.naconmax = per_robot * robots  # warp: contacts of the whole batch
        self.njmax = 4 * per_robot  # warp, per robot: a pyramidal condim-3 contact has 4 rows
        idx = self.index
        self._axle_qpos = jnp.asarray(idx.axle_qpos)
        self._axle_dof = jnp.asarray(idx.axle_dof)
        self._carrier_qpos = jnp.asarray(idx.carrier_qpos)
        self._acts = jnp.asarray(idx.actuators)
        self._wheel_geoms = jnp.asarray(idx.wheel_geoms)
        m = self.sim_model
        self._base_mass = float(m.body_mass[idx.chassis_body])
        self._base_ipos = jnp.asarray(m.body_ipos[idx.chassis_body])
        self._base_inertia = jnp.asarray(m.body_inertia[idx.chassis_body])
        self._geom_size = jnp.asarray(m.geom_size)
        self._geom_pos = jnp.asarray(m.geom_pos)
        self._roller_bodies = jnp.asarray(idx.roller_bodies)
        self._body_pos = jnp.asarray(m.body_pos)
        self._qpos0 = jnp.asarray(m.qpos0)
        self._axle_inv_inertia = jnp.asarray(axle_inverse_inertia(m, idx.axle_dof), jnp.float32)

    # --- parameters -------------------------------------------------------------------

    def nominal_params(self, **overrides: npt.ArrayLike) -> RobotParams:
        """The description's nominal parameters, with any field overridden (scalars broadcast)."""
        n = self.n_wheels
        a = self.desc.actuators
        base = {
            "friction": jnp.full((n,), self.desc.sim.floor_friction),
            "payload_mass": jnp.asarray(0.0),
            "payload_com": jnp.zeros(3),
            "radius_scale": jnp.ones(n),
            "torque_limit": jnp.full((n,), a.max_torque),
            "kp": jnp.full((n,), a.kp),
            "ki": jnp.full((n,), a.ki),
            "max_accel": jnp.asarray(a.max_accel),
        }
        for key, value in overrides.items():
            if key not in base:
                raise KeyError(f"{key!r} is not a RobotParams field; fields: {sorted(base)}")
            base[key] = jnp.broadcast_to(jnp.asarray(value, jnp.float32), base[key].shape)
        return RobotParams(**{k: jnp.asarray(v, jnp.float32) for k, v in base.items()})

    def model_for(self, params: RobotParams) -> mjx.Model:
        """This robot's MJX model with ``params`` written in (traceable; batched under vmap)."""
        m = self.mjx_model
        idx = self.index
        friction = m.geom_friction.at[self._wheel_geoms, 0].set(
            jnp.broadcast_to(params.friction[:, None], self._wheel_geoms.shape)
        )
        # payload: a point mass at payload_com, combined with the chassis about the new CoM
        mb, mp = self._base_mass, params.payload_mass
        total = mb + mp
        com = (mb * self._base_ipos + mp * params.payload_com) / total
        db, dp = self._base_ipos - com, params.payload_com - com

        def point(mass: jax.Array | float, d: jax.Array) -> jax.Array:
            return mass * jnp.array(
                [d[1] ** 2 + d[2] ** 2, d[0] ** 2 + d[2] ** 2, d[0] ** 2 + d[1] ** 2]
            )

        inertia = self._base_inertia + point(mb, db) + point(mp, dp)
        c = idx.chassis_body
        gain = m.actuator_gainprm.at[self._acts, 0].set(params.kp)
        bias = m.actuator_biasprm.at[self._acts, 2].set(-params.kp)
        # MuJoCo Warp drops a clamped actuator's damping from the implicit step, but the
        # chord servo's own slope already keeps every force within the limit, so under
        # warp its clamp sits beyond reach: the slope stays implicit, as under MJX's JAX
        limit = params.torque_limit * (CHORD_WARP_RANGE if self._chord_on_warp else 1.0)
        frange = m.actuator_forcerange.at[self._acts].set(jnp.stack([-limit, limit], -1))
        size, geom_pos, body_pos = self._geom_size, self._geom_pos, self._body_pos
        scale = params.radius_scale[:, None]
        # under warp the bounding sphere and box scale with the wheel: MuJoCo Warp's
        # broadphase culls pairs with them (a wheel larger than its bound would only touch
        # the floor once it had sunk in); MJX's JAX collision does not read them here
        rbound, aabb = m.geom_rbound, m.geom_aabb
        if self.impl == "warp":
            rbound = rbound.at[self._wheel_geoms].multiply(scale)
            aabb = aabb.at[self._wheel_geoms].multiply(
                scale.reshape(*scale.shape, *(1,) * (aabb.ndim - 1))
            )
        if self.fidelity == "fast":
            size = size.at[self._wheel_geoms[:, 0], 0].multiply(params.radius_scale)
        else:  # the whole roller ring scales about the axle: rollers, spheres, capsules
            size = (
                size.at[self._wheel_geoms, 0]
                .multiply(scale)
                .at[self._wheel_geoms, 1]
                .multiply(scale)
            )
            geom_pos = geom_pos.at[self._wheel_geoms].multiply(scale[..., None])
            body_pos = body_pos.at[self._roller_bodies].multiply(scale[..., None])
        return m.replace(
            geom_friction=friction,
            geom_size=size,
            geom_rbound=rbound,
            geom_aabb=aabb,
            geom_pos=geom_pos,
            body_pos=body_pos,
            body_mass=m.body_mass.at[c].set(total),
            body_ipos=m.body_ipos.at[c].set(com),
            body_inertia=m.body_inertia.at[c].set(inertia),
            actuator_gainprm=gain,
            actuator_biasprm=bias,
            actuator_forcerange=frange,
        )

    # --- simulation -------------------------------------------------------------------

    def reset(self, params: RobotParams, pose: npt.ArrayLike = (0.0, 0.0, 0.0)) -> SimState:
        """A robot at rest at world ``pose`` (x, y, yaw), wheels on the floor."""
        p = jnp.asarray(pose, jnp.float32)
        f = self.index.free_qpos
        qpos = self._qpos0
        half = p[2] / 2
        qpos = qpos.at[f : f + 2].set(p[:2])
        qpos = qpos.at[f + 3 : f + 7].set(jnp.stack([jnp.cos(half), 0.0, 0.0, jnp.sin(half)]))
        # wheels with a radius error stand the chassis higher or lower
        r_nominal = float(np.max(np.asarray(self.geometry.radii)))
        r = jnp.max(params.radius_scale * jnp.asarray(self.geometry.radii))
        qpos = qpos.at[f + 2].add(r - r_nominal)
        with jax.numpy_rank_promotion("allow"):
            data = self._make_data(params).replace(qpos=qpos)
        n = self.n_wheels
        return SimState(
            data=data,
            setpoint=jnp.zeros(n),
            integral=jnp.zeros(n),
            accel=jnp.array([0.0, 0.0, GRAVITY]),
            initial_qpos=qpos,
            unstable=jnp.asarray(0, jnp.int32),
        )

    def _make_data(self, params: RobotParams) -> mjx.Data:
        device = jax.local_devices()[0]
        if self.impl == "warp":  # Warp's data is built from the host model, with capacities
            return mjx.make_data(
                self.sim_model, device=device, impl="warp", naconmax=self.naconmax, njmax=self.njmax
            )
        return mjx.make_data(self.model_for(params), device=device)

    def _physics_step(
        self, model: mjx.Model, state: SimState, command: jax.Array, params: RobotParams
    ) -> SimState:
        data = state.data
        if self.fidelity == "fast":  # re-zero the carriers: the axle never tilts (mjx-model.md §2)
            data = data.replace(qpos=data.qpos.at[self._carrier_qpos].set(0.0))
        rate = data.qvel[self._axle_dof]
        setpoint, integral, ctrl = servo_control(
            state.setpoint, state.integral, command, rate, params, self.dt
        )
        if self.servo == "chord":
            model = chord_servo(
                model, self._acts, ctrl - rate, params, self.dt, self._axle_inv_inertia
            )
        with jax.numpy_rank_promotion("allow"):  # MJX relies on implicit rank promotion
            data = mjx.step(model, data.replace(ctrl=data.ctrl.at[self._acts].set(ctrl)))
        # Non-finite, or blown up while still finite (a diverging solve passes through huge
        # values first): either way the robot is reset. Normal |qvel| stays below ~300.
        finite = jnp.all(jnp.abs(data.qpos) < MAX_ABS_QPOS) & jnp.all(
            jnp.abs(data.qvel) < MAX_ABS_QVEL
        )
        data = data.replace(
            qpos=jnp.where(finite, data.qpos, state.initial_qpos),
            qvel=jnp.where(finite, data.qvel, 0.0),
            qacc_warmstart=jnp.where(finite, data.qacc_warmstart, 0.0),
        )
        return state.replace(
            data=data,
            setpoint=jnp.where(finite, setpoint, 0.0),
            integral=jnp.where(finite, integral, 0.0),
            unstable=state.unstable + (~finite).astype(jnp.int32),
        )

    def step(
        self, state: SimState, command: jax.typing.ArrayLike, params: RobotParams, substeps: int = 1
    ) -> SimState:
        """Advance ``substeps`` physics steps holding wheel-rate setpoints (n,) rad/s."""
        model = self.model_for(params)
        cmd = jnp.asarray(command, jnp.float32)
        v0 = self._linear_velocity_world(state.data)

        def body(s: SimState, _: None) -> tuple[SimState, None]:
            return self._physics_step(model, s, cmd, params), None

        state, _ = jax.lax.scan(body, state, None, length=substeps)
        v1 = self._linear_velocity_world(state.data)
        R = _quat_to_mat(state.data.qpos[self.index.free_qpos + 3 : self.index.free_qpos + 7])
        accel_world = (v1 - v0) / (substeps * self.dt) + jnp.array([0.0, 0.0, GRAVITY])
        return state.replace(accel=jnp.matmul(R.T, accel_world, precision=HIGHEST))

    def _linear_velocity_world(self, data: mjx.Data) -> jax.Array:
        d = self.index.free_dof
        return data.qvel[d : d + 3]

    def sensors(self, state: SimState) -> Sensors:
        """Encoders, IMU and (for evaluation) the true pose and body twist."""
        data = state.data
        f, d = self.index.free_qpos, self.index.free_dof
        q = data.qpos[f + 3 : f + 7]
        R = _quat_to_mat(q)
        v_body = jnp.matmul(R.T, data.qvel[d : d + 3], precision=HIGHEST)
        omega_body = data.qvel[d + 3 : d + 6]  # free-joint angular velocity is body-frame
        yaw = _quat_to_yaw(q)
        return Sensors(
            wheel_angle=data.qpos[self._axle_qpos],
            wheel_rate=data.qvel[self._axle_dof],
            gyro_z=omega_body[2],
            accel=state.accel,
            wheel_torque=data.actuator_force[self._acts],
            pose=jnp.stack([data.qpos[f], data.qpos[f + 1], yaw]),
            twist=jnp.stack([v_body[0], v_body[1], omega_body[2]]),
        )

    def up_z(self, state: SimState) -> jax.Array:
        """World z component of the chassis's up axis: 1 upright, below
        :data:`TIPPED_UP_Z` tipped over (no flat-floor mecanum base gets there physically;
        an unconverged solve on a slippery floor did, docs/physics_model.md)."""
        f = self.index.free_qpos
        return _quat_to_mat(state.data.qpos[f + 3 : f + 7])[2, 2]

    # --- batches ------------------------------------------------------------------------

    def batched(self, substeps: int = 1) -> tuple[Any, Any, Any]:
        """Jitted, vmapped ``(reset, step, sensors)`` over a leading robot axis (on CPU in
        chunks, :func:`cpu_chunk`)."""
        chunk = cpu_chunk(self.fidelity, self.impl)
        reset = jax.jit(chunked_vmap(self.reset, chunk))
        step = jax.jit(chunked_vmap(lambda s, c, p: self.step(s, c, p, substeps), chunk))
        sensors = jax.jit(jax.vmap(self.sensors))
        return reset, step, sensors


WARP_CONTACTS = {"fast": 2, "reference": 6}
"""Contact capacity per wheel and robot under ``sim.impl = "warp"``, per fidelity: a fast
wheel (a sphere) touches the floor at one point, a reference wheel with two or three of its
roller spheres; twice that leaves headroom for the moments rollers change over."""


def _quiet_solver_limits(model: mjx.Model) -> mjx.Model:
    """MuJoCo Warp prints a line whenever a solve stops at its iteration or line-search
    limit; MJX's JAX implementation stops there silently, and so does this project (the
    limits are set on purpose, SimSpec.iterations). Buffer overflows still print."""
    from mujoco.mjx.third_party.mujoco_warp import OverflowType

    quiet = OverflowType.ALL & ~(OverflowType.ITERATIONS | OverflowType.LS_ITERATIONS)
    impl = dataclasses.replace(model.opt._impl, warn_overflow=int(quiet))
    return model.replace(opt=model.opt.replace(_impl=impl))


def steady_twist(
    robot: Robot,
    params: RobotParams,
    command: jax.Array,
    seconds: float = 2.0,
    average_last: float = 0.5,
) -> jax.Array:
    """Hold wheel-rate setpoints from rest; the mean true body twist over the last part."""
    n_steps = round(seconds / robot.dt)
    n_avg = max(1, round(average_last / robot.dt))
    state = robot.reset(params)

    def body(s: SimState, _: None) -> tuple[SimState, jax.Array]:
        s = robot.step(s, command, params)
        return s, robot.sensors(s).twist

    _, twists = jax.lax.scan(body, state, None, length=n_steps)
    return jnp.mean(twists[-n_avg:], axis=0)


__all__ = [
    "TIPPED_UP_Z",
    "WARP_CONTACTS",
    "Robot",
    "steady_twist",
]
