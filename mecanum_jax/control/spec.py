"""The controller's frozen description: :class:`ControllerSpec`.

Everything the robot-side controller needs to know, as plain Python numbers and NumPy
arrays: the observation layout, the residual (its space, base, scale, deadband and stop
rule), the action filter, the ``feedback`` controller's gains, the integrators the policy
observes, the limits and kinematics of the nominal robot, and the control period. It is
built from an export's metadata (:meth:`ControllerSpec.from_meta`), which the training
environment writes from its config (``mecanum_jax.task.controller``), so the environment
and every export read one and the same description.

This module depends on NumPy and the standard library only: it is copied beside exports.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
from typing import Any

import numpy as np

Layout = tuple[tuple[str, int], ...]


def sensor_layout(n_wheels: int) -> Layout:
    """One sensor frame's entries and sizes, in order: encoder rates, gyro z, accelerometer,
    wheel-odometry twist (:func:`mecanum_jax.control.step.frame`)."""
    return (("wheel_rate", n_wheels), ("gyro_z", 1), ("accel", 3), ("odometry_twist", 3))


def sensor_size(n_wheels: int) -> int:
    """One sensor frame's length."""
    return sum(size for _, size in sensor_layout(n_wheels))


def policy_layout(
    n_wheels: int,
    action_size: int,
    yaw_integral: bool,
    feedback_integral: bool = False,
    history: int = 0,
    path_error: bool = False,
) -> Layout:
    """The policy observation's entries and their sizes, in order; ``history`` earlier
    sensor frames come last."""
    layout: Layout = (
        ("command", 3),
        ("wheel_rate", n_wheels),
        ("gyro_z", 1),
        ("accel", 3),
        ("odometry_twist", 3),
        ("last_action", action_size),
    )
    if yaw_integral:
        layout = (*layout, ("yaw_error_integral", 1))
    if feedback_integral:
        layout = (*layout, ("feedback_integral", 1))
    if path_error:
        layout = (*layout, ("path_error", 3))
    if history > 0:
        layout = (*layout, ("sensor_history", history * sensor_size(n_wheels)))
    return layout


def entry_slice(layout: Layout, name: str) -> slice:
    """Where entry ``name`` lies in an observation vector of ``layout``."""
    start = 0
    for entry, size in layout:
        if entry == name:
            return slice(start, start + int(size))
        start += int(size)
    raise KeyError(f"observation entry {name!r} is not in the layout {[n for n, _ in layout]}")


@dataclasses.dataclass(frozen=True)
class FeedbackSpec:
    """The ``feedback`` controller (``mecanum_jax.task.references.FeedbackConfig``)."""

    kp: float = 0.0
    ki: float = 0.5
    i_max: float = 1.5
    omega_weight: float = 0.1
    hold_steps: int = 0
    reset: bool = False
    deadband: float = 0.0
    margin: float = 0.0


