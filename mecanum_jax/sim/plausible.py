"""Plausibility checks of a robot description: numbers a real robot would not have.

A description can be valid (positive, finite) and still describe no robot anyone builds:
millimetres typed as metres (``wheel_radius = 40.0``), a wheel wider than itself several
times over, a wheel larger than the base. :func:`check_plausible` refuses these with the
field, the value and the way out: ``allow_implausible = true`` in the description's
``[robot]`` table accepts them (a toy, a vehicle the size of a house).

The robot's name is checked always: it names directories and files (runs, models), so it
is a plain word of letters, digits, ``_``, ``-`` and ``.``; and two wheels less than 1 mm
apart are refused always (no robot has them).
"""

from __future__ import annotations

import itertools
import math
import re

import numpy as np

from mecanum_jax.config import ConfigError
from mecanum_jax.kinematics.geometry import WheelGeometry
from mecanum_jax.sim.specs import BodySpec, GeometrySpec, MotorSpec, RobotSpec

MIN_LENGTH, MAX_LENGTH = 0.001, 5.0
"""The plausible range of a robot's lengths, m: 1 mm to 5 m."""
MAX_WIDTH_PER_RADIUS = 4.0
"""The widest plausible wheel, in wheel radii (twice its diameter)."""
MIN_RIM_SPEED, MAX_RIM_SPEED = 0.01, 100.0
"""The plausible range of a wheel's top rim speed, m/s (motor limit, gear ratio and
radius together): 1 cm/s to 100 m/s; mecanum robots reach a few."""
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
OVERRIDE = "set allow_implausible = true in [robot] to accept"


def check_name(robot: RobotSpec) -> None:
    """Raise :class:`ConfigError` unless the robot's name is a plain word (no path)."""
    if not NAME.fullmatch(robot.name):
        raise ConfigError(
            f"robot.name = {robot.name!r}: a robot's name names its files and runs, so it "
            "must be letters, digits, '_', '-' or '.', starting with a letter or digit "
            "(no spaces, '/', '\\' or other path characters)"
        )


def _lengths(geometry: GeometrySpec, body: BodySpec) -> dict[str, float]:
    fields = ("wheel_radius", "half_size", "half_wheelbase", "half_track", "centre_distance")
    out = {f"geometry.{k}": getattr(geometry, k) for k in fields}
    for i, w in enumerate(geometry.wheels or ()):
        out[f"geometry.wheels[{i}].radius"] = w.radius
        out[f"geometry.wheels[{i}] distance from the centre"] = math.hypot(w.x, w.y) or None
    out["body.wheel_width"] = body.wheel_width
    for i, v in enumerate(body.half_size or ()):
        out[f"body.half_size[{i}]"] = v
    return {k: v for k, v in out.items() if v is not None}


def _check_apart(who: str, wheels: WheelGeometry) -> None:
    """Two wheels in one place cannot be built (no override): refuse them by name."""
    p = np.asarray(wheels.positions, dtype=float)
    for i, j in itertools.combinations(range(len(wheels.names)), 2):
        if float(np.linalg.norm(p[i] - p[j])) < MIN_LENGTH:
            raise ConfigError(
                f"{who}: wheels {wheels.names[i]!r} and {wheels.names[j]!r} are both at "
                f"{np.round(p[i], 4).tolist()} m (less than {MIN_LENGTH} m apart): two wheels "
                "cannot share one place"
            )


def check_plausible(
    robot: RobotSpec, geometry: GeometrySpec, body: BodySpec, wheels: WheelGeometry
) -> None:
    """Raise :class:`ConfigError` naming the field and value of the first implausible
    number, unless ``robot.allow_implausible``. ``wheels`` is the built geometry."""
    check_name(robot)
    who = f"robot {robot.name!r}"
    _check_apart(who, wheels)
    if robot.allow_implausible:
        return
    for field, value in _lengths(geometry, body).items():
        if not MIN_LENGTH <= value <= MAX_LENGTH:
            hint = " (millimetres?)" if value > MAX_LENGTH else " (metres are the unit)"
            raise ConfigError(
                f"{who}: {field} = {value!r} m is outside {MIN_LENGTH}–{MAX_LENGTH:g} m"
                f"{hint}; {OVERRIDE}"
            )
    p = np.asarray(wheels.positions, dtype=float)
    r = np.asarray(wheels.radii, dtype=float)
    names = wheels.names
    for i, j in itertools.combinations(range(len(names)), 2):
        gap = float(np.linalg.norm(p[i] - p[j]))
        if gap < r[i] + r[j]:
            raise ConfigError(
                f"{who}: wheel radius {r[i]:g} m (wheel {names[i]!r}) is larger than the base: "
                f"wheels {names[i]!r} and {names[j]!r} are {gap:.4g} m apart, so wheels of "
                f"radius {r[i]:g} m and {r[j]:g} m overlap; {OVERRIDE}"
            )
    widest = MAX_WIDTH_PER_RADIUS * float(r.min())
    if body.wheel_width > widest:
        raise ConfigError(
            f"{who}: body.wheel_width = {body.wheel_width!r} m is wider than "
            f"{MAX_WIDTH_PER_RADIUS:g} wheel radii ({widest:.4g} m for radius {r.min():g} m); "
            f"{OVERRIDE}"
        )


def check_motors_plausible(robot: RobotSpec, motors: MotorSpec, wheels: WheelGeometry) -> None:
    """Raise :class:`ConfigError` where the motors, through their gears, would turn a wheel's
    rim slower or faster than :data:`MIN_RIM_SPEED`–:data:`MAX_RIM_SPEED` (rpm typed as rad/s,
    a gear ratio inverted), unless ``robot.allow_implausible``."""
    if robot.allow_implausible:
        return
    rate = motors.max_motor_rpm / motors.gear_ratio * 2 * math.pi / 60  # wheel rad/s
    for name, radius in zip(wheels.names, np.asarray(wheels.radii, float), strict=True):
        rim = rate * float(radius)
        if not MIN_RIM_SPEED <= rim <= MAX_RIM_SPEED:
            raise ConfigError(
                f"robot {robot.name!r}: motors.max_motor_rpm = {motors.max_motor_rpm!r} through "
                f"motors.gear_ratio = {motors.gear_ratio!r} turns wheel {name!r} (radius "
                f"{radius:g} m) at {rim:.4g} m/s at its rim, outside {MIN_RIM_SPEED:g}–"
                f"{MAX_RIM_SPEED:g} m/s; {OVERRIDE}"
            )


__all__ = ["MAX_LENGTH", "MIN_LENGTH", "check_motors_plausible", "check_name", "check_plausible"]
