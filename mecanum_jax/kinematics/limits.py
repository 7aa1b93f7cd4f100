"""Velocity limits: feasibility, desaturation, the feasible twist set, acceleration limits.

Each wheel's rate is bounded, ``|ω_i| <= m_i`` (from motor rpm and gear ratio, see
:func:`.motors.max_wheel_rate`). Through the inverse model ``ω = J t`` the set of
feasible twists is the convex polytope ``{t : |J_i t| <= m_i}`` with 2n facets. For 4
wheels it is seed 000 §4.1's "velocity space" — not the box the seed draws, but an
octahedron-like solid: full speed forward leaves no room for spin.

Desaturation scales a twist uniformly so the fastest wheel sits at its limit: the
direction of travel (and so the path's curvature) is kept. Clipping each wheel rate
independently, as many drivers do, changes the ratios between wheels and so bends the
path (:func:`clip_wheel_rates` is provided to show it).
"""

from __future__ import annotations

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax._checks import (
    InputError,
    as_float_array,
    check_finite,
    checked_twist,
    fmt,
    is_concrete,
)
from mecanum_jax.config import python_number
from mecanum_jax.kinematics.geometry import WheelGeometry
from mecanum_jax.kinematics.model import apply_rows, jacobian
from mecanum_jax.precision import HIGHEST


def _limits(geometry: WheelGeometry, max_rates: jax.typing.ArrayLike) -> jax.Array:
    m = as_float_array(max_rates, "max_rates")
    if m.ndim == 0:
        m = jnp.full((geometry.n_wheels,), m)
    if m.shape != (geometry.n_wheels,):
        raise InputError(
            f"max_rates: shape {tuple(m.shape)} is invalid; "
            f"expected ({geometry.n_wheels},) or a scalar"
        )
    if is_concrete(m):
        check_finite(m, "max_rates")
        bad = np.flatnonzero(np.asarray(m) <= 0)
        if bad.size:
            raise InputError(
                f"max_rates[{bad[0]}] = {fmt(np.asarray(m)[bad[0]])}: must be > 0 rad/s"
            )
    return m


def saturation(
    geometry: WheelGeometry, twist: jax.typing.ArrayLike, max_rates: jax.typing.ArrayLike
) -> jax.Array:
    """max_i |ω_i| / m_i for twists (...,3): ≤ 1 means feasible, 2 means twice too fast."""
    t, m = checked_twist(twist), _limits(geometry, max_rates)
    rates = apply_rows(jacobian(geometry), t)
    return jnp.max(jnp.abs(rates) / m.reshape((1,) * (t.ndim - 1) + (-1,)), axis=-1)


def is_feasible(
    geometry: WheelGeometry, twist: jax.typing.ArrayLike, max_rates: jax.typing.ArrayLike
) -> jax.Array:
    """Whether each twist (..., 3) keeps every wheel within its limit."""
    return saturation(geometry, twist, max_rates) <= 1.0


def desaturate(
    geometry: WheelGeometry, twist: jax.typing.ArrayLike, max_rates: jax.typing.ArrayLike
) -> tuple[jax.Array, jax.Array]:
    """Scale twists (..., 3) uniformly into the feasible set, keeping their direction.

    Returns ``(scaled_twist, scale)`` with ``scale = min(1, 1/saturation)`` (...,).
    Feasible twists pass unchanged. Differentiable almost everywhere.
    """
    t = checked_twist(twist)
    sat = saturation(geometry, t, max_rates)
    scale = 1.0 / jnp.maximum(sat, 1.0)
    return t * scale[..., None], scale


def nearest_feasible(
    geometry: WheelGeometry,
    twist: jax.typing.ArrayLike,
    max_rates: jax.typing.ArrayLike,
    omega_weight: float = 1.0,
) -> jax.Array:
    """The feasible twist nearest each twist (..., 3): argmin over ``|J t| <= m`` of
    ``(vx - cx)² + (vy - cy)² + omega_weight · (ωz - cz)²``.

    Unlike :func:`desaturate` it does not keep the direction: for an out-of-reach command
    it gives the feasible twist with the smallest tracking error in that metric, which is
    what an RMSE of vx, vy and ωz against the command rewards. ``omega_weight`` (> 0, in
    (m/s)² per (rad/s)²) trades linear against angular error (the reference controllers
    use 0.1, ``env.feedback.omega_weight``).

    Exact: the nearest point of the polytope lies on a facet, an edge or a vertex, so every
    set of 1-3 active half-spaces is tried (an orthogonal projection onto their
    intersection) and the nearest feasible candidate kept. Jit- and vmap-friendly;
    ``C(2n, 1) + C(2n, 2) + C(2n, 3)`` candidates per twist (92 for 4 wheels).
    Feasible twists pass unchanged.
    """
    weight = python_number(omega_weight)
    if not (isinstance(weight, int | float) and math.isfinite(weight)) or not weight > 0:
        raise InputError(f"omega_weight = {omega_weight!r}: must be a finite number > 0")
    omega_weight = float(weight)
    t = checked_twist(twist)
    with jax.numpy_rank_promotion("allow"):  # batch dims broadcast against per-facet ones
        return _nearest(t, *feasible_facets(geometry, max_rates), omega_weight)


