"""Seed 000 §4: the mecanum platform's velocity space and efficiency against the other drives.

Every drive gets the same wheels and the same wheel-rate limit (``max_rate``, from one
robot's motors), and is measured on the same three sets:

- ``area_v_wz``: the area of its feasible ``(vx, ωz)`` set at ``vy = 0``, (m/s)·(rad/s):
  what a differential drive can do at all;
- ``area_vx_vy``: the area of its feasible ``(vx, vy)`` set at ``ωz = 0``, (m/s)²;
- ``volume``: the volume of its feasible ``(vx, vy, ωz)`` set, (m/s)²·(rad/s); zero for
  every drive whose set is flat.

The areas integrate the set's radius over directions (every set here is star-shaped about
the origin), ``½∮ρ(θ)² dθ`` (a polygon through 3600 boundary points); the mecanum volume
is its polytope's convex hull. Also the largest speed along x, y, ωz and the x = y
diagonal (its norm), and seed 000 §4.2's efficiency: the net force per unit of summed
wheel force, ``|Σ F_i| / Σ |F_i|``, for the least-norm wheel forces (each wheel pushes
only along its rolling direction, a mecanum wheel along its roller axis) that push the
robot forward, or sideways, without a moment.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path
from typing import TYPE_CHECKING, TypeAlias

import jax.numpy as jnp
import numpy as np

from mecanum_jax.kinematics import drive_description, drive_geometry, drives, efficiency, limits
from mecanum_jax.sim.description import RobotDescription, resolve_description

if TYPE_CHECKING:
    from collections.abc import Callable

    import jax

    from mecanum_jax.kinematics.geometry import WheelGeometry

Speed: TypeAlias = "Callable[[jax.Array], jax.Array]"
"""A feasible set's radius: ``speed(directions (N, 3)) -> (N,)``."""

N_DIRECTIONS = 3600


@dataclasses.dataclass(frozen=True)
class Space:
    """One drive's velocity space and efficiency (see the module docstring)."""

    name: str
    drive: str
    max_vx: float
    max_vy: float
    max_wz: float
    max_diagonal: float
    area_v_wz: float
    area_vx_vy: float
    volume: float
    force_efficiency_forward: float
    force_efficiency_sideways: float


def _area(radius: jax.typing.ArrayLike) -> float:
    """The area inside the radius ρ (N,) at :data:`N_DIRECTIONS` evenly spaced angles: the
    shoelace sum ``½ Σ ρ_i ρ_(i+1) sin Δθ`` (→ ``½∮ρ² dθ``; 0 for a segment)."""
    rho = np.asarray(radius, float)
    return float(0.5 * np.sum(rho * np.roll(rho, -1)) * math.sin(2 * math.pi / len(rho)))


def _plane(axes: tuple[int, int]) -> np.ndarray:
    """Unit twists (N, 3) around the circle in the plane of two twist axes."""
    theta = np.linspace(0.0, 2 * math.pi, N_DIRECTIONS, endpoint=False)
    d = np.zeros((N_DIRECTIONS, 3))
    d[:, axes[0]], d[:, axes[1]] = np.cos(theta), np.sin(theta)
    return d


def boundary(speed: Speed, axes: tuple[int, int]) -> np.ndarray:
    """The set's boundary (N, 2) in the plane of ``axes``, from ``speed(directions)``."""
    d = _plane(axes)
    rho = np.asarray(speed(jnp.asarray(d)), float)
    return d[:, list(axes)] * rho[:, None]


def _force_efficiency(directions: np.ndarray, positions: np.ndarray, heading: float) -> float:
    """|ΣF| / Σ|F| of the least-norm forces ``f_i`` along ``directions`` (k, 2) at
    ``positions`` (k, 2) giving a pure force along ``heading``; 0 if none can."""
    u, p = directions, positions
    G = np.stack([u[:, 0], u[:, 1], p[:, 0] * u[:, 1] - p[:, 1] * u[:, 0]])
    want = np.array([math.cos(heading), math.sin(heading), 0.0])
    f = np.linalg.lstsq(G, want, rcond=None)[0]
    if np.linalg.norm(G @ f - want) > 1e-6 or not np.any(f):
        return 0.0
    return float(np.linalg.norm(G[:2] @ f) / np.sum(np.abs(f)))


