"""Wheel rates ↔ motor commands: rpm conversion, gear ratios and mirrored mounting.

A wheel rate (rad/s) is positive when that wheel alone would push the robot forward. The
motors on one side are usually mounted mirrored (seed 000 §2.4, seed 004's code), so
the motor shaft turns the other way: ``motor = sign · gear_ratio · wheel``. Seed 004's
command code applies the sign (``v3 = -(...)``, ``v4 = -(...)``) but its odometry code
forgets it; :func:`motor_rpm_to_wheel_rates` always applies it (docs/discrepancies.md).

rpm = rad/s · 60 / 2π (seed 004's note writes ``Ω·2π = rpm/60``, which is inverted).

Called eagerly, the conversions check their arguments: signs must be ±1, a gear ratio
finite and > 0, and the per-wheel arrays' shapes must match (an error names both). Under
``jit`` only the shapes are checked; the arithmetic is left as it is (see ``_checks``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax._checks import InputError, fmt, is_concrete

RAD_S_PER_RPM = 2 * math.pi / 60


def rads_to_rpm(rate: jax.typing.ArrayLike) -> jax.Array:
    """rad/s → revolutions per minute."""
    return jnp.asarray(rate) / RAD_S_PER_RPM


def rpm_to_rads(rpm: jax.typing.ArrayLike) -> jax.Array:
    """revolutions per minute → rad/s."""
    return jnp.asarray(rpm) * RAD_S_PER_RPM


def mirrored_signs(names: Sequence[str]) -> tuple[int, ...]:
    """Motor signs of the usual mounting: +1 for left wheels, −1 for right wheels.

    Wheels are matched by name (``right_*`` is mirrored), never by position in an array.
    """
    return tuple(-1 if name.startswith("right") else 1 for name in names)


def _per_wheel(value: jax.typing.ArrayLike, like: jax.Array, name: str, what: str) -> jax.Array:
    """A scalar or (n,) per-wheel value, shaped to broadcast against ``like`` (..., n);
    ``name`` and ``what`` (the other array's name) appear in errors."""
    arr = jnp.asarray(value)
    if arr.ndim == 0:
        return arr
    if arr.ndim != 1 or like.ndim == 0 or arr.shape[0] != like.shape[-1]:
        raise InputError(
            f"{name}: shape {tuple(arr.shape)} does not match {what}'s shape "
            f"{tuple(like.shape)}; expected a scalar or one value per wheel "
            f"({like.shape[-1] if like.ndim else '?'},)"
        )
    if like.ndim <= 1:
        return arr
    return arr.reshape((1,) * (like.ndim - arr.ndim) + arr.shape)


def _checked_signs(signs: jax.typing.ArrayLike) -> jax.typing.ArrayLike:
    if is_concrete(signs):
        arr = np.asarray(signs)
        bad = np.flatnonzero((arr.reshape(-1) != 1) & (arr.reshape(-1) != -1))
        if bad.size:
            value = arr.reshape(-1)[bad[0]]
            raise InputError(
                f"signs[{bad[0]}] = {fmt(value)} (signs = {arr.tolist()}): each motor's sign "
                "must be +1 or -1"
            )
    return signs


def _checked_gear_ratio(gear_ratio: jax.typing.ArrayLike) -> jax.typing.ArrayLike:
    if is_concrete(gear_ratio):
        arr = np.asarray(gear_ratio, dtype=float).reshape(-1)
        bad = np.flatnonzero(~(np.isfinite(arr) & (arr > 0)))
        if bad.size:
            where = f"gear_ratio[{bad[0]}]" if np.ndim(gear_ratio) else "gear_ratio"
            raise InputError(
                f"{where} = {fmt(arr[bad[0]])}: must be a finite number > 0 "
                "(motor turns per wheel turn)"
            )
    return gear_ratio


def wheel_rates_to_motor_rpm(
    wheel_rates: jax.typing.ArrayLike,
    signs: jax.typing.ArrayLike,
    gear_ratio: jax.typing.ArrayLike = 1.0,
) -> jax.Array:
    """Motor shaft speeds (..., n) rpm for wheel rates (..., n) rad/s.

    ``signs`` (n,) is ±1 per motor, ``gear_ratio`` motor turns per wheel turn (scalar or (n,)).
    """
    rpm = rads_to_rpm(wheel_rates)
    sign = _per_wheel(_checked_signs(signs), rpm, "signs", "wheel_rates")
    return (
        rpm * sign * _per_wheel(_checked_gear_ratio(gear_ratio), rpm, "gear_ratio", "wheel_rates")
    )


def motor_rpm_to_wheel_rates(
    motor_rpm: jax.typing.ArrayLike,
    signs: jax.typing.ArrayLike,
    gear_ratio: jax.typing.ArrayLike = 1.0,
) -> jax.Array:
    """Wheel rates (..., n) rad/s from motor encoder speeds (..., n) rpm."""
    rates = rpm_to_rads(motor_rpm)
    sign = _per_wheel(_checked_signs(signs), rates, "signs", "motor_rpm")
    return (
        rates * sign / _per_wheel(_checked_gear_ratio(gear_ratio), rates, "gear_ratio", "motor_rpm")
    )


def max_wheel_rate(
    max_motor_rpm: jax.typing.ArrayLike, gear_ratio: jax.typing.ArrayLike = 1.0
) -> jax.Array:
    """The largest wheel rate (rad/s) a motor of ``max_motor_rpm`` reaches through its gears."""
    return rpm_to_rads(max_motor_rpm) / jnp.asarray(_checked_gear_ratio(gear_ratio))