def _nearest(t: jax.Array, A: jax.Array, b: jax.Array, omega_weight: float) -> jax.Array:
    A, b = A.astype(t.dtype), b.astype(t.dtype)
    d = jnp.asarray([1.0, 1.0, math.sqrt(omega_weight)], t.dtype)
    Au = A / d  # the half-spaces in the weighted coordinates u = d · t
    c = t * d
    tol = 1e-5 * jnp.max(b)
    # every candidate in closed form (elementwise, so XLA fuses it; batched 2x2 and 3x3
    # solves were 8x slower on the CPU where the geometry varies per robot)
    r = _dot(Au, c[..., None, :]) - b  # (..., 2n): how far c lies outside each half-space
    on_facet = c[..., None, :] - (r / _dot(Au, Au))[..., None] * Au
    i = _combinations(A.shape[0], 2)
    p, q, rp, rq = Au[i[:, 0]], Au[i[:, 1]], r[..., i[:, 0]], r[..., i[:, 1]]
    pp, qq, pq = _dot(p, p), _dot(q, q), _dot(p, q)
    det2 = pp * qq - pq**2  # the Gram determinant: 0 for parallel planes (no edge)
    ok2 = jnp.abs(det2) > 1e-8 * pp * qq
    det2 = jnp.where(ok2, det2, 1.0)
    lp, lq = (qq * rp - pq * rq) / det2, (pp * rq - pq * rp) / det2
    on_edge = c[..., None, :] - lp[..., None] * p - lq[..., None] * q
    on_edge = jnp.where(ok2[:, None], on_edge, jnp.inf)
    j = _combinations(A.shape[0], 3)
    x, y, z = Au[j[:, 0]], Au[j[:, 1]], Au[j[:, 2]]
    yz, zx, xy = jnp.cross(y, z), jnp.cross(z, x), jnp.cross(x, y)
    det3 = _dot(x, yz)  # three planes meet in one point (Cramer's rule) where it is not 0
    ok3 = det3**2 > 1e-8 * _dot(x, x) * _dot(y, y) * _dot(z, z)
    det3 = jnp.where(ok3, det3, 1.0)
    vertex = (b[j[:, 0], None] * yz + b[j[:, 1], None] * zx + b[j[:, 2], None] * xy) / det3[:, None]
    vertex = jnp.where(ok3[:, None], vertex, jnp.inf)
    vertex = jnp.broadcast_to(vertex, (*c.shape[:-1], *vertex.shape))
    u = jnp.concatenate([on_facet, on_edge, vertex], axis=-2)  # (..., K, 3)
    feasible = jnp.all(jnp.einsum("ij,...kj->...ki", Au, u, precision=HIGHEST) <= b + tol, axis=-1)
    dist = jnp.where(feasible, jnp.sum((u - c[..., None, :]) ** 2, axis=-1), jnp.inf)
    best = jnp.take_along_axis(u, jnp.argmin(dist, axis=-1)[..., None, None], axis=-2)[..., 0, :]
    inside = jnp.all(r <= 0, axis=-1)
    return jnp.where(inside[..., None], t, best / d)


def _dot(x: jax.Array, y: jax.Array) -> jax.Array:
    """Row-wise dot products as elementwise products and a sum: no matmul, so no matmul
    precision setting can change them on any device."""
    return jnp.sum(x * y, axis=-1)


def _combinations(n: int, k: int) -> np.ndarray:
    return np.asarray(list(itertools.combinations(range(n), k)))


def clip_wheel_rates(
    wheel_rates: jax.typing.ArrayLike, max_rates: jax.typing.ArrayLike
) -> jax.Array:
    """Naive per-wheel clipping to ±m_i: does not keep the twist's direction (see module doc)."""
    w = as_float_array(wheel_rates, "wheel_rates")
    m = jnp.asarray(max_rates, w.dtype)
    m = m.reshape((1,) * (w.ndim - m.ndim) + m.shape) if m.ndim else m
    return jnp.clip(w, -m, m)


