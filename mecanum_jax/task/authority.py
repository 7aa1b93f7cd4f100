"""State-dependent authority of the learned residual (:class:`AuthorityConfig`).

With ``mode = "slip"`` the residual's bound is scheduled on slip signals the robot
measures, from the sensor frame it observes (noisy, delayed) and the setpoints it sent:

- ``yaw``: the exponential average of gyro ωz − wheel-odometry ωz, rad/s. The wheels'
  kinematics and the gyro agree on a robot whose wheels grip and whose radii are nominal;
  slip, a mis-calibrated radius or a payload's yaw drag pull them apart;
- ``servo``: per wheel, the exponential average of (setpoint − measured rate) / max rate,
  of which the gate reads the mean magnitude over the wheels: a torque-limited or weak
  servo lags its setpoint steadily, a nominal one only during transients.

Averaging the signed errors, not their magnitudes, lets the sensor noise average out.
``gate = clip(max(|yaw| / yaw_slip, servo / servo_error), 0, 1)`` and the bound is
``floor + (residual_scale − floor) · gate``: near ``floor`` on the nominal robot, where
the base controller is already exact, and the full ``residual_scale`` where it slips.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.config import invalid, require
from mecanum_jax.task.constants import RobotConstants

AUTHORITY_MODES = ("constant", "slip")
"""What :attr:`AuthorityConfig.mode` may name."""


@dataclasses.dataclass(frozen=True)
class AuthorityConfig:
    """How large the residual correction may be: residual_scale always ("constant"), or
    scheduled between floor and residual_scale by measured slip ("slip"; the policy then
    observes the gate, "authority", in [0, 1])."""

    mode: str = "constant"
    """"constant": the bound is residual_scale; "slip": it grows with the slip signals."""
    floor: float = 0.01
    """The bound when the slip signals are 0, a fraction like residual_scale
    (0 <= floor <= residual_scale; floor = residual_scale: the bound is constant)."""
    tau: float = 0.5
    """Time constant of the slip signals' exponential averages, s (> 0)."""
    yaw_slip: float = 0.2
    """|averaged gyro ωz − odometry ωz|, rad/s, at which the bound is full (> 0). Under
    feedback on the gpu recipe's robots, the nominal robot's stays below 0.04 rad/s
    (gate < 0.2) in 82% of its steps within reach (transients after command changes make
    the rest); a randomized robot's steady ωz error above 0.1 rad/s gives a median of
    about 0.2 rad/s."""
    servo_error: float = 0.02
    """Mean over the wheels of |averaged setpoint − measured rate|, as a fraction of the
    largest wheel rate, at which the bound is full (> 0). The training distribution's
    servos rarely lag steadily: 99% of the steps stay below 0.004 (nominal) and 0.01
    (randomized)."""

    def validate(self, where: str = "env.authority") -> None:
        """Check values; raise :class:`ConfigError` naming the field (floor's upper bound,
        residual_scale, is checked by EnvConfig.validate)."""
        if self.mode not in AUTHORITY_MODES:
            raise invalid(f"{where}.mode", self.mode, f"expected one of {AUTHORITY_MODES}")
        require(self, where, ("floor",), lambda v: v >= 0, "must be >= 0")
        require(self, where, ("tau", "yaw_slip", "servo_error"), lambda v: v > 0, "must be > 0")

    @property
    def slip(self) -> bool:
        """Whether the bound is scheduled (mode "slip")."""
        return self.mode == "slip"


def initial(n_wheels: int) -> dict[str, jax.Array]:
    """The averaged slip signals at a reset: 0 (``info`` keys)."""
    return {"authority_yaw": jnp.asarray(0.0), "authority_servo": jnp.zeros(n_wheels)}


def update(
    robot: RobotConstants,
    cfg: AuthorityConfig,
    dt: float,
    info: dict[str, Any],
    frame: jax.Array,
    setpoints: jax.Array,
) -> dict[str, jax.Array]:
    """The averages after a control step of ``dt`` s: ``frame`` is the sensor frame
    observed now (:func:`.observations.delayed`, scaled as
    :func:`.observations.sensor_vector` makes it), ``setpoints`` the wheel rates sent in
    the step (rad/s)."""
    n = robot.n_wheels
    a = float(np.exp(-dt / cfg.tau))
    yaw = (frame[n] - frame[n + 6]) * robot.command_scale[2]  # gyro − odometry ωz, rad/s
    servo = setpoints / robot.max_rates - frame[:n]  # fractions of each wheel's max rate
    return {
        "authority_yaw": a * info["authority_yaw"] + (1.0 - a) * yaw,
        "authority_servo": a * info["authority_servo"] + (1.0 - a) * servo,
    }


def gate(cfg: AuthorityConfig, info: dict[str, Any]) -> jax.Array:
    """The gate in [0, 1] of the averaged slip signals in ``info``."""
    yaw = jnp.abs(info["authority_yaw"]) / cfg.yaw_slip
    servo = jnp.mean(jnp.abs(info["authority_servo"])) / cfg.servo_error
    return jnp.clip(jnp.maximum(yaw, servo), 0.0, 1.0)


def bound(cfg: AuthorityConfig, residual_scale: float, g: jax.Array) -> jax.Array:
    """The residual's bound (a fraction, like ``residual_scale``) at gate ``g``."""
    return cfg.floor + (residual_scale - cfg.floor) * g


__all__ = ["AUTHORITY_MODES", "AuthorityConfig", "bound", "gate", "initial", "update"]
