"""Calibrate wheel radii and lever arms from logs, by least squares through the kinematics.

Chassis parameters are hard to measure and are calibrated with sensors (seed 002 note 1).
Given logged wheel rates (encoders) and measured body twists (motion capture, a lidar
odometry), or wheel-angle increments and measured poses, this fits the parameters of a
nominal geometry by Levenberg–Marquardt (Gauss–Newton with adaptive damping), with the
Jacobian of the residuals from ``jax.jacfwd`` through :func:`kinematics.forward` or the
SE(2) odometry.

Parameter sets (``fit``):

- ``"radii+lever_scale"``: each wheel's effective radius, and one scale on all contact
  positions (for the standard layouts: the seeds' lever arm K = rx + ry).
- ``"radii+levers"``: each wheel's radius and its own lever arm ``p_i × u_i`` (the moment
  arm of its roller force). This is the full identifiable geometry: moving a wheel along
  its own roller axis changes nothing the wheels can sense, so positions as such are not
  identifiable; their moment arms are.
- ``"radii"``, ``"lever_scale"``: either alone.

Uncertainty is the Gauss–Newton covariance ``(JᵀWJ)⁻¹``, with each residual component's
noise variance estimated from the fit's residuals. A parameter the log cannot determine
(no rotation in the log, so the lever arm is unobservable; a wheel that never turns) makes
the fit raise :class:`UnidentifiableError` rather than return a confident number.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax._checks import InputError, as_float_array, check_finite, check_last_axis
from mecanum_jax.kinematics.geometry import WheelGeometry
from mecanum_jax.kinematics.model import (
    apply_rows,
    forward_matrix,
    jacobian,
    require_full_rank,
    roller_axes,
)
from mecanum_jax.kinematics.odometry import integrate_increments

FitSet = Literal["radii+lever_scale", "radii+levers", "radii", "lever_scale"]


class UnidentifiableError(ValueError):
    """The log does not determine some parameter; the message says which and why."""


class CalibrationResult(NamedTuple):
    """A calibration.

    Attributes:
      geometry: the calibrated geometry.
      params: fitted values by name, in physical units (radii m, lever_scale 1, levers m).
      std: one-sigma uncertainties, same keys and units.
      correlation: (p, p) correlation matrix of the parameters, in ``names`` order.
      names: the parameters' names, e.g. ``("radius[left_front]", …, "lever_scale")``.
      residual_rms: per residual component after the fit: (vx, vy, ωz) for twist logs,
        one per wheel (rad/s) for ``fit="radii+levers"``, (x, y, θ) for pose logs.
      iterations: Levenberg–Marquardt iterations taken.
    """

    geometry: WheelGeometry
    params: dict[str, np.ndarray]
    std: dict[str, np.ndarray]
    correlation: np.ndarray
    names: tuple[str, ...]
    residual_rms: np.ndarray
    iterations: int


def _parametrize(
    nominal: WheelGeometry, fit: FitSet
) -> tuple[int, Callable[[jax.Array], WheelGeometry], list[str]]:
    n = nominal.n_wheels
    u = roller_axes(nominal)
    normal = jnp.stack([-u[:, 1], u[:, 0]], -1)  # shifting p_i along this changes its lever by −1
    fit_radii = fit in ("radii+lever_scale", "radii+levers", "radii")
    mode = {
        "radii+lever_scale": "scale",
        "lever_scale": "scale",
        "radii+levers": "levers",
        "radii": None,
    }[fit]
    names = [f"radius[{w}]" for w in nominal.names] if fit_radii else []
    if mode == "scale":
        names.append("lever_scale")
    elif mode == "levers":
        names += [f"lever[{w}]" for w in nominal.names]

    def build(theta: jax.Array) -> WheelGeometry:
        k = 0
        radii, positions = nominal.radii, nominal.positions
        if fit_radii:
            radii = nominal.radii * jnp.exp(theta[:n])
            k = n
        if mode == "scale":
            positions = nominal.positions * jnp.exp(theta[k])
        elif mode == "levers":
            positions = nominal.positions - theta[k : k + n, None] * normal
        return nominal.replace(radii=radii, positions=positions)

    return len(names), build, names


def _levenberg_marquardt(
    residual: Callable[[jax.Array], jax.Array], theta0: jax.Array, max_iter: int
) -> tuple[jax.Array, jax.Array]:
    """Minimise ½‖residual(θ)‖² from θ0; returns (θ, iterations)."""

    def cost(th: jax.Array) -> jax.Array:
        return 0.5 * jnp.sum(residual(th) ** 2)

    def body(state: tuple) -> tuple:
        th, lam, it, _, c = state
        r = residual(th)
        Jr = jax.jacfwd(residual)(th)
        A = Jr.T @ Jr
        g = Jr.T @ r
        step = jnp.linalg.solve(A + lam * jnp.diag(jnp.diag(A) + 1e-12), -g)
        c_new = cost(th + step)
        better = c_new < c
        th = jnp.where(better, th + step, th)
        rel = jnp.where(better, (c - c_new) / jnp.maximum(c, 1e-300), 1.0)
        lam = jnp.where(better, lam * 0.3, lam * 10.0)
        return th, lam, it + 1, rel, jnp.where(better, c_new, c)

    def cond(state: tuple) -> jax.Array:
        _, lam, it, rel, _ = state
        return (it < max_iter) & ((rel > 1e-12) | (it < 2)) & (lam < 1e12)

    init = (
        theta0,
        jnp.asarray(1e-3, theta0.dtype),
        jnp.asarray(0),
        jnp.asarray(1.0, theta0.dtype),
        cost(theta0),
    )
    th, _, it, _, _ = jax.lax.while_loop(cond, body, init)
    return th, it


def _fit(
    nominal: WheelGeometry,
    fit: FitSet,
    residual_of: Callable[[WheelGeometry], jax.Array],
    components: tuple[str, ...],
    max_iter: int,
) -> CalibrationResult:
    require_full_rank(nominal)
    p, build, names = _parametrize(nominal, fit)
    theta0 = jnp.zeros((p,), nominal.dtype)

    def raw(theta: jax.Array) -> jax.Array:
        return residual_of(build(theta))  # (T, 3)

    # Two passes: unit weights, then each component whitened by its residual variance.
    sigma = jnp.ones((raw(theta0).shape[-1],), nominal.dtype)
    theta, iters = theta0, jnp.asarray(0)
    for _ in range(2):
        s = sigma

        def whitened(th: jax.Array, s: jax.Array = s) -> jax.Array:
            return (raw(th) / s[None, :]).reshape(-1)

        theta, it = jax.jit(_levenberg_marquardt, static_argnums=(0, 2))(whitened, theta, max_iter)
        iters = iters + it
        res = raw(theta)
        dof = max(res.size - p, 1) / res.shape[-1]
        sigma = jnp.sqrt(jnp.sum(res**2, axis=0) / dof)
        sigma = jnp.maximum(sigma, 1e-12 * (jnp.max(sigma) + 1e-30))

    Jr = np.asarray(
        jax.jacfwd(lambda th: (raw(th) / sigma[None, :]).reshape(-1))(theta), dtype=float
    )
    _check_identifiable(Jr, names, components)
    cov = np.linalg.inv(Jr.T @ Jr)
    std_theta = np.sqrt(np.diag(cov))
    corr = cov / np.outer(std_theta, std_theta)
    geometry = build(theta)
    th = np.asarray(theta, dtype=float)
    params, std = _physical_params(fit, geometry, th, std_theta)
    final_residual = np.asarray(raw(theta), dtype=float)
    _check_relative_std(params, std, names)
    return CalibrationResult(
        geometry=geometry,
        params=params,
        std=std,
        correlation=corr,
        names=tuple(names),
        residual_rms=np.sqrt(np.mean(final_residual**2, axis=0)),
        iterations=int(iters),
    )


def _physical_params(
    fit: FitSet, geometry: WheelGeometry, th: np.ndarray, std_theta: np.ndarray
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The fitted parameters in physical units, and their standard deviations."""
    params: dict[str, np.ndarray] = {}
    std: dict[str, np.ndarray] = {}
    n = geometry.n_wheels
    k = 0
    if fit in ("radii+lever_scale", "radii+levers", "radii"):
        params["radii"] = np.asarray(geometry.radii, dtype=float)
        std["radii"] = params["radii"] * std_theta[:n]  # delta method, radius = r0·exp(θ)
        k = n
    if fit in ("radii+lever_scale", "lever_scale"):
        params["lever_scale"] = np.exp(th[k])
        std["lever_scale"] = params["lever_scale"] * std_theta[k]
    elif fit == "radii+levers":
        u = np.asarray(roller_axes(geometry), dtype=float)
        pos = np.asarray(geometry.positions, dtype=float)
        params["levers"] = pos[:, 0] * u[:, 1] - pos[:, 1] * u[:, 0]
        std["levers"] = std_theta[k : k + n]
    return params, std


