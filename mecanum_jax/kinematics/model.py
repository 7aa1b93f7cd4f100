"""Inverse and forward kinematics of a roller-wheel (mecanum) robot, for any layout.

The rigid-body constraint (conventions.md): wheel ``i``'s contact point moves with
``v_i = v_c + ω_c × p_i``; only the component of ``v_i`` along the axis ``u_i`` of the
roller touching the floor is driven by the hub, the rest is taken up by the free roller.
The hub contributes ``r_i ω_i cos γ_i`` along ``u_i``, hence the inverse model

    ω_i = ((v_c + ω_c × p_i) · u_i) / (r_i cos γ_i),   u_i = (cos(ψ_i+γ_i), sin(ψ_i+γ_i)),

the general form of seed 003 eq. 10 and seed 004 eqs. 2.4–2.6. Stacked for all wheels it
is ``ω = J t`` with the (n, 3) Jacobian :func:`jacobian`. The forward model is the
least-squares twist ``t = (JᵀJ)⁻¹ Jᵀ ω`` (seed 004 eq. 2.14).

Shapes: twists ``(..., 3)`` = (vx m/s, vy m/s, ωz rad/s); wheel rates ``(..., n)`` rad/s.
Both maps are batched over any leading axes, and work in float32 and float64 and under
``jit``, ``vmap`` and ``grad``. They are written elementwise (a sum of n·3 scaled
columns) rather than as a matmul: on CPU XLA's small-matrix dot is several times slower
than the fused elementwise loop (see ``docs/benchmarks.md``).

Checked entry points (:func:`inverse`, :func:`forward`) check shapes always and, when
called eagerly, values: non-finite inputs and singular layouts raise. Under ``jit`` the
value checks can't raise; there NaN propagates per robot (a NaN in one twist gives NaN in
that robot's wheel rates only, never in other robots'), a NaN in the geometry makes every
output NaN, and :func:`forward` of a singular layout returns NaN rather than a silently
wrong pseudo-inverse.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax._checks import (
    InputError,
    as_float_array,
    check_finite,
    check_last_axis,
    checked_twist,
    is_concrete,
)
from mecanum_jax.kinematics.geometry import (  # the layout's Jacobian and rank live with it
    GeometryError,
    SingularLayoutError,
    WheelGeometry,
    _singular_tolerance,
    jacobian,
    jacobian_rank,
)
from mecanum_jax.kinematics.geometry import (
    condition_number as condition_number,
)
from mecanum_jax.kinematics.geometry import (
    roller_axes as roller_axes,
)
from mecanum_jax.kinematics.geometry import (
    singular_values as singular_values,
)
from mecanum_jax.precision import HIGHEST


def apply_rows(matrix: jax.Array, x: jax.Array) -> jax.Array:
    """``x @ matrix.T`` for x of shape (..., k) and matrix (m, k), written elementwise.

    Each output column is a sum of k broadcast products, which XLA fuses into one loop.
    """
    m, k = matrix.shape
    lead = (1,) * (x.ndim - 1)
    out = x[..., 0:1] * matrix[:, 0].reshape((*lead, m))
    for j in range(1, k):
        out = out + x[..., j : j + 1] * matrix[:, j].reshape((*lead, m))
    return out


def _checked_geometry(geometry: WheelGeometry) -> None:
    if is_concrete(geometry):
        for field in ("positions", "drive_angles", "roller_angles", "radii"):
            check_finite(getattr(geometry, field), f"geometry.{field}", GeometryError)


def inverse(geometry: WheelGeometry, twist: jax.typing.ArrayLike) -> jax.Array:
    """Wheel rates (..., n) rad/s that realise body twists (..., 3).

    Raises:
      InputError: if the twist's last axis is not 3, or (eagerly) if it is not finite.
    """
    t = checked_twist(twist)
    _checked_geometry(geometry)
    return apply_rows(jacobian(geometry), t)


def inverse_soa(geometry: WheelGeometry, twist_components: jax.typing.ArrayLike) -> jax.Array:
    """:func:`inverse` for component-major data: twists (3, ...) → wheel rates (n, ...).

    The same maths as :func:`inverse` with the component axis first ("structure of
    arrays"), the layout accelerators stream fastest (``docs/benchmarks.md``).
    """
    t = as_float_array(twist_components, "twist_components")
    if t.ndim == 0 or t.shape[0] != 3:
        raise InputError(
            f"twist_components: shape {tuple(t.shape)} is invalid; its first axis must have "
            "size 3 (vx, vy, wz)"
        )
    check_finite(t, "twist_components")
    _checked_geometry(geometry)
    J = jacobian(geometry)
    lead = (-1,) + (1,) * (t.ndim - 1)
    return (
        t[0:1] * J[:, 0].reshape(lead)
        + t[1:2] * J[:, 1].reshape(lead)
        + t[2:3] * J[:, 2].reshape(lead)
    )


def _gram_adjugate(J: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(JᵀJ, adj(JᵀJ), det(JᵀJ)) in closed form: elementwise ops XLA fuses, no solver call."""
    G = jnp.matmul(J.T, J, precision=HIGHEST)
    a, b, c = G[0, 0], G[0, 1], G[0, 2]
    d, e, f = G[1, 1], G[1, 2], G[2, 2]
    adj = jnp.stack(
        [
            jnp.stack([d * f - e * e, c * e - b * f, b * e - c * d]),
            jnp.stack([c * e - b * f, a * f - c * c, b * c - a * e]),
            jnp.stack([b * e - c * d, b * c - a * e, a * d - b * b]),
        ]
    )
    det = a * adj[0, 0] + b * adj[0, 1] + c * adj[0, 2]
    return G, adj, det


def is_singular(geometry: WheelGeometry) -> jax.Array:
    """Traceable test of rank < 3 (a boolean array).

    Uses ``det(JᵀJ) / tr(JᵀJ)³ <= tol²`` with ``tol = 10·max(n, 3)·eps``: for a layout with
    singular values σ1 ≥ σ2 ≥ σ3 the ratio is about (σ3/σ1)²(σ2/σ1)², so it fires for rank
    deficiency (σ3/σ1 below ~tol) and otherwise only for hopelessly conditioned layouts.
    """
    G, _, det = _gram_adjugate(jacobian(geometry))
    return _gram_singular(G, det, geometry)


def _gram_singular(G: jax.Array, det: jax.Array, geometry: WheelGeometry) -> jax.Array:
    trace = G[0, 0] + G[1, 1] + G[2, 2]
    return det <= (_singular_tolerance(geometry) ** 2) * trace**3


def null_twists(geometry: WheelGeometry) -> jax.Array:
    """Unit twists (k, 3) that no wheel drives or senses: the null space of J (k = 3 − rank)."""
    J = np.asarray(jacobian(geometry), dtype=float)
    _, s, vt = np.linalg.svd(J)
    tol = float(_singular_tolerance(geometry)) * s[0]
    return jnp.asarray(vt[int(np.sum(s > tol)) :], geometry.dtype)


def forward_matrix(geometry: WheelGeometry) -> jax.Array:
    """F = (JᵀJ)⁻¹Jᵀ, (3, n): ``twist = F @ wheel_rates`` (seed 004 eq. 2.14).

    Traceable; for a singular layout every entry is NaN (never a silent pseudo-inverse).
    """
    J = jacobian(geometry)
    G, adj, det = _gram_adjugate(J)
    singular = jax.lax.stop_gradient(_gram_singular(G, det, geometry))
    F = jnp.matmul(adj, J.T, precision=HIGHEST) / jnp.where(singular, 1.0, det)
    return jnp.where(singular, jnp.nan, F)


def require_full_rank(geometry: WheelGeometry) -> None:
    """Raise :class:`SingularLayoutError` unless the (concrete) layout has rank 3."""
    rank = jacobian_rank(geometry)
    if rank < 3:
        null = np.round(np.asarray(null_twists(geometry), dtype=float), 6).tolist()
        raise SingularLayoutError(
            f"geometry {geometry.names}: the layout is singular (Jacobian rank {rank} < 3), "
            f"so the twist is not determined by the wheel rates; undetermined twist "
            f"directions (vx, vy, wz): {null}"
        )


def forward(geometry: WheelGeometry, wheel_rates: jax.typing.ArrayLike) -> jax.Array:
    """Least-squares body twists (..., 3) from wheel rates (..., n) rad/s.

    Raises:
      InputError: if the last axis is not n, or (eagerly) if rates are not finite.
      SingularLayoutError: (eagerly) if the layout has rank < 3.
    """
    w = as_float_array(wheel_rates, "wheel_rates")
    check_last_axis(
        w, geometry.n_wheels, "wheel_rates", f"one rate per wheel, n = {geometry.n_wheels}"
    )
    check_finite(w, "wheel_rates")
    _checked_geometry(geometry)
    if is_concrete(geometry):
        require_full_rank(geometry)
    return apply_rows(forward_matrix(geometry), w)


def consistency_residual(geometry: WheelGeometry, wheel_rates: jax.typing.ArrayLike) -> jax.Array:
    """Wheel rates (..., n) that no rigid twist explains: ``ω − J F ω``.

    Zero when the wheels agree on one body motion; non-zero means they fight each other,
    so some wheels must slip (e.g. seed 004's 'left-front and right-front forward').
    """
    w = as_float_array(wheel_rates, "wheel_rates")
    check_last_axis(
        w, geometry.n_wheels, "wheel_rates", f"one rate per wheel, n = {geometry.n_wheels}"
    )
    J = jacobian(geometry)
    return w - apply_rows(J, apply_rows(forward_matrix(geometry), w))


class ICR(NamedTuple):
    """The instantaneous centre of rotation of body twists (seed 000 eq. 20).

    Attributes:
      point: (..., 2) m, its position in the body frame; NaN where there is none.
      translating: (...,) True for a pure translation (no ICR: it is at infinity).
      stationary: (...,) True when the twist is zero (no motion, no ICR).
    """

    point: jax.Array
    translating: jax.Array
    stationary: jax.Array


def icr(twist: jax.typing.ArrayLike, omega_tol: float = 1e-9) -> ICR:
    """Instantaneous centre of rotation of twists (..., 3).

    With ω ≠ 0 the ICR is ``(−vy/ω, vx/ω)``: at distance ``|v|/|ω|`` from the centre,
    perpendicular to v, on its left when ω > 0 (seed 000 eq. 20, ``R_c = v_c/ω_c``). A
    pure spin puts it at the centre. When ``|ω| <= omega_tol`` (rad/s) the motion is a
    translation, reported by the flag ``translating`` and a NaN point, never as a huge
    number.
    """
    t = checked_twist(twist)
    w = t[..., 2]
    rotating = jnp.abs(w) > omega_tol
    safe_w = jnp.where(rotating, w, jnp.ones_like(w))
    point = jnp.stack([-t[..., 1] / safe_w, t[..., 0] / safe_w], -1)
    point = jnp.where(rotating[..., None], point, jnp.nan)
    moving = jnp.any(t[..., :2] != 0, axis=-1)
    return ICR(point=point, translating=~rotating & moving, stationary=~rotating & ~moving)
