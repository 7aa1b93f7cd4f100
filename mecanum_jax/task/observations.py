"""What the robot observes: sensors with noise and latency, and the observation layouts.

The policy's ``obs["state"]`` is the robot-side controller's observation
(:func:`mecanum_jax.control.step.observe`, laid out as its spec's ``layout``): the command,
encoder rates, IMU gyro z and accelerometer, the wheel-odometry body twist, and the last
action, with sensor noise (:class:`NoiseConfig`) and an observation latency of whole
control steps, and the integrators the config asks for. The critic's
``obs["privileged_state"]`` adds the true twist and the randomized physical parameters
(and the true path error). Every entry is scaled to about unit size.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from mecanum_jax.config import require
from mecanum_jax.control import ControllerSpec, Layout
from mecanum_jax.control import step as ctl
from mecanum_jax.sim.state import RobotParams, Sensors
from mecanum_jax.task.constants import RobotConstants

if TYPE_CHECKING:
    from mecanum_jax.task.controller import TaskInfo


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


def privileged_layout(layout: Layout, n_wheels: int, path: bool = False) -> Layout:
    """The critic's observation: the policy's, then the truth it cannot sense (with
    ``path``, the true path error last)."""
    n = n_wheels
    extra: Layout = (("true_path_error", 3),) if path else ()
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
        *extra,
    )


def sensor_vector(
    spec: ControllerSpec, s: Sensors, key: jax.Array, noise_std: jax.Array
) -> jax.Array:
    """The scaled sensor frame (:func:`mecanum_jax.control.step.frame`) of noisy
    encoder rates, gyro z and accelerometer (standard deviations ``noise_std``)."""
    k1, k2, k3 = jax.random.split(key, 3)
    rate = s.wheel_rate + noise_std[0] * jax.random.normal(k1, s.wheel_rate.shape)
    gyro = s.gyro_z + noise_std[1] * jax.random.normal(k2)
    accel = s.accel + noise_std[2] * jax.random.normal(k3, (3,))
    return ctl.frame(spec, rate, gyro[None], accel, jnp)


def observe(
    robot: RobotConstants,
    sens: Sensors,
    info: TaskInfo,
    policy: jax.Array,
    path_scale: jax.Array | None = None,
) -> dict[str, jax.Array]:
    """The policy's observation ``policy`` (the controller's, :func:`ctl.observe`) and the
    critic's: that, then the truth (:func:`privileged_layout`; with ``path_scale``, the
    true path error divided by it last)."""
    p: RobotParams = info["params"]
    nom = robot.nominal_params
    truth = sens.twist / robot.command_scale
    parts = [
        policy,
        truth,
        p.friction,
        p.payload_mass[None],
        p.payload_com,
        p.radius_scale,
        p.torque_limit / nom.torque_limit,
        p.kp / nom.kp,
        info["latency"].astype(jnp.float32)[None],
    ]
    if path_scale is not None:  # the true path error, scaled as the measured one
        parts.append(info["true_path_error"] / path_scale)
    return {"state": policy, "privileged_state": jnp.concatenate(parts)}


def command_from_obs(robot: RobotConstants, obs: dict[str, jax.Array]) -> jax.Array:
    """The (noise-free) command carried in the first three policy observations."""
    cmd = obs["state"][..., :3]
    return cmd * robot.command_scale.reshape((1,) * (cmd.ndim - 1) + (3,))


__all__ = [
    "NoiseConfig",
    "command_from_obs",
    "observe",
    "privileged_layout",
    "sensor_vector",
]
