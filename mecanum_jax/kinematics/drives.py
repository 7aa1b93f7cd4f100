"""The other wheeled drives of seed 001: differential, tricycle, synchronous and Ackermann.

Each drive has the shape of the mecanum API: a geometry pytree (built by a checked
constructor or from a description in ``configs/robots/drives/``), ``inverse`` (body twist
→ actuator commands), ``forward`` (actuator readings → body twist), ``icr``, odometry
through the exact SE(2) integrator, and the velocity limits (the feasible set, saturation,
desaturation). Everything is batched over leading axes and passes ``jit``, ``vmap`` and
``grad``, in float32 and float64.

Body frame: x forward, y left (REP-103). The reference point, as seed 001 puts it: the
midpoint between the wheels (differential), the rear-axle midpoint (tricycle, Ackermann),
the chassis centre (synchronous). Actuators, per drive (``drive_geometry.ACTUATORS``):

- **differential** ``(ω_L, ω_R)`` wheel rates, rad/s: ``v = r(ω_R + ω_L)/2``,
  ``ω = r(ω_R − ω_L)/L``;
- **tricycle** ``(α, ω_s)``: steering angle of the front wheel (rad, + to the left) at
  ``d`` ahead of the rear axle and its rate: ``v = r ω_s cos α``, ``ω = (r ω_s/d) sin α``;
- **synchronous** ``(φ, ω_w)``: the common steering angle of all wheels and their common
  rate: ``(vx, vy) = r ω_w (cos φ, sin φ)``; the chassis does not rotate (ωz = 0);
- **Ackermann** ``(δ_L, δ_R, ω_RL, ω_RR)``: the front wheels' steering angles (the
  Ackermann condition ``cot δ_R − cot δ_L = track/wheelbase``) and the rear wheels'
  rates (an open differential: ``v ∓ ω·track/2``).

A twist a drive cannot produce (a sideways velocity for the non-holonomic drives, a yaw
rate for the synchronous drive, a curvature beyond the steering limit) is never silently
dropped: :func:`inverse` raises :class:`DriveError` naming it (``strict=True``, concrete
input), and :func:`reachable` / :func:`residual` flag it under ``jit``.

The drives' geometries and their checked constructors are in
:mod:`mecanum_jax.kinematics.drive_geometry`, their descriptions in
:mod:`mecanum_jax.kinematics.drive_description`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax._checks import (
    as_float_array,
    check_finite,
    check_last_axis,
    checked_twist,
    fmt,
    is_concrete,
)
from mecanum_jax.kinematics import odometry
from mecanum_jax.kinematics.drive_geometry import (
    ACTUATORS,
    Ackermann,
    Differential,
    Drive,
    DriveError,
    Synchronous,
    Tricycle,
)
from mecanum_jax.kinematics.model import ICR
from mecanum_jax.kinematics.model import icr as twist_icr

if TYPE_CHECKING:
    import numpy.typing as npt

TOLERANCE = 1e-6
"""Relative size of a twist component a drive is allowed to miss before it is flagged."""


# --- inverse and forward --------------------------------------------------------------------


def _inverse(g: Drive, t: jax.Array) -> jax.Array:
    """Actuators for the producible part of ``t`` (steering clipped to its limit)."""
    r = g.wheel_radius
    v, vy, w = t[..., 0], t[..., 1], t[..., 2]
    if isinstance(g, Differential):
        return jnp.stack([v - w * g.track / 2, v + w * g.track / 2], -1) / r
    if isinstance(g, Synchronous):
        return jnp.stack([jnp.arctan2(vy, v), jnp.hypot(v, vy) / r], -1)
    if isinstance(g, Tricycle):
        # α in (−π/2, π/2] with a signed wheel speed, so reversing keeps the steering
        lateral = w * g.wheelbase
        alpha = jnp.arctan2(lateral, v)
        flip = jnp.abs(alpha) > math.pi / 2 + 1e-12
        alpha = jnp.where(flip, alpha - jnp.sign(alpha) * math.pi, alpha)
        speed = jnp.where(flip, -1.0, 1.0) * jnp.hypot(v, lateral)
        return jnp.stack([jnp.clip(alpha, -g.max_steer, g.max_steer), speed / r], -1)
    # Ackermann: ICR at (0, R = v/ω) on the rear axle; tan δ = l κ / (1 ∓ κ d/2)
    kappa = jnp.where(v != 0, w / jnp.where(v != 0, v, 1.0), 0.0)
    kappa = jnp.clip(kappa, -_max_curvature(g), _max_curvature(g))
    half = g.track / 2
    left = jnp.arctan(g.wheelbase * kappa / (1 - kappa * half))
    right = jnp.arctan(g.wheelbase * kappa / (1 + kappa * half))
    w = v * kappa
    return jnp.stack([left, right, (v - w * half) / r, (v + w * half) / r], -1)


def _max_curvature(g: Ackermann) -> jax.Array:
    """|κ| at which the inner wheel reaches ``max_steer``: ``tan m / (l + (d/2) tan m)``."""
    tan = math.tan(g.max_steer)
    return tan / (g.wheelbase + g.track / 2 * tan)


def _forward(g: Drive, a: jax.Array) -> jax.Array:
    r = g.wheel_radius
    zero = jnp.zeros_like(a[..., 0])
    if isinstance(g, Differential):
        left, right = r * a[..., 0], r * a[..., 1]
        return jnp.stack([(right + left) / 2, zero, (right - left) / g.track], -1)
    if isinstance(g, Synchronous):
        speed = r * a[..., 1]
        return jnp.stack([speed * jnp.cos(a[..., 0]), speed * jnp.sin(a[..., 0]), zero], -1)
    if isinstance(g, Tricycle):
        speed = r * a[..., 1]
        alpha = a[..., 0]
        return jnp.stack([speed * jnp.cos(alpha), zero, speed * jnp.sin(alpha) / g.wheelbase], -1)
    # Ackermann: speed from the rear wheels, curvature from both steering angles (mean)
    v = r * (a[..., 2] + a[..., 3]) / 2
    half = g.track / 2
    tl, tr = jnp.tan(a[..., 0]), jnp.tan(a[..., 1])
    kappa = (tl / (g.wheelbase + half * tl) + tr / (g.wheelbase - half * tr)) / 2
    return jnp.stack([v, zero, v * kappa], -1)


def _reason(g: Drive, twist: np.ndarray) -> str:
    if isinstance(g, Synchronous):
        if abs(twist[2]) > 0:
            return "a synchronous drive's chassis does not rotate (wz must be 0; the wheels steer)"
    elif abs(twist[1]) > TOLERANCE * max(1.0, float(np.abs(twist).max())):
        return f"a {g.name} drive cannot move sideways (vy must be 0)"
    if isinstance(g, Ackermann | Tricycle):
        return f"needs more steering than max_steer = {fmt(math.degrees(g.max_steer))}°"
    return "not producible by this drive"


def _check_reachable(g: Drive, t: jax.Array) -> None:
    bad = np.asarray(~reachable(g, t))
    if bad.any():
        index = tuple(int(i) for i in np.argwhere(bad)[0]) if bad.ndim else ()
        tw = np.asarray(t)[index]
        where = f"twist[{', '.join(map(str, index))}]" if index else "twist"
        shown = "(" + ", ".join(fmt(x) for x in tw) + ")"
        raise DriveError(f"{where} = {shown}: {_reason(g, tw)}")


def inverse(geometry: Drive, twist: jax.typing.ArrayLike, strict: bool = True) -> jax.Array:
    """Actuator commands (..., k) for body twists (..., 3) (``ACTUATORS[geometry.name]``).

    ``strict`` (and concrete input): a twist the drive cannot produce raises
    :class:`DriveError` naming it. Otherwise (or under ``jit``) the commands produce the
    producible part, with steering clipped to its limit: :func:`residual` is the rest.
    """
    t = checked_twist(twist)
    if strict and is_concrete(t, geometry):
        _check_reachable(geometry, t)
    return _inverse(geometry, t)


def _checked_actuators(g: Drive, actuators: npt.ArrayLike) -> jax.Array:
    names = ACTUATORS[g.name]
    a = as_float_array(actuators, "actuators")
    check_last_axis(a, len(names), "actuators", ", ".join(names))
    check_finite(a, "actuators", DriveError)
    steer = [i for i, n in enumerate(names) if n.startswith("steer")]
    limit = getattr(g, "max_steer", math.pi)
    if steer and is_concrete(a):
        angles = np.abs(np.asarray(a)[..., steer])
        if np.any(angles > limit + 1e-6):
            idx = tuple(int(i) for i in np.argwhere(angles > limit + 1e-6)[0])
            value = float(np.asarray(a)[(*idx[:-1], steer[idx[-1]])])
            raise DriveError(
                f"actuators[..., {steer[idx[-1]]}] ({names[steer[idx[-1]]]}) = {fmt(value)} rad "
                f"({fmt(math.degrees(value))}°): beyond max_steer = "
                f"{fmt(math.degrees(limit))}°"
            )
    return a


def forward(geometry: Drive, actuators: jax.typing.ArrayLike) -> jax.Array:
    """Body twists (..., 3) from actuator readings (..., k)."""
    return _forward(geometry, _checked_actuators(geometry, actuators))


def residual(geometry: Drive, twist: jax.typing.ArrayLike) -> jax.Array:
    """What of each twist (..., 3) the drive cannot produce: ``t − forward(inverse(t))``."""
    t = checked_twist(twist)
    return t - _forward(geometry, _inverse(geometry, t))


def reachable(geometry: Drive, twist: jax.typing.ArrayLike) -> jax.Array:
    """Whether the drive can produce each twist (...,) at all (speed limits aside)."""
    t = checked_twist(twist)
    err = jnp.linalg.norm(residual(geometry, t), axis=-1)
    return err <= TOLERANCE * jnp.maximum(1.0, jnp.max(jnp.abs(t), axis=-1))


def icr(geometry: Drive, actuators: jax.typing.ArrayLike, omega_tol: float = 1e-9) -> ICR:
    """Instantaneous centre of rotation (body frame) of actuator readings (..., k).

    A differential drive's lies at ``(0, R)``, ``R = (L/2)(V_R + V_L)/(V_R − V_L)``; a
    tricycle's and an Ackermann car's on the rear axle line, ``R = d·cot α`` (seed 001);
    a synchronous drive's is always at infinity (``translating``).
    """
    return twist_icr(forward(geometry, actuators), omega_tol)


def wheel_odometry(
    geometry: Drive,
    initial_pose: jax.typing.ArrayLike,
    actuators: jax.typing.ArrayLike,
    dt: float,
    *,
    return_path: bool = True,
) -> jax.Array:
    """Dead reckoning from actuator readings (T, ..., k), each held for ``dt`` s: poses."""
    twists = forward(geometry, actuators)
    return odometry.integrate_twists(initial_pose, twists, dt, return_path=return_path)


# --- velocity limits ------------------------------------------------------------------------


def wheel_rates(geometry: Drive, actuators: jax.typing.ArrayLike) -> jax.Array:
    """The driven wheels' rates (..., m) among the actuators, rad/s."""
    a = as_float_array(actuators, "actuators")
    names = ACTUATORS[geometry.name]
    return a[..., [i for i, n in enumerate(names) if n.endswith("rate")]]


