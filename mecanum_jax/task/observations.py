"""What the robot observes: sensors with noise and latency, and the observation layouts.

The policy's ``obs["state"]``: the command, encoder rates, IMU gyro z and accelerometer,
the wheel-odometry body twist, and the last action, with sensor noise
(:class:`NoiseConfig`) and an observation latency of whole control steps; optionally the
leaky integral of the measured yaw-rate error, and, when the residual corrects the
``feedback`` controller, that controller's integrator. The critic's ``obs["privileged_state"]``
adds the true twist and the randomized physical parameters. Every entry is scaled to
about unit size (by the rate limits, the largest feasible twist, or gravity).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.config import require
from mecanum_jax.precision import HIGHEST
from mecanum_jax.sim.state import GRAVITY, RobotParams, Sensors
from mecanum_jax.task.constants import RobotConstants

Layout = tuple[tuple[str, int], ...]


@dataclasses.dataclass(frozen=True)
class NoiseConfig:
    """Gaussian sensor noise (standard deviations); scale = 0 turns it off."""

    scale: float = 1.0
    """Multiplies every standard deviation below (>= 0; 0: noise off)."""
    wheel_rate: float = 0.3
    """Encoder wheel-rate noise, rad/s (>= 0)."""
    gyro: float = 0.02
    """Gyro z noise, rad/s (>= 0)."""
    accel: float = 0.3
    """Accelerometer noise, m/s² (>= 0)."""

    def validate(self, where: str = "env.noise") -> None:
        """Check values; raise :class:`ConfigError` naming the field."""
        fields = ("scale", "wheel_rate", "gyro", "accel")
        require(self, where, fields, lambda v: v >= 0, "must be >= 0")

    def std(self) -> jax.Array:
        """The standard deviations (wheel rate, gyro, accel), scaled."""
        return jnp.asarray(
            [self.scale * self.wheel_rate, self.scale * self.gyro, self.scale * self.accel],
            jnp.float32,
        )


def policy_layout(
    n_wheels: int,
    action_size: int,
    yaw_integral: bool,
    feedback_integral: bool = False,
    history: int = 0,
) -> Layout:
    """The policy observation's entries and their sizes, in order; ``history`` earlier
    sensor frames come last."""
    layout: Layout = (
        ("command", 3),
        ("wheel_rate", n_wheels),
        ("gyro_z", 1),
        ("accel", 3),
        ("odometry_twist", 3),
        ("last_action", action_size),
    )
    if yaw_integral:
        layout = (*layout, ("yaw_error_integral", 1))
    if feedback_integral:
        layout = (*layout, ("feedback_integral", 1))
    if history > 0:
        layout = (*layout, ("sensor_history", history * sensor_size(n_wheels)))
    return layout


def entry_start(layout: Layout, name: str) -> int:
    """Where entry ``name`` of ``layout`` starts in the observation vector (the privileged
    layout begins with the policy's, so the same index holds in both)."""
    names = [n for n, _ in layout]
    if name not in names:
        raise KeyError(f"observation entry {name!r} is not in the layout {names}")
    return sum(size for _, size in layout[: names.index(name)])


def sensor_size(n_wheels: int) -> int:
    """One sensor frame: encoder rates, gyro z, accelerometer (3), odometry twist (3)."""
    return n_wheels + 1 + 3 + 3


def privileged_layout(layout: Layout, n_wheels: int) -> Layout:
    """The critic's observation: the policy's, then the truth it cannot sense."""
    n = n_wheels
    return (
        *layout,
        ("true_twist", 3),
        ("friction", n),
        ("payload_mass", 1),
        ("payload_com", 3),
        ("radius_scale", n),
        ("torque_scale", n),
        ("gain_scale", n),
        ("latency", 1),
    )


def sensor_vector(
    robot: RobotConstants, s: Sensors, key: jax.Array, noise_std: jax.Array
) -> jax.Array:
    """Noisy encoder rates, gyro z, accelerometer and the odometry twist (scaled)."""
    k1, k2, k3 = jax.random.split(key, 3)
    n = robot.n_wheels
    rate = s.wheel_rate + noise_std[0] * jax.random.normal(k1, (n,))
    gyro = s.gyro_z + noise_std[1] * jax.random.normal(k2)
    accel = s.accel + noise_std[2] * jax.random.normal(k3, (3,))
    odom = jnp.matmul(robot.forward_matrix, rate, precision=HIGHEST)
    return jnp.concatenate(
        [
            rate / robot.max_rates,
            (gyro / robot.command_scale[2])[None],
            accel / GRAVITY,
            odom / robot.command_scale,
        ]
    )


def delayed(info: dict[str, Any]) -> jax.Array:
    """The sensor vector as the robot observes it now: ``latency`` steps old."""
    return jnp.take(info["history"], info["latency"], axis=0)


def past_sensors(info: dict[str, Any], frames: int) -> jax.Array:
    """The ``frames`` sensor frames before the one observed now, newest first, flattened."""
    past = jax.lax.dynamic_slice_in_dim(info["history"], info["latency"] + 1, frames, axis=0)
    return past.reshape(-1)


def measured_yaw_rate(robot: RobotConstants, info: dict[str, Any]) -> jax.Array:
    """The gyro's yaw rate as a controller sees it now (noisy, ``latency`` steps old)."""
    return delayed(info)[robot.n_wheels] * robot.command_scale[2]


def yaw_integral(
    robot: RobotConstants, info: dict[str, Any], command: jax.Array, tau: float, dt: float
) -> jax.Array:
    """The observed leaky yaw-error integral (time constant ``tau`` > 0 s) after a step of
    ``dt`` s that tracked ``command``."""
    err = command[2] - measured_yaw_rate(robot, info)
    return float(np.exp(-dt / tau)) * info["yaw_integral"] + err * dt


def observe(
    robot: RobotConstants,
    sens: Sensors,
    info: dict[str, Any],
    yaw_integral_tau: float,
    feedback_integral: bool,
    history: int,
) -> dict[str, jax.Array]:
    """The policy's and the critic's observations of the state ``info`` describes (the
    entries as :func:`policy_layout` lists them)."""
    scale = robot.command_scale
    parts = [info["command"] / scale, delayed(info), info["last_action"]]
    if yaw_integral_tau > 0:
        parts.append((info["yaw_integral"] / (yaw_integral_tau * scale[2]))[None])
    if feedback_integral:  # the integrator of the controller the residual corrects, rad/s
        parts.append((info["feedback_integral"] / scale[2])[None])
    if history > 0:
        parts.append(past_sensors(info, history))
    state = jnp.concatenate(parts)
    p: RobotParams = info["params"]
    nom = robot.nominal_params
    truth = sens.twist / scale
    privileged = jnp.concatenate(
        [
            state,
            truth,
            p.friction,
            p.payload_mass[None],
            p.payload_com,
            p.radius_scale,
            p.torque_limit / nom.torque_limit,
            p.kp / nom.kp,
            info["latency"].astype(jnp.float32)[None],
        ]
    )
    return {"state": state, "privileged_state": privileged}


def command_from_obs(robot: RobotConstants, obs: dict[str, jax.Array]) -> jax.Array:
    """The (noise-free) command carried in the first three policy observations."""
    cmd = obs["state"][..., :3]
    return cmd * robot.command_scale.reshape((1,) * (cmd.ndim - 1) + (3,))


__all__ = [
    "NoiseConfig",
    "command_from_obs",
    "delayed",
    "entry_start",
    "measured_yaw_rate",
    "observe",
    "past_sensors",
    "policy_layout",
    "privileged_layout",
    "sensor_size",
    "sensor_vector",
    "yaw_integral",
]
