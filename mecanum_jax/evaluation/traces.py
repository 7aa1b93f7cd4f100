"""A rollout's record (:class:`Trace`) and its figures: poses in the start frame, the path
the commands describe, and the report's metrics, pooled or per episode.

:func:`summarize` turns a :class:`Trace` into the report's metrics
(:mod:`mecanum_jax.evaluation.metrics` defines them and their paired comparison):

- ``rmse_vx``, ``rmse_vy`` (m/s), ``rmse_wz`` (rad/s), ``rmse_lin`` (of the velocity
  vector), over every control step of every episode, against the command in force;
  ``worst_rmse_lin`` and ``worst_rmse_wz``: the same over the worst single episode;
- ``ss_*``: steady-state error against the nearest feasible twist of the true robot;
  ``settle_lin_s``, ``settle_wz_s``: settling time after command steps;
- for scripted (fixed-sequence) scenarios, the final pose error against the path the
  commands describe — ``drift_m`` and ``heading_drift_rad`` (mean over episodes); on a
  closed sequence that is the distance from the start;
- ``energy_j``: Σ|τ·ω|·dt per episode (mean over episodes); ``energy_per_m`` per metre
  travelled; ``null_energy_j`` the part of it in the wheels' null space;
- ``saturated``: the fraction of wheel-steps with the torque at its limit;
- ``unstable``: physics resets (should be 0).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Generic, NamedTuple, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.evaluation import metrics
from mecanum_jax.kinematics import odometry

if TYPE_CHECKING:
    import numpy.typing as npt

A = TypeVar("A", np.ndarray, jax.Array)
"""A :class:`Trace`'s arrays: NumPy on the host, JAX in the rollout program."""
METRICS = (
    "rmse_vx",
    "rmse_vy",
    "rmse_wz",
    "rmse_lin",
    "ss_vx",
    "ss_vy",
    "ss_wz",
    "ss_lin",
    "settle_lin_s",
    "settle_wz_s",
    "worst_rmse_lin",
    "worst_rmse_wz",
    "drift_m",
    "heading_drift_rad",
    "energy_j",
    "energy_per_m",
    "null_energy_j",
    "saturated",
    "unstable",
)


class Trace(NamedTuple, Generic[A]):
    """A rollout, per episode and control step (leading axes E, T); numpy on the host."""

    command: A  # (E, T, 3) command in force during the step
    target: A  # (E, T, 3) the command's nearest feasible twist for the true robot
    twist: A  # (E, T, 3) true body twist at the end of the step
    pose: A  # (E, T, 3) world pose (x, y, yaw) at the end of the step
    start: A  # (E, 3) pose before the first step
    energy_j: A  # (E, T)
    saturated: A  # (E, T)
    unstable: A  # (E, T)
    wheel_torque: A  # (E, T, n) N·m
    wheel_rate: A  # (E, T, n) rad/s
    qpos: A  # (E, T, nq), for rendering
    action: A | None = None  # (E, T, a) the action applied (after the filter); 0 for references


def relative_poses(trace: Trace[np.ndarray]) -> np.ndarray:
    """Poses (E, T, 3) in each episode's start frame (x forward, y left, yaw from start)."""
    start = trace.start[:, None, :]
    d = trace.pose[..., :2] - start[..., :2]
    c, s = np.cos(start[..., 2]), np.sin(start[..., 2])
    x = c * d[..., 0] + s * d[..., 1]
    y = -s * d[..., 0] + c * d[..., 1]
    yaw = _wrap(trace.pose[..., 2] - start[..., 2])
    return np.stack([x, y, yaw], axis=-1)


def intended_poses(commands: np.ndarray, dt: float) -> np.ndarray:
    """The path (E, T, 3) that the commands (E, T, 3) describe from the start, exactly on SE(2)."""
    path = odometry.integrate_twists(
        jnp.zeros((commands.shape[0], 3)), jnp.swapaxes(jnp.asarray(commands), 0, 1), dt
    )
    return np.swapaxes(np.asarray(path), 0, 1)


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def trace_parts(
    trace: Trace[np.ndarray],
    jacobian: npt.ArrayLike,
    dt: float,
    cfg: metrics.MetricConfig | None = None,
) -> dict[str, metrics.Part]:
    """The per-episode metrics of a rollout (:func:`.metrics.episode_parts`), and the
    flicker of its actions where it has them (:func:`.metrics.flicker_part`)."""
    parts = metrics.episode_parts(
        trace.command,
        trace.target,
        trace.twist,
        trace.pose,
        trace.start,
        trace.energy_j,
        trace.saturated,
        trace.wheel_torque,
        trace.wheel_rate,
        np.asarray(jacobian),
        dt,
        cfg,
    )
    if trace.action is not None:
        parts["flicker"] = metrics.flicker_part(np.asarray(trace.action))
    return parts


