"""The robot's mirror group acting on observations and actions.

An O or X layout is unchanged by the left-right mirror (y → −y), the front-back mirror
(x → −x) and the half turn; each maps a twist ``(vx, vy, ωz)`` by signs and the wheels by
a signed permutation (``J[i]·t = s_i·J[π(i)]``, found from the Jacobian, so any robot with
these symmetries qualifies and one without them is refused). Each group element acts on
an observation vector as a signed permutation of its entries (:func:`mirrors`), and a
policy averaged over the group, ``f(o) = ¼ Σ_g g⁻¹·f(g·o)``, is exactly equivariant: a
command the mirror leaves unchanged gets a correction it leaves unchanged, whatever the
weights (:func:`symmetrize`). NumPy and the standard library only (copied beside exports).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from .spec import ControllerSpec

TWIST_SIGNS = {
    "left_right": (1.0, -1.0, -1.0),
    "front_back": (-1.0, 1.0, -1.0),
    "half_turn": (-1.0, -1.0, 1.0),
}
"""Each non-trivial element's signs on ``(vx, vy, ωz)``."""

Map = tuple[np.ndarray, np.ndarray]  # (index, sign): x' = sign · x[..., index]


class AsymmetricRobotError(ValueError):
    """The robot's wheels are not mapped onto each other by a mirror."""


def wheel_map(jacobian: np.ndarray, signs: tuple[float, ...], name: str = "") -> Map:
    """The wheels' signed permutation under the twist signs ``signs``."""
    J = np.asarray(jacobian, np.float64)
    mirrored = J * np.asarray(signs)
    index, sign = [], []
    for i, row in enumerate(mirrored):
        for j, other in enumerate(J):
            for s in (1.0, -1.0):
                if np.allclose(row, s * other, rtol=1e-4, atol=1e-6):
                    index.append(j)
                    sign.append(s)
                    break
            else:
                continue
            break
        else:
            raise AsymmetricRobotError(
                f"env.symmetric = true: wheel {i}'s row {row.round(4).tolist()} of the "
                f"{name} mirror matches no wheel; this robot is not mirror-symmetric"
            )
    return np.asarray(index), np.asarray(sign, np.float32)


def _entry_map(name: str, size: int, signs: Any, wheels: Map, spec: ControllerSpec) -> Map:
    t = np.asarray(signs, np.float32)
    twist = (np.arange(3), t)
    scalar = (np.zeros(1, int), t[2:3])
    accel = (np.arange(3), np.asarray([t[0], t[1], 1.0], np.float32))
    frame = [wheels, scalar, accel, twist]
    if name in ("command", "odometry_twist", "path_error"):
        return twist
    if name == "wheel_rate":
        return wheels
    if name in ("gyro_z", "yaw_error_integral", "feedback_integral"):
        return scalar
    if name == "accel":
        return accel
    if name == "last_action":
        return twist if spec.twist_residual else wheels
    if name == "sensor_history":
        return _concat(frame * (size // sum(len(i) for i, _ in frame)))
    raise AsymmetricRobotError(f"observation entry {name!r}: no mirror image is defined")


def _concat(maps: list[Map]) -> Map:
    index, sign, start = [], [], 0
    for i, s in maps:
        index.append(i + start)
        sign.append(s)
        start += len(i)
    return np.concatenate(index), np.concatenate(sign).astype(np.float32)


def mirrors(spec: ControllerSpec) -> list[tuple[Map, Map]]:
    """For each non-trivial group element, its (observation, action) signed permutations."""
    out = []
    for name, signs in TWIST_SIGNS.items():
        wheels = wheel_map(spec.jacobian, signs, name)
        obs = _concat([_entry_map(e, s, signs, wheels, spec) for e, s in spec.layout])
        act = (np.arange(3), np.asarray(signs, np.float32)) if spec.twist_residual else wheels
        out.append((obs, act))
    return out


def symmetrize(
    spec: ControllerSpec, loc: Callable[[Any], Any], obs: Any, xp: Any, absolute: bool = False
) -> Any:
    """``¼ Σ_g g⁻¹·loc(g·obs)``: ``loc`` averaged over the mirror group (each element its
    own inverse); ``absolute``: the action signs dropped (a scale, not a direction)."""
    total = loc(obs)
    for (oi, os), (ai, asign) in mirrors(spec):
        out = xp.take(loc(xp.take(obs, oi, axis=-1) * xp.asarray(os)), ai, axis=-1)
        total = total + (out if absolute else out * xp.asarray(asign))
    return total / 4.0


__all__ = ["TWIST_SIGNS", "AsymmetricRobotError", "mirrors", "symmetrize", "wheel_map"]
