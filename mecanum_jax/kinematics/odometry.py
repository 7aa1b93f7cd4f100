"""Planar odometry: body twists or wheel-angle increments → world pose (x, y, θ).

Poses are ``(..., 3)`` = (x m, y m, θ rad) in the world ("odom") frame; twists ``(..., 3)``
in the body frame. Time series are **time-major**: ``(T, ..., 3)`` or ``(T, ..., n)``,
so :func:`jax.lax.scan` runs over axis 0 and every other leading axis is a batch of robots
(use ``jnp.moveaxis(x, 1, 0)`` for batch-major logs).

Integration is exact on SE(2) for a twist held constant over each step: the body moves
along a circular arc. With φ = ω·dt, the body-frame displacement is

    dx = (A(φ) vx − B(φ) vy) dt,  dy = (B(φ) vx + A(φ) vy) dt,  dθ = φ,
    A(φ) = sin φ / φ,  B(φ) = (1 − cos φ) / φ,

and A, B switch to their Taylor series for |φ| < 1e-3 (float64-accurate there), so a
straight line has no 0/0. :func:`euler_step` and :func:`semi_implicit_step` (heading
first, then position with the new heading, as ROS 2's mecanum_drive_controller
integrates) are here for comparison; they are only first-order accurate on arcs.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mecanum_jax._checks import (
    InputError,
    as_float_array,
    check_finite,
    check_last_axis,
    is_concrete,
)
from mecanum_jax.kinematics.geometry import WheelGeometry
from mecanum_jax.kinematics.model import apply_rows, forward_matrix, require_full_rank

_SERIES_BELOW = 1e-3


def rotation_world_to_body(theta: jax.typing.ArrayLike) -> jax.Array:
    """Seed 001's R(θ) = [[cos θ, sin θ, 0], [−sin θ, cos θ, 0], [0, 0, 1]], (..., 3, 3).

    ``R(θ) @ ξ_world`` is the same velocity expressed in the body frame.
    """
    th = jnp.asarray(theta)
    c, s = jnp.cos(th), jnp.sin(th)
    z, o = jnp.zeros_like(th), jnp.ones_like(th)
    return jnp.stack(
        [jnp.stack([c, s, z], -1), jnp.stack([-s, c, z], -1), jnp.stack([z, z, o], -1)], -2
    )


def body_to_world(theta: jax.typing.ArrayLike, twist: jax.typing.ArrayLike) -> jax.Array:
    """A body-frame twist (..., 3) expressed in the world frame at heading θ (...)."""
    t = jnp.asarray(twist)
    th = jnp.asarray(theta)[..., None]
    c, s = jnp.cos(th), jnp.sin(th)
    vx, vy = t[..., 0:1], t[..., 1:2]
    return jnp.concatenate([c * vx - s * vy, s * vx + c * vy, t[..., 2:3]], -1)


def world_to_body(theta: jax.typing.ArrayLike, twist: jax.typing.ArrayLike) -> jax.Array:
    """A world-frame twist (..., 3) expressed in the body frame at heading θ (...): R(θ)·ξ."""
    return body_to_world(-jnp.asarray(theta), twist)


def _arc_coefficients(phi: jax.Array) -> tuple[jax.Array, jax.Array]:
    """A(φ) = sin φ/φ and B(φ) = (1 − cos φ)/φ without 0/0 (and with finite gradients)."""
    small = jnp.abs(phi) < _SERIES_BELOW
    safe = jnp.where(small, jnp.ones_like(phi), phi)
    p2 = phi * phi
    a_series = 1.0 - p2 / 6.0 * (1.0 - p2 / 20.0)
    b_series = phi / 2.0 * (1.0 - p2 / 12.0 * (1.0 - p2 / 30.0))
    a = jnp.where(small, a_series, jnp.sin(safe) / safe)
    b = jnp.where(small, b_series, (1.0 - jnp.cos(safe)) / safe)
    return a, b


def integrate_increment(pose: jax.Array, increment: jax.Array) -> jax.Array:
    """Compose a pose (..., 3) with a body-frame increment (..., 3) = twist·dt, exactly on SE(2).

    The increment is the displacement of a constant-twist arc: (vx·dt, vy·dt, ω·dt).
    """
    a, b = _arc_coefficients(increment[..., 2:3])
    dx = a * increment[..., 0:1] - b * increment[..., 1:2]
    dy = b * increment[..., 0:1] + a * increment[..., 1:2]
    th = pose[..., 2:3]
    c, s = jnp.cos(th), jnp.sin(th)
    return jnp.concatenate(
        [
            pose[..., 0:1] + c * dx - s * dy,
            pose[..., 1:2] + s * dx + c * dy,
            th + increment[..., 2:3],
        ],
        -1,
    )


def euler_step(pose: jax.Array, twist: jax.Array, dt: jax.typing.ArrayLike) -> jax.Array:
    """Explicit Euler: position advanced with the heading at the start of the step."""
    world = body_to_world(pose[..., 2], twist)
    return pose + world * dt


def semi_implicit_step(pose: jax.Array, twist: jax.Array, dt: jax.typing.ArrayLike) -> jax.Array:
    """Semi-implicit Euler, as ROS 2's mecanum_drive_controller integrates: the heading is
    updated first, and the position advanced with the new heading."""
    theta = pose[..., 2:3] + twist[..., 2:3] * dt
    world = body_to_world(theta[..., 0], twist)
    return jnp.concatenate([pose[..., :2] + world[..., :2] * dt, theta], -1)


def _check_series(name: str, x: jax.Array, last: int, meaning: str) -> None:
    check_last_axis(x, last, name, meaning)
    if x.ndim < 2:
        raise InputError(
            f"{name}: shape {tuple(x.shape)} is invalid; expected (T, ..., {last}), time first"
        )
    if x.shape[0] == 0:
        raise InputError(f"{name}: shape {tuple(x.shape)} is a zero-length series (T = 0)")
    check_finite(x, name)


def _check_pose(pose: jax.Array, batch_shape: tuple[int, ...]) -> None:
    check_last_axis(pose, 3, "initial_pose", "x, y, theta")
    check_finite(pose, "initial_pose")
    try:
        jnp.broadcast_shapes(pose.shape[:-1], batch_shape)
    except ValueError:
        raise InputError(
            f"initial_pose: shape {tuple(pose.shape)} does not match the series' robots "
            f"{batch_shape}"
        ) from None


def integrate_increments(
    initial_pose: jax.typing.ArrayLike,
    increments: jax.typing.ArrayLike,
    *,
    return_path: bool = True,
) -> jax.Array:
    """Integrate body-frame increments (T, ..., 3) from ``initial_pose`` (..., 3).

    Returns the poses after each step, (T, ..., 3), or only the final pose (..., 3) when
    ``return_path=False``.
    """
    inc = as_float_array(increments, "increments")
    _check_series("increments", inc, 3, "dx, dy, dtheta in the body frame")
    pose = as_float_array(initial_pose, "initial_pose")
    _check_pose(pose, inc.shape[1:-1])
    pose = jnp.broadcast_to(pose, inc.shape[1:]).astype(jnp.result_type(pose, inc))

    def step(p: jax.Array, d: jax.Array) -> tuple[jax.Array, jax.Array | None]:
        nxt = integrate_increment(p, d)
        return nxt, (nxt if return_path else None)

    final, path = jax.lax.scan(step, pose, inc, unroll=min(inc.shape[0], 4))
    return path if path is not None else final


def integrate_twists(
    initial_pose: jax.typing.ArrayLike,
    twists: jax.typing.ArrayLike,
    dt: float,
    *,
    return_path: bool = True,
) -> jax.Array:
    """Integrate body twists (T, ..., 3), each held for ``dt`` seconds, exactly on SE(2)."""
    if not (isinstance(dt, int | float) and dt > 0 and dt != float("inf")):
        raise InputError(f"dt = {dt!r}: expected a finite time step > 0 s")
    t = as_float_array(twists, "twists")
    _check_series("twists", t, 3, "vx, vy, wz")
    return integrate_increments(initial_pose, t * dt, return_path=return_path)


def wheel_odometry(
    geometry: WheelGeometry,
    initial_pose: jax.typing.ArrayLike,
    wheel_increments: jax.typing.ArrayLike,
    *,
    return_path: bool = True,
) -> jax.Array:
    """Dead reckoning from encoder deltas: wheel-angle increments (T, ..., n) rad → poses.

    Each step's body increment is the least-squares ``F Δφ`` (seed 004 eq. 2.14 applied to
    angles: a constant twist over the step turns the wheels by ``J t dt``), integrated
    exactly on SE(2). No time step is needed.
    """
    d = as_float_array(wheel_increments, "wheel_increments")
    _check_series(
        "wheel_increments",
        d,
        geometry.n_wheels,
        f"one increment per wheel, n = {geometry.n_wheels}",
    )
    if is_concrete(geometry):
        require_full_rank(geometry)
    return integrate_increments(
        initial_pose, apply_rows(forward_matrix(geometry), d), return_path=return_path
    )