def summarize(
    trace: Trace[np.ndarray],
    dt: float,
    scripted: bool,
    jacobian: npt.ArrayLike,
    cfg: metrics.MetricConfig | None = None,
    parts: dict[str, metrics.Part] | None = None,
) -> dict[str, float | None]:
    """The report's metrics of one rollout (see the module docstring); ``parts``: its
    :func:`trace_parts` if already computed."""
    err = trace.twist - trace.command
    parts = trace_parts(trace, jacobian, dt, cfg) if parts is None else parts
    out: dict[str, float | None] = metrics.summary(parts)
    out |= {
        "worst_rmse_lin": float(np.max(np.sqrt(np.mean(err[..., 0] ** 2 + err[..., 1] ** 2, 1)))),
        "worst_rmse_wz": float(np.max(np.sqrt(np.mean(err[..., 2] ** 2, axis=1)))),
        "drift_m": None,
        "heading_drift_rad": None,
        "unstable": float(np.sum(trace.unstable > 0)),
    }
    if scripted:
        final = relative_poses(trace)[:, -1]
        goal = intended_poses(trace.command, dt)[:, -1]
        out["drift_m"] = float(np.mean(np.linalg.norm(final[:, :2] - goal[:, :2], axis=-1)))
        out["heading_drift_rad"] = float(np.mean(np.abs(_wrap(final[:, 2] - goal[:, 2]))))
    return out


def drift_parts(trace: Trace[np.ndarray], dt: float) -> dict[str, metrics.Part]:
    """Final position and heading drift of a scripted rollout, per episode."""
    final = relative_poses(trace)[:, -1]
    goal = intended_poses(trace.command, dt)[:, -1]
    ones = np.ones(len(final))
    return {
        "drift_m": metrics.Part(np.linalg.norm(final[:, :2] - goal[:, :2], axis=-1), ones, "mean"),
        "heading_drift_rad": metrics.Part(np.abs(_wrap(final[:, 2] - goal[:, 2])), ones, "mean"),
    }


def per_episode(
    trace: Trace[np.ndarray], dt: float, scripted: bool, cfg: metrics.MetricConfig | None = None
) -> dict[str, list[float | None]]:
    """Per-episode RMSE of v and ωz, steady-state error of v and ωz (``None`` for an episode
    without steady steps) and its count of steady steps (the summary's ``ss_*`` pool them,
    weighted by that count), and the final drift of scripted scenarios: for scripts that
    look for the episodes where a policy fails, or where two devices differ."""
    err = trace.twist - trace.command
    parts = metrics.tracking_parts(
        trace.command, trace.target, trace.twist, dt, cfg or metrics.MetricConfig()
    )
    count = parts["ss_lin"].den

    def steady(name: str) -> list[float | None]:
        num = parts[name].num
        return [float(np.sqrt(n / c)) if c > 0 else None for n, c in zip(num, count, strict=True)]

    out: dict[str, list[float | None]] = {
        "rmse_lin": np.sqrt(np.mean(err[..., 0] ** 2 + err[..., 1] ** 2, axis=1)).tolist(),
        "rmse_wz": np.sqrt(np.mean(err[..., 2] ** 2, axis=1)).tolist(),
        "ss_lin": steady("ss_lin"),
        "ss_wz": steady("ss_wz"),
        "steady_steps": [float(c) for c in count],
    }
    if scripted:
        final = relative_poses(trace)[:, -1]
        goal = intended_poses(trace.command, dt)[:, -1]
        out["drift_m"] = np.linalg.norm(final[:, :2] - goal[:, :2], axis=-1).tolist()
    return out


__all__ = [
    "METRICS",
    "Trace",
    "drift_parts",
    "intended_poses",
    "per_episode",
    "relative_poses",
    "summarize",
    "trace_parts",
]