def _drive_wheels(g: drive_geometry.Drive, heading: float) -> tuple[np.ndarray, np.ndarray]:
    """Driven wheels' rolling directions and positions for a translation along ``heading``
    (steered wheels turned to it where the drive can)."""
    straight = np.array([[1.0, 0.0]])
    if isinstance(g, drive_geometry.Differential):
        half = float(g.track) / 2
        return np.repeat(straight, 2, 0), np.array([[0.0, half], [0.0, -half]])
    if isinstance(g, drive_geometry.Ackermann):
        half = float(g.track) / 2
        return np.repeat(straight, 2, 0), np.array([[0.0, half], [0.0, -half]])
    if isinstance(g, drive_geometry.Tricycle):
        return straight, np.array([[float(g.wheelbase), 0.0]])
    # synchronous: three wheels at a triangle's corners, all turned to the heading
    corners = np.array([[math.cos(a), math.sin(a)] for a in (0.0, 2.1, 4.2)]) * 0.1
    turned = np.repeat([[math.cos(heading), math.sin(heading)]], 3, 0)
    return turned, corners


def _space(name: str, drive: str, speed: Speed, volume: float, eff: list[float]) -> Space:
    """A :class:`Space` from ``speed(directions (N, 3)) -> (N,)``, the set's radius."""
    tops = [float(x) for x in speed(jnp.asarray(np.eye(3)))]
    return Space(
        name=name,
        drive=drive,
        max_vx=tops[0],
        max_vy=tops[1],
        max_wz=tops[2],
        max_diagonal=float(speed(jnp.asarray([[1.0, 1.0, 0.0]]))[0]),
        area_v_wz=_area(speed(jnp.asarray(_plane((0, 2))))),
        area_vx_vy=_area(speed(jnp.asarray(_plane((0, 1))))),
        volume=volume,
        force_efficiency_forward=eff[0],
        force_efficiency_sideways=eff[1],
    )


def _mecanum_speed(desc: RobotDescription) -> tuple[WheelGeometry, jax.Array, Speed]:
    """A mecanum robot's float64 geometry, its wheel-rate limits, and its feasible set's
    radius ``speed(directions (N, 3)) -> (N,)``."""
    g = desc.build_geometry(jnp.float64)
    rates = desc.max_wheel_rates(g)
    return g, rates, functools.partial(limits.max_speed, g, max_rates=rates)


def _drive_speed(
    desc: drive_description.DriveDescription, max_rate: float
) -> tuple[drive_geometry.Drive, Speed]:
    """A drive's float64 geometry, and its feasible set's radius at ``max_rate`` (rad/s)."""
    g = desc.build(jnp.float64)
    return g, functools.partial(drives.max_speed, g, max_rate=max_rate)


def _load(
    mecanum: str, others: tuple[str, ...]
) -> tuple[RobotDescription, list[drive_description.DriveDescription], float]:
    """The robots compared, and the wheel-rate limit they all share: the mecanum's."""
    desc = resolve_description(mecanum)
    g = desc.build_geometry(jnp.float64)
    max_rate = float(np.min(np.asarray(desc.max_wheel_rates(g))))
    return desc, [drive_description.load_drive(name) for name in others], max_rate


def drive_space(desc: drive_description.DriveDescription, max_rate: float) -> Space:
    """A drive's space at the wheel-rate limit ``max_rate`` (rad/s)."""
    g, speed = _drive_speed(desc, max_rate)
    eff = [_force_efficiency(*_drive_wheels(g, h), h) for h in (0.0, math.pi / 2)]
    return _space(desc.robot.name, desc.robot.drive, speed, 0.0, eff)


