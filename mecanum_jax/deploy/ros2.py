"""ROS 2 conventions: ros2_control's ``mecanum_drive_controller`` parameters to and from
this project's robot descriptions.

The controller's kinematics are this project's O layout with 45° rollers, in another
wheel order and with other names:

=====================  ===============================================  ==================
this project           ros2_control ``mecanum_drive_controller``        note
=====================  ===============================================  ==================
wheel 0, left-front    ``front_left_wheel_command_joint_name``          ``ω = (vx − vy − k·ωz) / r``
wheel 1, left-back     ``rear_left_wheel_command_joint_name``           ``ω = (vx + vy − k·ωz) / r``
wheel 2, right-back    ``rear_right_wheel_command_joint_name``          ``ω = (vx − vy + k·ωz) / r``
wheel 3, right-front   ``front_right_wheel_command_joint_name``         ``ω = (vx + vy + k·ωz) / r``
``wheel_radius``       ``kinematics.wheels_radius``                     m
``half_wheelbase +     ``kinematics.sum_of_robot_center_projection_     ``k = lx + ly``, m
half_track``           on_X_Y_axis``
origin at the wheels'  ``kinematics.base_frame_offset`` (x, y, θ)       only zero converts
centre
=====================  ===============================================  ==================

Both take body twists in REP-103 (x forward, y left, z up) and wheel rates in rad/s,
positive rolling the robot forward; a motor mounted mirrored is a sign in the URDF joint's
axis there and ``motors.signs`` here. The controller knows only the sum ``lx + ly``; the
kinematics need nothing more, but the physics model needs both, so the converter takes
``half_track`` (default: half the sum, a square footprint) and says so in the file.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path
from typing import Annotated, Any, TypedDict, Unpack

import tyro

from mecanum_jax.config import ConfigError
from mecanum_jax.sim.description import RobotDescription, parse_description, resolve_description

# (this project's wheel order) -> the controller's joint-name parameters
JOINT_PARAMETERS = (
    "front_left_wheel_command_joint_name",
    "rear_left_wheel_command_joint_name",
    "rear_right_wheel_command_joint_name",
    "front_right_wheel_command_joint_name",
)
LEVER_ARM = "sum_of_robot_center_projection_on_X_Y_axis"


class DescriptionOptions(TypedDict, total=False):
    """The keyword options of :func:`description_toml` that :func:`convert_file` passes on."""

    half_track: float | None
    max_motor_rpm: float
    gear_ratio: float
    signs: tuple[int, ...]


def controller_parameters(data: dict[str, Any], controller: str | None = None) -> dict[str, Any]:
    """The ``ros__parameters`` of one controller in a parsed ROS 2 parameter file (or the
    parameters themselves). ``controller`` names it; by default the one controller whose
    parameters have a ``kinematics`` table."""
    if "kinematics" in data:
        return data
    found = {
        name: body["ros__parameters"]
        for name, body in data.items()
        if isinstance(body, dict)
        and isinstance(body.get("ros__parameters"), dict)
        and "kinematics" in body["ros__parameters"]
    }
    if controller is not None:
        if controller not in found:
            raise ConfigError(
                f"controller = {controller!r}: no such mecanum_drive_controller in the file; "
                f"found {sorted(found)}"
            )
        return dict(found[controller])
    if len(found) != 1:
        raise ConfigError(
            f"controller = None: expected one controller with a kinematics table, found "
            f"{sorted(found)}; name one"
        )
    return dict(next(iter(found.values())))


def _positive(params: dict[str, Any], key: str) -> float:
    value = params.get("kinematics", {}).get(key)
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise ConfigError(f"kinematics.{key} = {value!r}: expected a number (m)")
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"kinematics.{key} = {value!r}: must be a finite number > 0 m")
    return float(value)


def description_toml(
    params: dict[str, Any],
    name: str,
    *,
    half_track: float | None = None,
    max_motor_rpm: float = 9000.0,
    gear_ratio: float = 19.0,
    signs: tuple[int, ...] = (1, 1, -1, -1),
) -> str:
    """A robot description (TOML text for ``configs/robots/``) from the controller's
    parameters. Checked by parsing it back; raises :class:`ConfigError` naming the field."""
    radius = _positive(params, "wheels_radius")
    lever = _positive(params, LEVER_ARM)
    offset = params.get("kinematics", {}).get("base_frame_offset") or {}
    for axis in ("x", "y", "theta"):
        value = offset.get(axis, 0.0)
        if value != 0:
            raise ConfigError(
                f"kinematics.base_frame_offset.{axis} = {value!r}: only a zero offset converts "
                "(a description's origin is the centre of its wheels)"
            )
    ly = lever / 2 if half_track is None else float(half_track)
    if not 0 < ly < lever:
        raise ConfigError(f"half_track = {half_track!r}: must be in (0, {LEVER_ARM} = {lever}) m")
    joints = [str(params.get(p, "")) for p in JOINT_PARAMETERS]
    split = "half of" if half_track is None else "given;"
    text = f"""# Converted from ros2_control mecanum_drive_controller parameters (mecanum-ros2).
# Joints, in this project's wheel order (left-front, left-back, right-back, right-front):
#   {", ".join(joints)}
# lx + ly = {lever} m ({LEVER_ARM}); half_track {split} that sum: the kinematics
# need only the sum, the physics model both. Units: metres, degrees, rpm.
[robot]
name = "{name}"
description = "mecanum base from ros2_control parameters, r = {radius} m, lx + ly = {lever} m"