def saturation(
    geometry: Drive, twist: jax.typing.ArrayLike, max_rate: jax.typing.ArrayLike
) -> jax.Array:
    """max |driven wheel rate| / ``max_rate`` (...,) for the producible part of twists."""
    m = as_float_array(max_rate, "max_rate")
    if is_concrete(m) and not float(np.min(np.asarray(m))) > 0:
        raise DriveError(f"max_rate = {fmt(np.min(np.asarray(m)))}: must be > 0 rad/s")
    rates = wheel_rates(geometry, _inverse(geometry, checked_twist(twist)))
    return jnp.max(jnp.abs(rates), axis=-1) / m


def is_feasible(
    geometry: Drive, twist: jax.typing.ArrayLike, max_rate: jax.typing.ArrayLike
) -> jax.Array:
    """Whether each twist (...,) is producible and within the wheel-rate limit."""
    return reachable(geometry, twist) & (saturation(geometry, twist, max_rate) <= 1.0 + 1e-6)


def desaturate(
    geometry: Drive, twist: jax.typing.ArrayLike, max_rate: jax.typing.ArrayLike
) -> tuple[jax.Array, jax.Array]:
    """The producible part of each twist, scaled down uniformly to the wheel-rate limit:
    ``(twist (..., 3), scale (...,))``. The steering limit does not scale away: a
    curvature beyond it stays flagged by :func:`reachable`."""
    t = checked_twist(twist)
    produced = _forward(geometry, _inverse(geometry, t))
    sat = saturation(geometry, t, max_rate)
    scale = jnp.where(sat > 1.0, 1.0 / jnp.where(sat > 1.0, sat, 1.0), 1.0)
    return produced * scale[..., None], scale


def max_speed(
    geometry: Drive, direction: jax.typing.ArrayLike, max_rate: jax.typing.ArrayLike
) -> jax.Array:
    """Largest feasible scale s (...) of unit twists ``direction`` (..., 3); 0 where the
    drive cannot produce that direction."""
    d = checked_twist(direction)
    unit = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
    sat = saturation(geometry, unit, max_rate)
    top = jnp.where(sat > 0, 1.0 / jnp.where(sat > 0, sat, 1.0), jnp.inf)
    return jnp.where(reachable(geometry, unit), top, 0.0)


__all__ = [
    "desaturate",
    "forward",
    "icr",
    "inverse",
    "is_feasible",
    "max_speed",
    "reachable",
    "residual",
    "saturation",
    "wheel_odometry",
    "wheel_rates",
]