@dataclasses.dataclass(frozen=True, eq=False)
class ControllerSpec:
    """The robot-side controller, frozen (see the module's doc)."""

    layout: Layout
    action_size: int
    residual: bool
    residual_space: str
    residual_base: str
    residual_scale: float
    residual_deadband: float
    residual_ramp_s: float
    residual_at_stop: bool
    action_filter: float
    yaw_integral_tau: float
    path_tau: float
    obs_history: int
    control_dt: float
    gravity: float
    command_scale: np.ndarray
    max_rates: np.ndarray
    jacobian: np.ndarray
    forward_matrix: np.ndarray
    feedback: FeedbackSpec
    symmetric: bool = False
    path_integrator: str = "euler"

    @property
    def n_wheels(self) -> int:
        return int(self.max_rates.shape[0])

    @property
    def feedback_base(self) -> bool:
        """The residual corrects the ``feedback`` controller (not the analytic baseline)."""
        return self.residual and self.residual_base == "feedback"

    @property
    def twist_residual(self) -> bool:
        return self.residual and self.residual_space == "twist"

    @property
    def observation_size(self) -> int:
        return sum(int(s) for _, s in self.layout)

    def has(self, name: str) -> bool:
        return any(entry == name for entry, _ in self.layout)

    def entry(self, name: str) -> slice:
        return entry_slice(self.layout, name)

    def sensor(self, name: str) -> slice:
        """Where entry ``name`` lies in a sensor frame (:func:`sensor_layout`)."""
        return entry_slice(sensor_layout(self.n_wheels), name)

    @functools.cached_property
    def nearest(self) -> NearestMaps:
        """The feasible-twist projection of the ``feedback`` controller's metric."""
        limits = self.max_rates * np.float32(1.0 - self.feedback.margin)
        return NearestMaps.build(self.jacobian, limits, self.feedback.omega_weight)

    @classmethod
    def from_meta(cls, meta: dict[str, Any]) -> ControllerSpec:
        """The spec an export's metadata describes (older exports: their defaults)."""
        fb = dict(meta.get("feedback") or {})
        dt = float(meta["control_dt"])
        feedback = FeedbackSpec(
            kp=float(fb.get("kp", 0.0)),
            ki=float(fb.get("ki", 0.5)),
            i_max=float(fb.get("i_max", 1.5)),
            omega_weight=float(fb.get("omega_weight", 0.1)),
            hold_steps=round(float(fb.get("hold_s") or 0.0) / dt),
            reset=bool(fb.get("reset") or False),
            deadband=float(fb.get("deadband") or 0.0),
            margin=float(fb.get("margin") or 0.0),
        )
        f32 = functools.partial(np.asarray, dtype=np.float32)
        return cls(
            layout=tuple((str(n), int(s)) for n, s in meta["observation_layout"]),
            action_size=int(meta["action_size"]),
            residual=bool(meta["residual"]),
            residual_space=str(meta.get("residual_space", "wheel")),
            residual_base=str(meta.get("residual_base", "analytic")),
            residual_scale=float(meta["residual_scale"]),
            residual_deadband=float(meta.get("residual_deadband") or 0.0),
            residual_ramp_s=float(meta.get("residual_ramp_s") or 0.0),
            residual_at_stop=bool(meta.get("residual_at_stop", True)),
            action_filter=float(meta.get("action_filter") or 0.0),
            yaw_integral_tau=float(meta.get("yaw_integral_tau") or 0.0),
            path_tau=float(meta.get("path_tau") or 0.0),
            obs_history=int(meta.get("obs_history") or 0),
            control_dt=dt,
            gravity=float(meta["gravity"]),
            command_scale=f32(meta["command_scale"]),
            max_rates=f32(meta["max_rates"]),
            jacobian=f32(meta["jacobian"]),
            forward_matrix=f32(meta["forward_matrix"]),
            feedback=feedback,
            symmetric=bool(meta.get("symmetric") or False),
            path_integrator=str(meta.get("path_integrator") or "euler"),
        )


@dataclasses.dataclass(frozen=True, eq=False)
class NearestMaps:
    """The feasible twist nearest a twist, ``argmin (vx−cx)² + (vy−cy)² + w·(ωz−cz)²``
    over ``|J t| <= m``, as precomputed affine maps.

    The nearest point lies on a facet, an edge or a vertex of the polytope; the orthogonal
    projection onto each set of 1-3 active half-spaces is an affine map ``u = P c + q`` of
    the weighted twist ``c = d·t`` (92 maps for 4 wheels). A twist is mapped by all of them
    and the nearest feasible result kept; a feasible twist passes unchanged.
    """

    P: np.ndarray  # (K, 3, 3)
    q: np.ndarray  # (K, 3)
    Au: np.ndarray  # (2n, 3): the half-spaces in weighted coordinates
    b: np.ndarray  # (2n,)
    d: np.ndarray  # (3,): the metric's weights
    tol: float

    @classmethod
    def build(cls, jacobian: np.ndarray, max_rates: np.ndarray, weight: float) -> NearestMaps:
        J = np.asarray(jacobian, np.float64)
        A = np.stack([J, -J], axis=1).reshape(-1, 3)
        b = np.repeat(np.asarray(max_rates, np.float64), 2)
        d = np.asarray([1.0, 1.0, np.sqrt(weight)])
        Au = A / d
        maps, offsets = [], []
        for k in (1, 2, 3):
            for rows in itertools.combinations(range(len(A)), k):
                As, bs = Au[list(rows)], b[list(rows)]
                G = As @ As.T
                if abs(np.linalg.det(G)) <= 1e-8 * np.prod(np.sum(As * As, axis=1)):
                    continue  # rows dependent: no edge or vertex there
                Ginv = np.linalg.inv(G)
                maps.append(np.eye(3) - As.T @ Ginv @ As)
                offsets.append(As.T @ Ginv @ bs)
        f32 = functools.partial(np.asarray, dtype=np.float32)
        tol = 1e-5 * float(np.max(b))
        return cls(f32(maps), f32(offsets), f32(Au), f32(b), f32(d), tol)


__all__ = [
    "ControllerSpec",
    "FeedbackSpec",
    "Layout",
    "NearestMaps",
    "entry_slice",
    "policy_layout",
    "sensor_layout",
    "sensor_size",
]