def mecanum_space(desc: RobotDescription) -> Space:
    """A mecanum robot's space at its own wheel-rate limits."""
    from scipy.spatial import ConvexHull

    g, rates, speed = _mecanum_speed(desc)
    vertices = limits.feasible_vertices(g, rates)
    volume = float(ConvexHull(vertices).volume) if len(vertices) >= 4 else 0.0
    eff = efficiency.efficiency(g, jnp.asarray([0.0, math.pi / 2])).force_efficiency
    return _space(desc.robot.name, "mecanum", speed, volume, [float(x) for x in eff])


def compare(
    mecanum: str = "o_rectangle", others: tuple[str, ...] = drive_geometry.DRIVES
) -> tuple[list[Space], float]:
    """The mecanum robot's space and each other drive's at its wheel-rate limit:
    ``(spaces, max_rate)``; the drives' own motor limits are replaced by the mecanum's."""
    desc, other_descs, max_rate = _load(mecanum, others)
    spaces = [mecanum_space(desc)] + [drive_space(d, max_rate) for d in other_descs]
    return spaces, max_rate


def plot(mecanum: str, others: tuple[str, ...], out: Path) -> Path:
    """The mecanum polytope in 3-D beside the (vx, ωz) and (vx, vy) sets of every drive."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    from scipy.spatial import ConvexHull

    desc, other_descs, max_rate = _load(mecanum, others)
    g, rates, speed = _mecanum_speed(desc)
    sets: dict[str, Speed] = {desc.robot.name: speed}
    for other in other_descs:
        sets[other.robot.name] = _drive_speed(other, max_rate)[1]
    fig = plt.figure(figsize=(15, 5))
    ax3 = fig.add_subplot(1, 3, 1, projection="3d")
    vertices = limits.feasible_vertices(g, rates)
    hull = ConvexHull(vertices)
    ax3.add_collection3d(
        Poly3DCollection(vertices[hull.simplices], alpha=0.25, facecolor="tab:blue", lw=0.2)
    )
    span = np.abs(vertices).max(axis=0)
    ax3.set(xlim=(-span[0], span[0]), ylim=(-span[1], span[1]), zlim=(-span[2], span[2]))
    ax3.set(xlabel="vx (m/s)", ylabel="vy (m/s)", zlabel="ωz (rad/s)")
    ax3.set_title(f"{desc.robot.name}: feasible (vx, vy, ωz)")
    for k, (name, speed) in enumerate(sets.items()):
        colour = f"C{k}"
        for panel, axes in ((2, (0, 2)), (3, (0, 1))):
            ax = fig.add_subplot(1, 3, panel) if k == 0 else fig.axes[panel - 1]
            pts = boundary(speed, axes)
            if np.ptp(pts[:, 0]) > 0 or np.ptp(pts[:, 1]) > 0:
                ax.plot(*np.vstack([pts, pts[:1]]).T, color=colour, label=name)
            if axes == (0, 2) and name != desc.robot.name:
                ax3.plot(pts[:, 0], np.zeros(len(pts)), pts[:, 1], color=colour, lw=1)
    for ax, title, ylabel in (
        (fig.axes[1], "vy = 0: (vx, ωz)", "ωz (rad/s)"),
        (fig.axes[2], "ωz = 0: (vx, vy)", "vy (m/s)"),
    ):
        ax.set(title=title, xlabel="vx (m/s)", ylabel=ylabel)
        ax.axhline(0, color="0.8", lw=0.5)
        ax.axvline(0, color="0.8", lw=0.5)
        ax.legend(fontsize=8)
    fig.suptitle(f"Velocity spaces at equal wheel-rate limits ({max_rate:.1f} rad/s)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


__all__ = ["Space", "boundary", "compare", "drive_space", "mecanum_space", "plot"]