def _check_identifiable(Jr: np.ndarray, names: list[str], components: tuple[str, ...]) -> None:
    col = np.linalg.norm(Jr, axis=0)
    scale = col.max() if col.size else 1.0
    if scale == 0:
        raise UnidentifiableError("the log carries no information on any parameter (no motion?)")
    dead = [names[i] for i in np.flatnonzero(col <= 1e-9 * scale)]
    if dead:
        raise UnidentifiableError(
            f"{', '.join(dead)}: not identifiable from this log (the residuals do not depend on it)"
            + _hint(dead)
        )
    _, s, vt = np.linalg.svd(Jr / col, full_matrices=False)
    if s[-1] <= 1e-7 * s[0]:
        weights = np.abs(vt[-1])
        involved = [names[i] for i in np.flatnonzero(weights > 0.3 * weights.max())]
        raise UnidentifiableError(
            f"{', '.join(involved)}: not separately identifiable from this log "
            f"(normalised information matrix condition {s[0] / s[-1]:.3g})" + _hint(involved)
        )


def _check_relative_std(
    params: dict[str, np.ndarray], std: dict[str, np.ndarray], names: list[str]
) -> None:
    for key in ("radii", "lever_scale"):
        if key in params:
            rel = np.atleast_1d(std[key] / np.abs(params[key]))
            bad = np.flatnonzero(rel > 0.25)
            if bad.size:
                label = [n for n in names if n.startswith("radius") or n == "lever_scale"]
                label = [n for n in label if (n == "lever_scale") == (key == "lever_scale")]
                worst = label[int(bad[0])] if key == "radii" else "lever_scale"
                raise UnidentifiableError(
                    f"{worst}: poorly identifiable from this log (relative uncertainty "
                    f"{float(rel[bad[0]]):.3g} > 0.25)" + _hint([worst])
                )
    if "levers" in params:
        arm = np.abs(params["levers"]).max()
        bad = np.flatnonzero(std["levers"] > 0.25 * max(arm, 1e-6))
        if bad.size:
            raise UnidentifiableError(
                f"{[n for n in names if n.startswith('lever')][int(bad[0])]}: poorly identifiable "
                f"from this log (uncertainty {float(std['levers'][bad[0]]):.3g} m)"
                + _hint(["lever"])
            )