def feasible_facets(
    geometry: WheelGeometry, max_rates: jax.typing.ArrayLike
) -> tuple[jax.Array, jax.Array]:
    """The feasible twist set as half-spaces ``A t <= b``: A (2n, 3), b (2n,).

    Rows 2i and 2i+1 are wheel i's forward and backward limits.
    """
    J = jacobian(geometry)
    m = _limits(geometry, max_rates)
    A = jnp.stack([J, -J], axis=1).reshape(-1, 3)
    b = jnp.stack([m, m], axis=1).reshape(-1)
    return A, b


def _vertices(A: np.ndarray, b: np.ndarray, dim: int) -> np.ndarray:
    pts = []
    for rows in itertools.combinations(range(A.shape[0]), dim):
        sub = A[list(rows)]
        if abs(np.linalg.det(sub)) < 1e-12 * max(1.0, np.abs(sub).max() ** dim):
            continue
        x = np.linalg.solve(sub, b[list(rows)])
        if np.all(A @ x <= b * (1 + 1e-9) + 1e-12):
            pts.append(x)
    if not pts:
        return np.zeros((0, dim))
    pts_arr = np.unique(np.round(np.asarray(pts), 12), axis=0)
    return pts_arr


def feasible_vertices(geometry: WheelGeometry, max_rates: jax.typing.ArrayLike) -> np.ndarray:
    """Vertices (k, 3) of the feasible twist polytope, for plotting. Needs a concrete geometry.

    Empty-interior directions (a singular layout's unbounded set) yield no vertices along
    them: an X-square's set is an infinite prism along ωz, and this returns an empty array.
    """
    A, b = (np.asarray(x, dtype=float) for x in feasible_facets(geometry, max_rates))
    return _vertices(A, b, 3)


def feasible_slice(
    geometry: WheelGeometry, max_rates: jax.typing.ArrayLike, wz: float = 0.0
) -> np.ndarray:
    """The polygon (k, 2) of feasible (vx, vy) at a fixed ωz, counter-clockwise, for plotting."""
    A, b = (np.asarray(x, dtype=float) for x in feasible_facets(geometry, max_rates))
    b2 = b - A[:, 2] * wz
    if np.any(b2 < 0):
        return np.zeros((0, 2))
    pts = _vertices(A[:, :2], b2, 2)
    if len(pts) == 0:
        return pts
    centre = pts.mean(axis=0)
    return pts[np.argsort(np.arctan2(pts[:, 1] - centre[1], pts[:, 0] - centre[0]))]


def max_speed(
    geometry: WheelGeometry, direction: jax.typing.ArrayLike, max_rates: jax.typing.ArrayLike
) -> jax.Array:
    """Largest feasible scale s (...) of unit twists ``direction`` (..., 3): the set's radius."""
    d = checked_twist(direction)
    norm = jnp.linalg.norm(d, axis=-1)
    sat = saturation(geometry, d / jnp.where(norm > 0, norm, 1.0)[..., None], max_rates)
    return jnp.where(sat > 0, 1.0 / jnp.where(sat > 0, sat, 1.0), jnp.inf)


def limit_acceleration(
    previous: jax.typing.ArrayLike,
    target: jax.typing.ArrayLike,
    dt: float,
    max_linear_accel: float,
    max_angular_accel: float,
) -> jax.Array:
    """Rate-limit body twists (..., 3) toward ``target`` (ROS 2 controllers' limiter, batched).

    The linear velocity change is limited in magnitude (its direction kept), the angular
    one in value: ``|Δv| <= a_lin dt``, ``|Δω| <= α dt``.
    """
    checked = []
    for name, value in (
        ("dt", dt),
        ("max_linear_accel", max_linear_accel),
        ("max_angular_accel", max_angular_accel),
    ):
        number = python_number(value)
        if isinstance(number, bool) or not (isinstance(number, int | float) and number > 0):
            raise InputError(f"{name} = {value!r}: expected a number > 0")
        checked.append(float(number))
    dt, max_linear_accel, max_angular_accel = checked
    prev, tgt = checked_twist(previous), checked_twist(target)
    dv = tgt[..., :2] - prev[..., :2]
    norm = jnp.linalg.norm(dv, axis=-1, keepdims=True)
    cap = max_linear_accel * dt
    dv = dv * jnp.minimum(1.0, cap / jnp.where(norm > 0, norm, 1.0))
    dw = jnp.clip(tgt[..., 2:3] - prev[..., 2:3], -max_angular_accel * dt, max_angular_accel * dt)
    return jnp.concatenate([prev[..., :2] + dv, prev[..., 2:3] + dw], axis=-1)
