"""Descriptions of the other drives: ``configs/robots/drives/<name>.toml``, read and
checked into a :class:`DriveDescription` that builds the drive's geometry
(:mod:`mecanum_jax.kinematics.drive_geometry`)."""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, cast

import jax.numpy as jnp

from mecanum_jax.config import CONFIG_DIR, find_config, from_mapping, load_toml
from mecanum_jax.kinematics import motors
from mecanum_jax.kinematics.drive_geometry import (
    Drive,
    DriveError,
    DriveName,
    ackermann,
    differential,
    synchronous,
    tricycle,
)

if TYPE_CHECKING:
    import jax


@dataclasses.dataclass(frozen=True)
class DriveRobotSpec:
    name: str
    """The robot's name."""
    drive: DriveName
    """The drive: differential, tricycle, synchronous or ackermann."""
    description: str = ""
    """One line about the robot."""


@dataclasses.dataclass(frozen=True)
class DriveGeometrySpec:
    wheel_radius: float
    """Radius of the driven wheels, m."""
    track: float | None = None
    """Distance between the left and right wheels, m (differential, Ackermann)."""
    wheelbase: float | None = None
    """Distance from the rear axle to the front (steered) wheels, m (tricycle, Ackermann)."""
    max_steer_deg: float | None = None
    """Steering limit, degrees (tricycle: <= 90, default 90; Ackermann: < 90, default 35)."""


@dataclasses.dataclass(frozen=True)
class DriveMotorSpec:
    max_motor_rpm: float
    """Motor shaft speed limit, rpm."""
    gear_ratio: float = 1.0
    """Motor turns per wheel turn."""


@dataclasses.dataclass(frozen=True)
class DriveDescription:
    """A non-mecanum robot: ``configs/robots/drives/<name>.toml``."""

    robot: DriveRobotSpec
    geometry: DriveGeometrySpec
    motors: DriveMotorSpec

    def build(self, dtype: jax.typing.DTypeLike = jnp.float32) -> Drive:
        """The geometry pytree; errors name the missing or invalid field."""
        g, kind = self.geometry, self.robot.drive
        needs = {
            "differential": ("track",),
            "tricycle": ("wheelbase",),
            "synchronous": (),
            "ackermann": ("wheelbase", "track"),
        }[kind]
        for key in ("track", "wheelbase", "max_steer_deg"):
            value = getattr(g, key)
            allowed = needs + (("max_steer_deg",) if kind in ("tricycle", "ackermann") else ())
            if key in needs and value is None:
                raise DriveError(f"geometry.{key}: missing, a {kind} drive needs it")
            if key not in allowed and value is not None:
                raise DriveError(f"geometry.{key} = {value!r}: a {kind} drive has no {key}")
        deg = g.max_steer_deg
        track, base = cast(float, g.track), cast(float, g.wheelbase)  # present where needed
        try:
            if kind == "differential":
                return differential(g.wheel_radius, track, dtype)
            if kind == "synchronous":
                return synchronous(g.wheel_radius, dtype)
            if kind == "tricycle":
                steer = math.pi / 2 if deg is None else math.radians(deg)
                return tricycle(g.wheel_radius, base, steer, dtype)
            steer = math.radians(35.0 if deg is None else deg)
            return ackermann(g.wheel_radius, base, track, steer, dtype)
        except DriveError as err:
            message = str(err)
            if message.startswith("max_steer ="):  # the file's field, in the unit it was given
                message = f"max_steer_deg = {deg!r}: {message.split(': ', 1)[1]}"
            raise DriveError(f"geometry.{message}") from None

    def max_wheel_rate(self) -> float:
        """The driven wheels' rate limit, rad/s, from the motor limit and the gear ratio."""
        return float(motors.max_wheel_rate(self.motors.max_motor_rpm, self.motors.gear_ratio))


def load_drive(robot: str) -> DriveDescription:
    """A drive description by path, or by name from ``configs/robots/drives/``."""
    path = find_config(robot, CONFIG_DIR / "robots" / "drives", "robot", "built-in drive")
    desc = from_mapping(DriveDescription, load_toml(path))
    m = desc.motors
    for key in ("max_motor_rpm", "gear_ratio"):
        if not getattr(m, key) > 0:
            raise DriveError(f"{path}: motors.{key} = {getattr(m, key)!r}: must be > 0")
    try:
        desc.build()
    except DriveError as err:
        raise DriveError(f"{path}: {err}") from None
    return desc


__all__ = [
    "DriveDescription",
    "DriveGeometrySpec",
    "DriveMotorSpec",
    "DriveRobotSpec",
    "load_drive",
]