[geometry]
layout = "O-rectangle"
wheel_radius = {radius!r}
half_wheelbase = {lever - ly!r}
half_track = {ly!r}
roller_angle_deg = 45.0

[motors]
max_motor_rpm = {max_motor_rpm!r}
gear_ratio = {gear_ratio!r}
signs = {list(signs)}
"""
    import tomllib

    parse_description(tomllib.loads(text), f"converted description {name!r}")
    return text


def to_controller_parameters(
    desc: RobotDescription, joints: tuple[str, ...] | None = None
) -> dict[str, Any]:
    """The controller's parameters for a description of the O layout with 45° rollers
    (``kinematics`` table and joint names; joint names default to ``<wheel>_joint``)."""
    g = desc.geometry
    if g.layout not in ("O-square", "O-rectangle") or abs((g.roller_angle_deg or 45) - 45) > 1e-9:
        raise ConfigError(
            f"geometry.layout = {g.layout!r}: mecanum_drive_controller models only the O "
            "layout with 45° rollers"
        )
    square = g.layout == "O-square"
    rx = g.half_size if square else g.half_wheelbase
    ry = g.half_size if square else g.half_track
    assert rx is not None
    assert ry is not None
    assert g.wheel_radius is not None
    names = joints or tuple(
        f"{w}_wheel_joint" for w in ("front_left", "rear_left", "rear_right", "front_right")
    )
    if len(names) != 4:
        raise ConfigError(f"joints = {list(names)}: expected 4 names (LF, LB, RB, RF)")
    return {
        **dict(zip(JOINT_PARAMETERS, names, strict=True)),
        "kinematics": {
            "base_frame_offset": {"x": 0.0, "y": 0.0, "theta": 0.0},
            "wheels_radius": g.wheel_radius,
            LEVER_ARM: rx + ry,
        },
    }


def convert_file(
    path: str | Path, name: str, controller: str | None = None, **kwargs: Unpack[DescriptionOptions]
) -> str:
    """:func:`description_toml` of a ROS 2 parameter file (YAML)."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"params = {str(path)!r}: no such file")
    try:
        data = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as err:
        raise ConfigError(f"params = {str(path)!r}: not valid YAML ({err})") from None
    except OSError as err:
        raise ConfigError(f"params = {str(path)!r}: unreadable ({err.strerror})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"params = {str(path)!r}: expected a mapping at the top")
    return description_toml(controller_parameters(data, controller), name, **kwargs)


@dataclasses.dataclass(frozen=True)
class Ros2Args:
    """Convert ros2_control ``mecanum_drive_controller`` parameters (YAML) to a robot
    description (TOML), or, with ``--to-ros``, a description to the controller's
    parameters (YAML on standard output)."""

    source: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="SOURCE")]
    """The ROS 2 parameter file (YAML); with ``--to-ros``, a description (name or .toml)."""
    out: Annotated[str | None, tyro.conf.Positional, tyro.conf.arg(metavar="OUT")] = None
    """The description to write (.toml; never overwritten); default: standard output."""
    name: str = "from_ros2"
    """The robot's name in the written description."""
    controller: str | None = None
    """Which controller of the file (default: the one with a ``kinematics`` table)."""
    half_track: float | None = None
    """ly, half the left-right wheel distance, m (default: half of lx + ly)."""
    max_motor_rpm: float = 9000.0
    """Motor shaft speed limit, rpm (the controller has none)."""
    gear_ratio: float = 19.0
    """Motor turns per wheel turn."""
    to_ros: bool = False
    """Write the controller's parameters for the description SOURCE instead."""


def main(argv: list[str] | None = None) -> int:
    """``mecanum-ros2 PARAMS.yaml [OUT.toml]`` / ``mecanum-ros2 --to-ros ROBOT``."""
    args = tyro.cli(Ros2Args, args=sys.argv[1:] if argv is None else argv, prog="mecanum-ros2")
    try:
        if args.to_ros:
            import yaml

            if args.out is not None:
                raise ConfigError(f"out = {args.out!r}: --to-ros writes to standard output")
            desc = resolve_description(args.source)
            params = {
                "mecanum_drive_controller": {"ros__parameters": to_controller_parameters(desc)}
            }
            text = yaml.safe_dump(params, sort_keys=False)
        else:
            if args.out is not None and not args.out.endswith(".toml"):
                raise ConfigError(f"out = {args.out!r}: expected a .toml file name")
            if args.out is not None and Path(args.out).exists():
                raise ConfigError(f"out = {args.out!r}: already exists; never overwritten")
            text = convert_file(
                args.source,
                args.name,
                args.controller,
                half_track=args.half_track,
                max_motor_rpm=args.max_motor_rpm,
                gear_ratio=args.gear_ratio,
            )
    except (ConfigError, OSError, UnicodeDecodeError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.out is None:
        sys.stdout.write(text)
        return 0
    try:
        with open(args.out, "x") as f:  # "x": an existing file is never overwritten
            f.write(text)
    except OSError as err:
        print(f"error: out = {args.out!r}: cannot write it: {err.strerror}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


__all__ = [
    "JOINT_PARAMETERS",
    "LEVER_ARM",
    "Ros2Args",
    "controller_parameters",
    "convert_file",
    "description_toml",
    "main",
    "to_controller_parameters",
]


if __name__ == "__main__":
    sys.exit(main())
