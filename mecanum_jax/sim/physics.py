"""Batched MJX physics of a mecanum robot: reset, step and sensors, under per-robot parameters.

The functions here simulate **one** robot; batch them with ``jax.vmap`` (see
:meth:`Robot.batched`; on the CPU in chunks, :mod:`mecanum_jax.sim.batching`). Per-robot
physical parameters (:class:`~mecanum_jax.sim.state.RobotParams`: floor
friction per wheel, payload mass and centre of mass, wheel-radius error, torque limit,
servo gains, setpoint slew limit) are arguments, so domain randomisation varies them per
robot without rebuilding the model: they are written into that robot's copy of the
``mjx.Model`` inside the vmapped step (:mod:`mecanum_jax.sim.robot_model` builds the robot
and writes them in; this module steps it).

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

from typing import TYPE_CHECKING

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import jax
import jax.numpy as jnp
import numpy as np
from jax.stages import Wrapped
from mujoco import mjx

from mecanum_jax.precision import HIGHEST
from mecanum_jax.sim.batching import chunked_vmap, cpu_chunk
from mecanum_jax.sim.robot_model import RobotModel
from mecanum_jax.sim.servo import chord_servo, servo_control
from mecanum_jax.sim.state import GRAVITY, RobotParams, Sensors, SimState

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


class Robot(RobotModel):
    """A compiled robot at one fidelity (:class:`~mecanum_jax.sim.robot_model.RobotModel`:
    the host model, its MJX model, and its index), stepped in MJX: reset, step, sensors,
    batches."""

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

    def batched(self, substeps: int = 1) -> tuple[Wrapped, Wrapped, Wrapped]:
        """Jitted, vmapped ``(reset, step, sensors)`` over a leading robot axis (on CPU in
        chunks, :func:`cpu_chunk`)."""
        chunk = cpu_chunk(self.fidelity, self.impl)

        def step_(s: SimState, c: jax.typing.ArrayLike, p: RobotParams) -> SimState:
            return self.step(s, c, p, substeps)

        reset = jax.jit(chunked_vmap(self.reset, chunk))
        step = jax.jit(chunked_vmap(step_, chunk))
        sensors = jax.jit(jax.vmap(self.sensors))
        return reset, step, sensors


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
    "Robot",
    "steady_twist",
]
