"""Wheel geometry of a mecanum (or any roller-wheel) robot, as a JAX pytree.

Conventions (``docs/conventions.md``): body frame x forward, y left, z up (REP-103);
twist ``(vx, vy, wz)`` in m/s, m/s, rad/s; wheel order of the seeds for 4-wheel layouts:
left-front, left-back, right-back, right-front.

Wheel ``i`` is described by

- ``positions[i] = (x_i, y_i)``: its contact point in the body frame, m;
- ``drive_angles[i] = ψ_i``: the direction in which it rolls when its hub turns
  positively, rad (0 for every wheel of a standard chassis);
- ``roller_angles[i] = γ_i``: the angle from the drive direction to the axis of the roller
  touching the floor, rad, ``0 < |γ_i| < π/2``;
- ``radii[i] = r_i``: its radius, m.

:class:`WheelGeometry` is a plain pytree, so ``jit``, ``vmap`` (e.g. over randomized
radii) and ``grad`` (e.g. calibration) pass through it. It performs no checks itself,
because JAX rebuilds pytrees from tracers; the constructors here validate their inputs.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING, Literal, TypedDict, Unpack

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax._checks import (
    InputError,
    as_float_array,
    check_finite,
    fmt,
    is_concrete,
    real_number,
)
from mecanum_jax.config import python_number
from mecanum_jax.precision import HIGHEST

if TYPE_CHECKING:
    import numpy.typing as npt

FOUR_WHEEL_NAMES = ("left_front", "left_back", "right_back", "right_front")
DEFAULT_ROLLER_ANGLE = math.pi / 4


class GeometryOptions(TypedDict, total=False):
    """The keyword options the layout constructors pass on to :func:`make_geometry`."""

    dtype: jax.typing.DTypeLike | None
    warn_singular: bool


class GeometryChanges(TypedDict, total=False):
    """The fields :meth:`WheelGeometry.replace` may change (its attributes)."""

    positions: jax.Array
    drive_angles: jax.Array
    roller_angles: jax.Array
    radii: jax.Array
    names: tuple[str, ...]


class GeometryError(InputError):
    """A wheel geometry is invalid. The message names the field, the wheel and the value."""


class SingularLayoutWarning(UserWarning):
    """The layout's Jacobian has rank < 3: some body motion can't be driven or observed."""


class SingularLayoutError(ValueError):
    """An operation needs a full-rank layout (e.g. the forward map) and got a singular one."""


@dataclasses.dataclass(frozen=True)
class WheelGeometry:
    """Per-wheel geometry arrays; see the module docstring for meanings and units.

    Attributes:
      positions: (n, 2) m, contact points in the body frame.
      drive_angles: (n,) rad.
      roller_angles: (n,) rad.
      radii: (n,) m.
      names: n wheel names (static metadata, not traced).
    """

    positions: jax.Array
    drive_angles: jax.Array
    roller_angles: jax.Array
    radii: jax.Array
    names: tuple[str, ...]

    @property
    def n_wheels(self) -> int:
        return int(self.radii.shape[-1])

    @property
    def dtype(self) -> np.dtype:
        return self.radii.dtype

    def replace(self, **changes: Unpack[GeometryChanges]) -> WheelGeometry:
        return dataclasses.replace(self, **changes)


jax.tree_util.register_dataclass(
    WheelGeometry,
    data_fields=["positions", "drive_angles", "roller_angles", "radii"],
    meta_fields=["names"],
)


def _fmt_angle(rad: float) -> str:
    return f"{fmt(rad)} rad ({fmt(math.degrees(rad))}°)"


def validate(geometry: WheelGeometry) -> None:
    """Check shapes and (when concrete) values of a geometry; raise :class:`GeometryError`."""
    pos = geometry.positions
    if pos.ndim != 2 or pos.shape[1] != 2:
        raise GeometryError(f"positions: shape {tuple(pos.shape)} is invalid; expected (n, 2)")
    n = pos.shape[0]
    if n < 3:
        raise GeometryError(
            f"positions: {n} wheel(s) given; a mecanum robot needs at least 3 wheels "
            "for 3 degrees of freedom"
        )
    for field in ("drive_angles", "roller_angles", "radii"):
        shape = tuple(getattr(geometry, field).shape)
        if shape != (n,):
            raise GeometryError(f"{field}: shape {shape} is invalid; expected ({n},)")
    if len(geometry.names) != n:
        raise GeometryError(f"names = {geometry.names!r}: expected {n} names, one per wheel")
    if len(set(geometry.names)) != n:
        raise GeometryError(f"names = {geometry.names!r}: wheel names must be unique")
    if not is_concrete(geometry):
        return
    for field in ("positions", "drive_angles", "roller_angles", "radii"):
        check_finite(getattr(geometry, field), field, GeometryError)
    radii = np.asarray(geometry.radii, dtype=float)
    for i, r in enumerate(radii):
        if r <= 0:
            raise GeometryError(
                f"radii[{i}] = {fmt(r)} (wheel {geometry.names[i]!r}): radius must be > 0 m"
            )
    rollers = np.asarray(geometry.roller_angles, dtype=float)
    for i, g in enumerate(rollers):
        if not 0.0 < abs(g) < math.pi / 2:
            raise GeometryError(
                f"roller_angles[{i}] = {_fmt_angle(float(g))} (wheel {geometry.names[i]!r}): "
                "the roller angle must satisfy 0 < |γ| < π/2 (0° < |γ| < 90°)"
            )


def make_geometry(
    positions: npt.ArrayLike,
    drive_angles: npt.ArrayLike,
    roller_angles: npt.ArrayLike,
    radii: npt.ArrayLike,
    names: Sequence[str] | None = None,
    *,
    dtype: jax.typing.DTypeLike | None = None,
    warn_singular: bool = True,
) -> WheelGeometry:
    """The general constructor, from per-wheel arrays with exactly the module's meanings.

    Args:
      positions: (n, 2) contact points, m.
      drive_angles: (n,) rad, or a scalar for all wheels.
      roller_angles: (n,) rad, or a scalar for all wheels.
      radii: (n,) m, or a scalar for all wheels.
      names: n unique names; default ``wheel_0 … wheel_{n-1}``.
      dtype: float dtype of the arrays (default: JAX's default float).
      warn_singular: emit :class:`SingularLayoutWarning` when the Jacobian's rank is < 3.

    Raises:
      GeometryError: naming the field, the wheel and the bad value.
    """
    pos = as_float_array(positions, "positions")
    if dtype is not None:
        pos = pos.astype(dtype)
    dtype = pos.dtype
    if pos.ndim != 2 or pos.shape[1] != 2:
        raise GeometryError(f"positions: shape {tuple(pos.shape)} is invalid; expected (n, 2)")
    n = pos.shape[0]

    def per_wheel(value: npt.ArrayLike, field: str) -> jax.Array:
        arr = as_float_array(value, field).astype(dtype)
        if arr.ndim == 0:
            arr = jnp.full((n,), arr, dtype)
        return arr

    geometry = WheelGeometry(
        positions=pos,
        drive_angles=per_wheel(drive_angles, "drive_angles"),
        roller_angles=per_wheel(roller_angles, "roller_angles"),
        radii=per_wheel(radii, "radii"),
        names=tuple(names) if names is not None else tuple(f"wheel_{i}" for i in range(n)),
    )
    validate(geometry)
    if warn_singular and is_concrete(geometry):
        _warn_if_singular(geometry)
    return geometry


# --- the layout's Jacobian and its rank ----------------------------------------------------


def roller_axes(geometry: WheelGeometry) -> jax.Array:
    """Unit vectors u_i of the floor rollers' axes in the body frame, (n, 2)."""
    a = geometry.drive_angles + geometry.roller_angles
    return jnp.stack([jnp.cos(a), jnp.sin(a)], axis=-1)


def jacobian(geometry: WheelGeometry) -> jax.Array:
    """The inverse-kinematics matrix J, (n, 3): ``wheel_rates = J @ twist``.

    Row i is ``[u_x, u_y, x_i u_y − y_i u_x] / (r_i cos γ_i)``, in rad/m, rad/m, rad/rad.
    """
    u = roller_axes(geometry)
    x, y = geometry.positions[:, 0], geometry.positions[:, 1]
    lever = x * u[:, 1] - y * u[:, 0]
    scale = 1.0 / (geometry.radii * jnp.cos(geometry.roller_angles))
    return jnp.stack([u[:, 0], u[:, 1], lever], axis=-1) * scale[:, None]


def _singular_tolerance(geometry: WheelGeometry) -> jax.Array:
    eps = jnp.finfo(geometry.dtype).eps
    return jnp.asarray(max(geometry.n_wheels, 3) * 10 * eps, geometry.dtype)


def singular_values(geometry: WheelGeometry) -> jax.Array:
    """Singular values of J in descending order, (3,)."""
    return jnp.linalg.svd(jacobian(geometry), compute_uv=False)


def jacobian_rank(geometry: WheelGeometry) -> int:
    """Numerical rank of J (3 for an omnidirectional layout). Needs a concrete geometry."""
    s = np.asarray(singular_values(geometry), dtype=float)
    tol = float(_singular_tolerance(geometry)) * s[0]
    return int(np.sum(s > tol))


def condition_number(geometry: WheelGeometry) -> jax.Array:
    """σ_max/σ_min of J (inf for a singular layout).

    J mixes units (its spin column is in metres), so the number depends on them: it is
    the amplification of relative errors from wheel rates to the SI twist.
    """
    s = singular_values(geometry)
    return jnp.where(s[-1] > _singular_tolerance(geometry) * s[0], s[0] / s[-1], jnp.inf)


def _warn_if_singular(geometry: WheelGeometry) -> None:
    rank = jacobian_rank(geometry)
    if rank < 3:
        warnings.warn(
            f"singular layout: Jacobian rank {rank} < 3 (condition number "
            f"{float(condition_number(geometry)):.3g}); some body twists can neither be "
            "driven nor measured by the wheels (see mecanum_jax.kinematics.model.null_twists)",
            SingularLayoutWarning,
            stacklevel=3,
        )


def _require_positive(value: object, field: str) -> float:
    """``value`` as a float: a finite number (NumPy/JAX scalars too) > 0, else an error."""
    number = real_number(value, field, GeometryError)
    if number <= 0:
        raise GeometryError(f"{field} = {value!r}: must be > 0")
    return number


def four_wheel(
    shape: Literal["O", "X"],
    radius: float,
    half_wheelbase: float,
    half_track: float,
    roller_angle: float = DEFAULT_ROLLER_ANGLE,
    *,
    dtype: jax.typing.DTypeLike | None = None,
    warn_singular: bool = True,
) -> WheelGeometry:
    """A standard 4-wheel chassis (seed 002), wheels in the seeds' order LF, LB, RB, RF.

    Args:
      shape: "O" when the axes of the floor rollers draw an O seen from above (tangent to
        the circle through the wheels; seed 000's inward "内八" layout), "X" when they point
        at the centre.
      radius: wheel radius r, m.
      half_wheelbase: rx, half the front-back distance between axles, m.
      half_track: ry, half the left-right distance between wheels, m.
      roller_angle: |γ|, rad (45° by default).

    The O layout has γ = (−γ, +γ, −γ, +γ); its inverse matrix is seed 000 eq. 18. The X
    layout has γ = (+γ, −γ, +γ, −γ) and lever arm rx − ry, so an X-square can't spin.
    """
    if shape not in ("O", "X"):
        raise GeometryError(f"shape = {shape!r}: expected 'O' or 'X'")
    radius = _require_positive(radius, "radius")
    rx = _require_positive(half_wheelbase, "half_wheelbase")
    ry = _require_positive(half_track, "half_track")
    roller_angle = _require_positive(roller_angle, "roller_angle")
    positions = [[rx, ry], [-rx, ry], [-rx, -ry], [rx, -ry]]
    sign = -1.0 if shape == "O" else 1.0
    rollers = [sign * roller_angle, -sign * roller_angle, sign * roller_angle, -sign * roller_angle]
    return make_geometry(
        positions, 0.0, rollers, radius, FOUR_WHEEL_NAMES, dtype=dtype, warn_singular=warn_singular
    )


def o_square(
    radius: float,
    half_size: float,
    roller_angle: float = DEFAULT_ROLLER_ANGLE,
    **kw: Unpack[GeometryOptions],
) -> WheelGeometry:
    """O-square: contact points on a square of side 2·half_size (seed 002's ideal layout)."""
    return four_wheel("O", radius, half_size, half_size, roller_angle, **kw)


def o_rectangle(
    radius: float,
    half_wheelbase: float,
    half_track: float,
    roller_angle: float = DEFAULT_ROLLER_ANGLE,
    **kw: Unpack[GeometryOptions],
) -> WheelGeometry:
    """O-rectangle: the most common layout (seed 002)."""
    return four_wheel("O", radius, half_wheelbase, half_track, roller_angle, **kw)


def x_square(
    radius: float,
    half_size: float,
    roller_angle: float = DEFAULT_ROLLER_ANGLE,
    **kw: Unpack[GeometryOptions],
) -> WheelGeometry:
    """X-square: singular, it cannot spin actively (seed 002); builds with a warning."""
    return four_wheel("X", radius, half_size, half_size, roller_angle, **kw)


def x_rectangle(
    radius: float,
    half_wheelbase: float,
    half_track: float,
    roller_angle: float = DEFAULT_ROLLER_ANGLE,
    **kw: Unpack[GeometryOptions],
) -> WheelGeometry:
    """X-rectangle: spins with the short lever arm |rx − ry| (seed 002)."""
    return four_wheel("X", radius, half_wheelbase, half_track, roller_angle, **kw)


def centripetal(
    radius: float,
    centre_distance: float,
    n_wheels: int = 3,
    roller_angle: float = DEFAULT_ROLLER_ANGLE,
    first_wheel_angle: float = 0.0,
    **kw: Unpack[GeometryOptions],
) -> WheelGeometry:
    """The centripetal layout of seed 003 §3.1: n wheels evenly spaced on a circle.

    Every hub axle passes through the centre, so wheel ``i`` at polar angle
    ``β_i = first_wheel_angle + 2πi/n`` rolls tangentially: ``ψ_i = β_i + π/2``. All
    rollers share the angle ``roller_angle``, as the seed recommends. With an odd n at most
    one wheel is singular in any direction of travel.
    """
    n = python_number(n_wheels)
    if isinstance(n, bool) or not isinstance(n, int) or n < 3:
        raise GeometryError(f"n_wheels = {n_wheels!r}: expected an integer >= 3")
    n_wheels = n
    radius = _require_positive(radius, "radius")
    centre_distance = _require_positive(centre_distance, "centre_distance")
    beta = first_wheel_angle + 2 * math.pi * np.arange(n_wheels) / n_wheels
    positions = centre_distance * np.stack([np.cos(beta), np.sin(beta)], axis=-1)
    names = [f"wheel_{i}" for i in range(n_wheels)]
    return make_geometry(positions, beta + math.pi / 2, roller_angle, radius, names, **kw)


def rotated(geometry: WheelGeometry, angle: jax.typing.ArrayLike) -> WheelGeometry:
    """The same chassis turned by ``angle`` rad about the body origin (positions and drives)."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    rot = jnp.stack([jnp.stack([c, -s]), jnp.stack([s, c])]).astype(geometry.dtype)
    return geometry.replace(
        positions=jnp.matmul(geometry.positions, rot.T, precision=HIGHEST),
        drive_angles=geometry.drive_angles + jnp.asarray(angle, geometry.dtype),
    )