def _hint(names: list[str]) -> str:
    if any("lever" in n for n in names):
        return "; the lever arm is only seen through rotation: log turning motion (ωz ≠ 0)"
    return "; log motion in which every wheel turns (e.g. forward, sideways and spinning)"


def _check_log(
    wheel: jax.Array, other: jax.Array, n: int, wheel_name: str, other_name: str, other_len: int
) -> None:
    check_last_axis(wheel, n, wheel_name, f"one column per wheel, n = {n}")
    check_last_axis(other, 3, other_name, "three components")
    if wheel.ndim != 2 or other.ndim != 2:
        raise InputError(
            f"{wheel_name} and {other_name}: expected 2-D logs (T, ·), "
            f"got {wheel.shape} and {other.shape}"
        )
    if wheel.shape[0] == 0:
        raise InputError(f"{wheel_name}: zero-length log (T = 0)")
    if other.shape[0] != wheel.shape[0] + other_len:
        raise InputError(
            f"{other_name}: {other.shape[0]} rows do not match {wheel_name}'s {wheel.shape[0]} "
            f"(expected {wheel.shape[0] + other_len})"
        )
    check_finite(wheel, wheel_name)
    check_finite(other, other_name)


def calibrate_from_twists(
    nominal: WheelGeometry,
    wheel_rates: jax.typing.ArrayLike,
    twists: jax.typing.ArrayLike,
    fit: FitSet = "radii+lever_scale",
    max_iter: int = 100,
) -> CalibrationResult:
    """Fit parameters so that ``forward(geometry, wheel_rates)`` matches measured twists.

    Args:
      nominal: the starting geometry (roller angles and layout are kept).
      wheel_rates: (T, n) rad/s from the encoders.
      twists: (T, 3) measured body twists.
    """
    w = as_float_array(wheel_rates, "wheel_rates")
    t = as_float_array(twists, "twists")
    _check_log(w, t, nominal.n_wheels, "wheel_rates", "twists", 0)
    w, t = w.astype(nominal.dtype), t.astype(nominal.dtype)
    if "lever" in fit:
        _check_rotation_excitation(nominal, t)
    if fit == "radii+levers":
        # Per-wheel levers: compare each wheel's rate with J(θ)·t. The twist-space residual
        # cannot see one combination of per-wheel levers (the one orthogonal to the range
        # of J), the wheel-space one can; it needs the twists measured well (errors in t
        # bias the fit by about (σ_t / spread of t)², negligible for motion capture).
        return _fit(nominal, fit, lambda g: apply_rows(jacobian(g), t) - w, nominal.names, max_iter)
    return _fit(
        nominal, fit, lambda g: apply_rows(forward_matrix(g), w) - t, ("vx", "vy", "wz"), max_iter
    )


