"""Singular directions of a layout (seed 003 §3) and how to steer clear of them.

Wheel i is *singular* for a body motion when its hub rate is zero: the contact point then
moves exactly along its floor roller's free-rolling direction, so the wheel is only carried
along and contributes no tractive power in that direction. For a pure translation along
heading φ (body frame) that happens when the motion is perpendicular to the roller axis
u_i, i.e. at ``φ = angle(u_i) ± 90°``, independent of where the wheel sits. The full
Jacobian keeps rank 3 there (docs/discrepancies.md #8): the robot still moves, driven by
the other wheels.

Seed 003's remedy, for lengthways-symmetric layouts where two wheels share a singular
direction: turn the body 10–30° so the travel direction is off the singular one
(:func:`avoidance_turn`).

A *rank-deficient* layout (an X-square: its rollers' axes all pass through the centre, so
it cannot spin) still drives every translation. Such a layout is *usable*: commands are
projected onto the twists it can reach (:func:`reachable_projector`,
:func:`project_reachable`), with one :class:`SingularLayoutWarning` naming the robot and
the lost direction (:func:`warn_unreachable`). A layout that cannot drive every planar
translation (rank < 2, or rank 2 losing a translation) is refused with a named
:class:`SingularLayoutError` (:func:`require_usable`).
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax._checks import checked_twist
from mecanum_jax.kinematics.geometry import (
    SingularLayoutError,
    SingularLayoutWarning,
    WheelGeometry,
)
from mecanum_jax.kinematics.model import (
    apply_rows,
    condition_number,
    jacobian,
    jacobian_rank,
    null_twists,
    roller_axes,
)

__all__ = [
    "SingularDirection",
    "avoidance_turn",
    "condition_number",
    "heading_margin",
    "jacobian_rank",
    "lost_directions",
    "project_reachable",
    "reachable_forward_matrix",
    "reachable_projector",
    "require_usable",
    "singular_directions",
    "singular_headings",
    "singular_wheels",
    "warn_unreachable",
]


def singular_wheels(
    geometry: WheelGeometry, twist: jax.typing.ArrayLike, tol: float = 1e-6
) -> jax.Array:
    """Which wheels (..., n) are singular (hub rate ≈ 0) for body twists (..., 3).

    A wheel is singular when ``|J_i · t| <= tol · ‖J_i‖ ‖t‖``: its hub turns at less than
    ``tol`` of the rate the same speed would need in its best direction. A zero twist
    makes no wheel singular.
    """
    t = checked_twist(twist)
    J = jacobian(geometry)
    rates = apply_rows(J, t)
    row_norm = jnp.linalg.norm(J, axis=-1)
    scale = jnp.linalg.norm(t, axis=-1, keepdims=True) * row_norm.reshape(
        (1,) * (t.ndim - 1) + (-1,)
    )
    return (jnp.abs(rates) <= tol * scale) & (scale > 0)


def singular_headings(geometry: WheelGeometry) -> jax.Array:
    """Per wheel, the translation heading (n,) rad in [0, π) at which its hub stands still.

    The opposite heading (+π) is singular too.
    """
    u = roller_axes(geometry)
    return jnp.mod(jnp.arctan2(u[:, 1], u[:, 0]) + jnp.pi / 2, jnp.pi)


def _axial_distance(a: jax.Array, b: jax.Array) -> jax.Array:
    """Distance between two undirected headings (mod π), in [0, π/2]."""
    d = jnp.mod(a - b + jnp.pi / 2, jnp.pi) - jnp.pi / 2
    return jnp.abs(d)


def heading_margin(geometry: WheelGeometry, heading: jax.typing.ArrayLike) -> jax.Array:
    """Angle (...) rad from a body-frame translation heading (...) to the nearest singular one."""
    h = jnp.asarray(heading)[..., None]
    s = singular_headings(geometry).reshape((1,) * (h.ndim - 1) + (-1,))
    return jnp.min(_axial_distance(h, s), axis=-1)


class SingularDirection(NamedTuple):
    """A translation heading (rad, in [0, π), body frame) and the wheels singular on it."""

    heading: float
    wheels: tuple[str, ...]


def singular_directions(
    geometry: WheelGeometry, min_wheels: int = 2, tol: float = 1e-6
) -> list[SingularDirection]:
    """Translation headings at which ``min_wheels`` or more wheels are singular at once.

    For the standard O/X layouts these are the two diagonals, each with two still wheels
    (seed 000's diagonal mode). For seed 003's centripetal layout with an odd number of
    wheels there are none. Needs a concrete geometry.
    """
    headings = np.asarray(singular_headings(geometry), dtype=float)
    order = np.argsort(headings)
    groups: list[list[int]] = []
    for i in order:
        if groups and _close_mod_pi(headings[groups[-1][0]], headings[i], tol):
            groups[-1].append(int(i))
        else:
            groups.append([int(i)])
    if len(groups) > 1 and _close_mod_pi(headings[groups[0][0]], headings[groups[-1][0]], tol):
        groups[0] = groups.pop() + groups[0]  # wrap-around at 0 / π
    out = [
        SingularDirection(
            float(np.mean(np.unwrap(headings[g], period=np.pi)) % np.pi),
            tuple(geometry.names[i] for i in g),
        )
        for g in groups
        if len(g) >= min_wheels
    ]
    return sorted(out, key=lambda d: d.heading)


def _close_mod_pi(a: float, b: float, tol: float) -> bool:
    d = (a - b + math.pi / 2) % math.pi - math.pi / 2
    return abs(d) <= tol


def avoidance_turn(
    geometry: WheelGeometry, heading: jax.typing.ArrayLike, margin: float = math.radians(10.0)
) -> jax.Array:
    """The smallest body turn (...) rad that keeps a world heading ``margin`` off singular ones.

    Travelling along world heading ``heading`` (...) with the body turned by δ, the body
    sees the motion at ``heading − δ``. Returns the δ of least magnitude for which every
    wheel's singular heading is at least ``margin`` away (0 if the heading is already
    clear), as seed 003 §3.2 proposes (it suggests 10°–30°). NaN where no turn achieves
    the margin (margin larger than half the gap between singular headings).
    """
    h = jnp.asarray(heading)
    s = singular_headings(geometry)
    # candidate turns: none, or put the heading exactly `margin` to either side of a singular one
    cands = jnp.concatenate([jnp.zeros((1,)), s + margin, s - margin]).astype(s.dtype)
    deltas = (
        jnp.mod(h[..., None] - cands.reshape((1,) * h.ndim + (-1,)) + jnp.pi / 2, jnp.pi)
        - jnp.pi / 2
    )
    deltas = jnp.where(jnp.arange(cands.shape[0]).reshape((1,) * h.ndim + (-1,)) == 0, 0.0, deltas)
    margins = jax.vmap(lambda d: heading_margin(geometry, h - d), in_axes=-1, out_axes=-1)(deltas)
    ok = margins >= margin * (1 - 1e-6)
    cost = jnp.where(ok, jnp.abs(deltas), jnp.inf)
    best = jnp.argmin(cost, axis=-1)
    delta = jnp.take_along_axis(deltas, best[..., None], axis=-1)[..., 0]
    return jnp.where(jnp.any(ok, axis=-1), delta, jnp.nan)


# --- rank-deficient layouts: the reachable twist subspace ----------------------------------


def reachable_projector(geometry: WheelGeometry) -> np.ndarray:
    """The (3, 3) orthogonal projector onto the twists the wheels can drive: the row space
    of the Jacobian (the identity for a rank-3 layout). Needs a concrete geometry."""
    lost = np.asarray(null_twists(geometry), dtype=float)
    return np.eye(3) - lost.T @ lost


def project_reachable(twist: jax.typing.ArrayLike, projector: jax.typing.ArrayLike) -> jax.Array:
    """Twists (..., 3) projected onto the reachable subspace (``projector`` from
    :func:`reachable_projector`): the part of a command the layout cannot drive is dropped.
    Pure and traceable (three fused multiply-adds per component), so it runs in the jitted
    command sampler; an identity projector returns the twists unchanged."""
    t = jnp.asarray(twist)
    return apply_rows(jnp.asarray(projector, t.dtype), t)


def reachable_forward_matrix(geometry: WheelGeometry) -> np.ndarray:
    """The (3, n) least-squares forward map restricted to the reachable twists: the
    pseudo-inverse of J. Equal to the forward matrix of a rank-3 layout; for a
    rank-deficient one it reports no motion along the lost directions (the wheels can't
    sense it) instead of NaN. Needs a concrete geometry."""
    J = np.asarray(jacobian(geometry), dtype=float)
    rank = jacobian_rank(geometry)
    u, s, vt = np.linalg.svd(J, full_matrices=False)
    return (vt[:rank].T / s[:rank]) @ u[:, :rank].T


def lost_directions(geometry: WheelGeometry) -> str:
    """The twist directions (vx, vy, ωz) a layout cannot drive, in words ("" for rank 3)."""
    named = {0: "vx (forward translation)", 1: "vy (sideways translation)", 2: "ωz (spin)"}
    words = []
    for v in np.asarray(null_twists(geometry), dtype=float):
        axis = int(np.argmax(np.abs(v)))
        if abs(abs(v[axis]) - 1.0) < 1e-6:
            words.append(named[axis])
        else:
            words.append(f"(vx, vy, ωz) = {np.round(v, 4).tolist()}")
    return ", ".join(words)


def require_usable(geometry: WheelGeometry, robot: str) -> None:
    """Raise :class:`SingularLayoutError` naming ``robot`` unless the wheels can drive
    every planar translation (a rank-3 layout, or a rank-2 one that only loses the spin)."""
    P = reachable_projector(geometry)
    if np.allclose(P[:2, :2], np.eye(2), atol=1e-6):
        return
    raise SingularLayoutError(
        f"robot {robot!r}: the wheels cannot drive every planar translation (Jacobian rank "
        f"{jacobian_rank(geometry)} of 3; lost: {lost_directions(geometry)}); such a layout "
        "cannot be simulated usefully or trained"
    )


def warn_unreachable(geometry: WheelGeometry, robot: str, stacklevel: int = 2) -> None:
    """The one :class:`SingularLayoutWarning` of a rank-deficient layout: it names the robot
    and the lost direction, and says that commands are projected (nothing for rank 3)."""
    if jacobian_rank(geometry) < 3:
        warnings.warn(
            f"robot {robot!r}: singular layout (Jacobian rank {jacobian_rank(geometry)}): it "
            f"cannot drive {lost_directions(geometry)}; commands are projected onto the twists "
            "it can reach",
            SingularLayoutWarning,
            stacklevel=stacklevel + 1,
        )
