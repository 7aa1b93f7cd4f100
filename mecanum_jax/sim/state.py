"""One simulated robot's parameters, state and sensor readings, and operations on batches
of them.

:class:`RobotParams` holds the per-robot physical parameters that domain randomisation
varies (:meth:`mecanum_jax.sim.robot_model.RobotModel.model_for` writes them into that
robot's copy of the ``mjx.Model``), :class:`SimState` what a step carries from one call to
the next, and :class:`Sensors` what a real base measures plus the ground truth. These types
need no MJX import of their own, so the task's observations, rewards and randomisation can
name them without loading the simulator.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, NamedTuple, TypedDict

import jax
import jax.numpy as jnp
import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt
    from mujoco import mjx

    from mecanum_jax.sim.description import RobotDescription

GRAVITY = 9.81


class RobotParams(NamedTuple):
    """Per-robot physical parameters (leaves may carry a leading batch axis under vmap).

    Attributes:
      friction: (n,) sliding friction coefficient at each wheel.
      payload_mass: () kg added to the chassis.
      payload_com: (3,) m, where the payload sits in the body frame.
      radius_scale: (n,) actual wheel radius / nominal radius (wheel-radius error).
      torque_limit: (n,) N·m.
      kp: (n,) servo proportional gain, N·m per rad/s.
      ki: (n,) servo integral gain, N·m per rad.
      max_accel: () setpoint slew limit, rad/s² (0: none).
    """

    friction: jax.Array
    payload_mass: jax.Array
    payload_com: jax.Array
    radius_scale: jax.Array
    torque_limit: jax.Array
    kp: jax.Array
    ki: jax.Array
    max_accel: jax.Array


def nominal_params(
    desc: RobotDescription, n_wheels: int, **overrides: npt.ArrayLike
) -> RobotParams:
    """The nominal parameters of the robot ``desc`` describes (``n_wheels`` wheels), with
    any field overridden (scalars broadcast): no model is built for them."""
    n = n_wheels
    a = desc.actuators
    base = {
        "friction": jnp.full((n,), desc.sim.floor_friction),
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


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SimState:
    """One robot's simulation state.

    Attributes:
      data: the MJX data.
      setpoint: (n,) the servos' current (slewed) rate setpoints, rad/s.
      integral: (n,) the servos' integrated rate error, rad.
      accel: (3,) specific force in the body frame over the last control step, m/s².
      initial_qpos: (nq,) the reset configuration, restored if the state goes non-finite.
      unstable: () how many times this robot went non-finite and was reset.
    """

    data: mjx.Data
    setpoint: jax.Array
    integral: jax.Array
    accel: jax.Array
    initial_qpos: jax.Array
    unstable: jax.Array

    def replace(self, **changes: jax.Array | mjx.Data) -> SimState:
        return dataclasses.replace(self, **changes)


class Sensors(NamedTuple):
    """What a real base measures (first five) and the ground truth (last two).

    Attributes:
      wheel_angle: (n,) rad, encoder angles (positive rolls forward).
      wheel_rate: (n,) rad/s, encoder rates.
      gyro_z: () rad/s, yaw rate in the body frame.
      accel: (3,) m/s², accelerometer (specific force, body frame; +9.81 z at rest).
      wheel_torque: (n,) N·m, the servos' applied torques.
      pose: (3,) true world pose (x, y, yaw), for evaluation only.
      twist: (3,) true body twist (vx, vy, wz), for evaluation only.
    """

    wheel_angle: jax.Array
    wheel_rate: jax.Array
    gyro_z: jax.Array
    accel: jax.Array
    wheel_torque: jax.Array
    pose: jax.Array
    twist: jax.Array


def select(done: jax.Array, fresh: SimState, state: SimState) -> SimState:
    """``fresh`` where ``done``, else ``state`` (one robot, or a batch with ``done`` per
    robot). MuJoCo Warp's contact and constraint buffers are shared by the whole batch, so
    they are kept as they are (``mjx.Data.where``), never selected leaf by leaf."""

    def where(a: jax.Array, b: jax.Array) -> jax.Array:
        return jnp.where(done, a, b)

    return SimState(
        data=state.data.where(done, fresh.data),
        setpoint=where(fresh.setpoint, state.setpoint),
        integral=where(fresh.integral, state.integral),
        accel=where(fresh.accel, state.accel),
        initial_qpos=where(fresh.initial_qpos, state.initial_qpos),
        unstable=where(fresh.unstable, state.unstable),
    )


def stack_params(params: list[RobotParams]) -> RobotParams:
    """Stack single-robot parameters into a batch."""
    return RobotParams(*(jnp.stack(xs) for xs in zip(*params, strict=True)))


class UnstableRobot(TypedDict):
    """A robot of a batch that went non-finite: its index, resets and parameters."""

    robot: int
    resets: int
    params: dict[str, float | list[float]]  # its RobotParams fields, rounded to 6 places


def unstable_robots(states: SimState, params: RobotParams) -> list[UnstableRobot]:
    """Robots (of a batch) that went non-finite and were reset: index, count and parameters."""
    counts = np.asarray(states.unstable)
    out: list[UnstableRobot] = []
    for i in np.flatnonzero(counts):
        fields = {k: np.asarray(v[i]).round(6).tolist() for k, v in params._asdict().items()}
        out.append({"robot": int(i), "resets": int(counts[i]), "params": fields})
    return out


__all__ = [
    "GRAVITY",
    "RobotParams",
    "Sensors",
    "SimState",
    "UnstableRobot",
    "nominal_params",
    "select",
    "stack_params",
    "unstable_robots",
]