def _check_rotation_excitation(nominal: WheelGeometry, twists: jax.Array) -> None:
    """Lever arms are only seen through rotation: refuse logs in which rotation contributes
    less than 5% of the wheels' rim speed (a heuristic guard on top of the statistical
    identifiability check, which noise in the measured ωz could fool)."""
    t = np.asarray(twists, dtype=float)
    lever = float(np.mean(np.linalg.norm(np.asarray(nominal.positions, dtype=float), axis=-1)))
    spin = float(np.sqrt(np.mean(t[:, 2] ** 2))) * lever
    speed = float(np.sqrt(np.mean(np.sum(t[:, :2] ** 2, axis=-1))))
    if spin < 0.05 * max(speed, 1e-12):
        raise UnidentifiableError(
            f"lever arm: not identifiable from this log: rotation moves the wheels at "
            f"{spin:.3g} m/s rms against {speed:.3g} m/s of translation (< 5%)" + _hint(["lever"])
        )


def calibrate_from_poses(
    nominal: WheelGeometry,
    wheel_increments: jax.typing.ArrayLike,
    poses: jax.typing.ArrayLike,
    fit: FitSet = "radii+lever_scale",
    max_iter: int = 100,
) -> CalibrationResult:
    """Fit parameters so that wheel odometry reproduces measured poses.

    Args:
      wheel_increments: (T, n) encoder angle increments, rad.
      poses: (T + 1, 3) measured world poses, the first being the start.
    """
    d = as_float_array(wheel_increments, "wheel_increments")
    p = as_float_array(poses, "poses")
    _check_log(d, p, nominal.n_wheels, "wheel_increments", "poses", 1)
    d, p = d.astype(nominal.dtype), p.astype(nominal.dtype)

    def residual(g: WheelGeometry) -> jax.Array:
        path = integrate_increments(p[0], apply_rows(forward_matrix(g), d))
        err = path - p[1:]
        wrapped = jnp.mod(err[:, 2] + jnp.pi, 2 * jnp.pi) - jnp.pi
        return jnp.concatenate([err[:, :2], wrapped[:, None]], axis=-1)

    return _fit(nominal, fit, residual, ("x", "y", "theta"), max_iter)
