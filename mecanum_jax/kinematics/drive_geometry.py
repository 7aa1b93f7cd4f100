"""The geometries of the other drives of seed 001 (differential, tricycle, synchronous and
Ackermann): pytrees, built by checked constructors (errors name the field and value).

Their kinematics (``inverse``, ``forward``, ``icr``, odometry, velocity limits) are in
:mod:`mecanum_jax.kinematics.drives`, their descriptions (``configs/robots/drives/``) in
:mod:`mecanum_jax.kinematics.drive_description`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Literal

import jax
import jax.numpy as jnp

from mecanum_jax._checks import InputError, as_float_array, check_finite, fmt, is_concrete

if TYPE_CHECKING:
    import numpy.typing as npt

DriveName = Literal["differential", "tricycle", "synchronous", "ackermann"]
DRIVES: tuple[DriveName, ...] = ("differential", "tricycle", "synchronous", "ackermann")
ACTUATORS: dict[str, tuple[str, ...]] = {
    "differential": ("left_rate", "right_rate"),
    "tricycle": ("steer", "wheel_rate"),
    "synchronous": ("steer", "wheel_rate"),
    "ackermann": ("steer_left", "steer_right", "rear_left_rate", "rear_right_rate"),
}


class DriveError(InputError):
    """A drive's geometry or command is invalid. The message names the field and value."""


@dataclasses.dataclass(frozen=True)
class Differential:
    """Two driven wheels of radius ``wheel_radius`` on one axle, ``track`` (L) apart, m."""

    wheel_radius: jax.Array
    track: jax.Array
    name = "differential"


@dataclasses.dataclass(frozen=True)
class Tricycle:
    """A steered and driven front wheel ``wheelbase`` (d) ahead of a fixed rear axle, m;
    steering within ±``max_steer`` rad (static)."""

    wheel_radius: jax.Array
    wheelbase: jax.Array
    max_steer: float = math.pi / 2
    name = "tricycle"


@dataclasses.dataclass(frozen=True)
class Synchronous:
    """Wheels of radius ``wheel_radius``, all steered together and driven together, m."""

    wheel_radius: jax.Array
    name = "synchronous"


@dataclasses.dataclass(frozen=True)
class Ackermann:
    """Steered front wheels and driven rear wheels ``wheelbase`` (l) apart, each axle
    ``track`` (d) wide, m; steering within ±``max_steer`` rad (< π/2, static)."""

    wheel_radius: jax.Array
    wheelbase: jax.Array
    track: jax.Array
    max_steer: float = math.radians(35.0)
    name = "ackermann"


Drive = Differential | Tricycle | Synchronous | Ackermann

for _cls in (Differential, Tricycle, Synchronous, Ackermann):
    _static = {"max_steer"}
    _fields = [f.name for f in dataclasses.fields(_cls)]
    jax.tree_util.register_dataclass(
        _cls,
        data_fields=[f for f in _fields if f not in _static],
        meta_fields=[f for f in _fields if f in _static],
    )


# --- constructors ---------------------------------------------------------------------------


def _length(value: npt.ArrayLike, field: str, dtype: jax.typing.DTypeLike) -> jax.Array:
    x = as_float_array(value, field).astype(dtype)
    if x.ndim != 0:
        raise DriveError(f"{field}: shape {tuple(x.shape)} is invalid; expected a scalar")
    if is_concrete(x):
        check_finite(x, field, DriveError)
        if float(x) <= 0:
            raise DriveError(f"{field} = {fmt(x)}: must be > 0 m")
    return x


def _steer_limit(value: float, field: str, below_quarter: bool) -> float:
    top = "< 90°" if below_quarter else "<= 90°"
    ok = 0 < value < math.pi / 2 if below_quarter else 0 < value <= math.pi / 2 + 1e-12
    if not (math.isfinite(value) and ok):
        raise DriveError(
            f"{field} = {fmt(value)} rad ({fmt(math.degrees(value))}°): must be in (0, {top}]"
        )
    return float(value)


def differential(
    wheel_radius: float, track: float, dtype: jax.typing.DTypeLike = jnp.float32
) -> Differential:
    return Differential(
        _length(wheel_radius, "wheel_radius", dtype), _length(track, "track", dtype)
    )


def tricycle(
    wheel_radius: float,
    wheelbase: float,
    max_steer: float = math.pi / 2,
    dtype: jax.typing.DTypeLike = jnp.float32,
) -> Tricycle:
    return Tricycle(
        _length(wheel_radius, "wheel_radius", dtype),
        _length(wheelbase, "wheelbase", dtype),
        _steer_limit(max_steer, "max_steer", below_quarter=False),
    )


def synchronous(wheel_radius: float, dtype: jax.typing.DTypeLike = jnp.float32) -> Synchronous:
    return Synchronous(_length(wheel_radius, "wheel_radius", dtype))


def ackermann(
    wheel_radius: float,
    wheelbase: float,
    track: float,
    max_steer: float = math.radians(35.0),
    dtype: jax.typing.DTypeLike = jnp.float32,
) -> Ackermann:
    return Ackermann(
        _length(wheel_radius, "wheel_radius", dtype),
        _length(wheelbase, "wheelbase", dtype),
        _length(track, "track", dtype),
        _steer_limit(max_steer, "max_steer", below_quarter=True),
    )


__all__ = [
    "ACTUATORS",
    "DRIVES",
    "Ackermann",
    "Differential",
    "Drive",
    "DriveError",
    "DriveName",
    "Synchronous",
    "Tricycle",
    "ackermann",
    "differential",
    "synchronous",
    "tricycle",
]
