"""How much of the wheels' motion and force ends up moving the robot (seed 000 §4.2).

For a pure translation at unit speed along a body-frame heading φ, each wheel's contact
velocity splits into the hub's rim speed ``r_i ω_i`` (along its drive direction) and the
floor roller's rolling speed ``s_i`` (along the roller's free direction, wasted in roller
friction and wear, seed 000 §4.3). Three figures per heading:

- ``speed_per_rim_speed = |v| / max_i r_i |ω_i|``: top speed per unit of motor rim speed;
  for 45° rollers 1 forward and sideways, 1/√2 diagonally (two wheels do all the work).
- ``roller_speed_per_speed = rms_i |s_i| / |v|``: how fast the rollers must spin; 0 going
  straight ahead, √2 sideways with 45° rollers. This is why sideways motion costs more.
- ``force_efficiency = |Σ F_i| / Σ |F_i|``: with ideal rollers a wheel can only push along
  its roller axis, so wheel forces partly cancel (seed 000 §4.2). Computed for the
  least-norm wheel forces producing a pure force along φ (no moment): 1/√2 forward and
  sideways for 45° rollers.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mecanum_jax.kinematics.geometry import WheelGeometry
from mecanum_jax.kinematics.model import jacobian, roller_axes
from mecanum_jax.precision import HIGHEST


class Efficiency(NamedTuple):
    """Per-heading figures (...,); see the module docstring."""

    speed_per_rim_speed: jax.Array
    roller_speed_per_speed: jax.Array
    force_efficiency: jax.Array


def _one_heading(geometry: WheelGeometry, heading: jax.Array) -> Efficiency:
    v = jnp.stack([jnp.cos(heading), jnp.sin(heading)]).astype(geometry.dtype)
    twist = jnp.concatenate([v, jnp.zeros((1,), v.dtype)])
    rates = jnp.matmul(jacobian(geometry), twist, precision=HIGHEST)
    rim = geometry.radii * rates
    psi = geometry.drive_angles
    d = jnp.stack([jnp.cos(psi), jnp.sin(psi)], -1)
    u = roller_axes(geometry)
    n = jnp.stack([-u[:, 1], u[:, 0]], -1)
    # contact velocity v = rim·d + s·n  →  s = (v − rim·d)·n / (n·n) with n ⟂ u, |n| = 1
    s = jnp.sum((v[None, :] - rim[:, None] * d) * n, axis=-1)
    # wheel forces f_i u_i; wrench W = Σ f_i [u_i; p_i × u_i] = G f; least-norm f for W = [v; 0]
    p = geometry.positions
    G = jnp.stack([u[:, 0], u[:, 1], p[:, 0] * u[:, 1] - p[:, 1] * u[:, 0]], axis=0)
    f = jnp.linalg.lstsq(G, jnp.concatenate([v, jnp.zeros((1,), v.dtype)]))[0]
    net = jnp.linalg.norm(jnp.matmul(G[:2], f, precision=HIGHEST))
    return Efficiency(
        speed_per_rim_speed=1.0 / jnp.max(jnp.abs(rim)),
        roller_speed_per_speed=jnp.sqrt(jnp.mean(s**2)),
        force_efficiency=net / jnp.sum(jnp.abs(f)),
    )


def efficiency(geometry: WheelGeometry, heading: jax.typing.ArrayLike) -> Efficiency:
    """Efficiency figures for translations along body-frame headings (...) rad."""
    h = jnp.asarray(heading, geometry.dtype)
    flat = jax.vmap(lambda a: _one_heading(geometry, a))(h.reshape(-1))
    return Efficiency(*(x.reshape(h.shape) for x in flat))
