"""The robot-side controller, written once for every array backend.

Each function takes the array namespace ``xp`` last: ``jax.numpy`` in the training
environment, ``numpy`` on the robot, and :mod:`mecanum_jax.deploy.onnx_xp`'s tracer, which
records the same code as an ONNX graph. They use only operations the three share (the
array API's elementwise functions, reductions, ``where``, ``concat``, ``take``, slices on
the trailing axes) and no matrix products, so no backend's matmul precision enters.

One control period, in the environment's order::

    obs = observe(spec, state, latency, xp)             # what the policy sees
    raw = network(obs)                                   # the policy's output in [-1, 1]
    setpoints, state = act(spec, state, raw, latency, xp) # to the servos
    ... the robot moves; the sensors read ``frame(...)`` ...
    state = sense(spec, state, frame, next_command, latency, xp)

``latency`` (control periods, 0 on a robot) picks which sensor frame is observed.
Depends on nothing but the namespace passed in (copied beside exports).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .spec import ControllerSpec
from .state import ControllerState

# --- small pieces ---------------------------------------------------------------------------


def rows(matrix: Any, x: Any, xp: Any) -> Any:
    """``matrix @ x`` row by row: x (..., k), a NumPy ``matrix`` (..., m, k) -> (..., m),
    as k products and a sum (no matmul, so no precision setting changes it).

    Not ``sum(x[..., None, :] * matrix, -1)``: XLA:CPU in jaxlib 0.10.2 fuses that
    reduction through YNNPACK and, for a (1000, 64, 3, 3) product plus an offset, returns
    values off by up to 20 (the flag ``--xla_cpu_experimental_ynn_fusion_type=`` avoids it
    too); tests/test_controller.py checks a 1000-row batch jitted against NumPy.
    """
    m = np.asarray(matrix, np.float32)
    lead = (None,) * (m.ndim - 1)
    out = x[(Ellipsis, 0, *lead)] * xp.asarray(m[..., 0])
    for j in range(1, m.shape[-1]):
        out = out + x[(Ellipsis, j, *lead)] * xp.asarray(m[..., j])
    return out


def soft_threshold(x: Any, d: float, xp: Any) -> Any:
    """``x`` shrunk towards 0 by ``d``."""
    return xp.sign(x) * xp.maximum(xp.abs(x) - d, 0.0)


def frame(spec: ControllerSpec, wheel_rate: Any, gyro_z: Any, accel: Any, xp: Any) -> Any:
    """One scaled sensor frame: encoder rates, gyro z, accelerometer and the
    wheel-odometry twist; ``gyro_z`` (..., 1)."""
    return xp.concat(
        [
            wheel_rate / xp.asarray(spec.max_rates),
            gyro_z / float(spec.command_scale[2]),
            accel / spec.gravity,
            rows(spec.forward_matrix, wheel_rate, xp) / xp.asarray(spec.command_scale),
        ],
        axis=-1,
    )


def observed_frame(state: ControllerState, latency: Any, xp: Any) -> Any:
    """The sensor frame observed now: ``latency`` periods old."""
    return xp.take(state.history, latency, axis=0)


def measured_yaw_rate(spec: ControllerSpec, state: ControllerState, latency: Any, xp: Any) -> Any:
    """The gyro's yaw rate as the controller sees it now, rad/s, shape (1,)."""
    gyro = observed_frame(state, latency, xp)[..., spec.sensor("gyro_z")]
    return gyro * float(spec.command_scale[2])


# --- the observation -------------------------------------------------------------------------


def observe(spec: ControllerSpec, state: ControllerState, latency: Any, xp: Any) -> Any:
    """The policy observation (``spec.layout``)."""
    scale = spec.command_scale
    parts = [
        state.command / xp.asarray(scale),
        observed_frame(state, latency, xp),
        state.last_action,
    ]
    if spec.yaw_integral_tau > 0:
        parts.append(state.yaw_integral[..., None] / (spec.yaw_integral_tau * float(scale[2])))
    if spec.feedback_base:
        parts.append(state.feedback_integral[..., None] / float(scale[2]))
    if spec.path_tau > 0:
        parts.append(state.path_error / xp.asarray(spec.path_tau * scale))
    if spec.obs_history > 0:
        past = xp.take(state.history, latency + 1 + xp.arange(spec.obs_history), axis=0)
        parts.append(xp.reshape(past, (-1,)))
    return xp.concat(parts, axis=-1)


# --- from the policy's output to the servos --------------------------------------------------


def shape_action(spec: ControllerSpec, raw: Any, command: Any, last_action: Any, xp: Any) -> Any:
    """The applied action for the network's output ``raw``: clipped to [-1, 1],
    soft-thresholded (``residual_deadband``), 0 at a stop command unless
    ``residual_at_stop``, low-passed with the last action (``action_filter``)."""
    action = xp.clip(raw, -1.0, 1.0)
    if spec.residual_deadband > 0:
        action = soft_threshold(action, spec.residual_deadband, xp)
    if not spec.residual_at_stop:
        stop = xp.all(command == 0.0, axis=-1, keepdims=True)
        action = xp.where(stop, 0.0, action)
    f = spec.action_filter
    if f > 0:
        action = f * last_action + (1.0 - f) * action
    return action


def ramp_in(spec: ControllerSpec, action: Any, command_age: Any, xp: Any) -> Any:
    """``action`` scaled by the ramp after a command change (``residual_ramp_s``): from
    1/T at the new command's first period to 1 after T s; ``command_age`` (..., 1)."""
    if spec.residual_ramp_s <= 0:
        return action
    per_period = spec.control_dt / spec.residual_ramp_s
    return action * xp.minimum(xp.astype(command_age + 1, xp.float32) * per_period, 1.0)


def feedback_twist(
    spec: ControllerSpec, command: Any, gyro_z: Any, integral: Any, gains: Any, xp: Any
) -> tuple[Any, Any]:
    """The ``feedback`` controller's PI-corrected twist (..., 3) and its yaw-rate error
    (..., 1); ``gyro_z`` and ``integral`` (..., 1), ``gains`` (..., 3): kp, ki, i_max."""
    err = command[..., 2:3] - gyro_z
    u = gains[..., 0:1] * err + integral
    if spec.feedback.deadband > 0:
        u = soft_threshold(u, spec.feedback.deadband, xp)
    return command + u * xp.asarray([0.0, 0.0, 1.0], dtype=xp.float32), err


def feedback_integral_step(
    spec: ControllerSpec,
    command: Any,
    gyro_z: Any,
    integral: Any,
    gains: Any,
    command_age: Any,
    xp: Any,
) -> Any:
    """The integrator after this period (..., 1): ``I + ki·e·dt`` clipped to ``± i_max``,
    held while the corrected twist is out of reach and the error would push it further,
    and while the command is younger than ``hold_steps`` (``command_age`` (..., 1))."""
    twist, err = feedback_twist(spec, command, gyro_z, integral, gains, xp)
    reach = xp.abs(rows(spec.jacobian, twist, xp)) / xp.asarray(spec.max_rates)
    saturated = xp.max(reach, axis=-1, keepdims=True) > 1.0
    u = twist[..., 2:3] - command[..., 2:3]
    hold = xp.logical_and(saturated, err * u > 0.0)
    if spec.feedback.hold_steps > 0:
        hold = xp.logical_or(hold, command_age < spec.feedback.hold_steps)
    i_max = gains[..., 2:3]
    grown = xp.clip(integral + gains[..., 1:2] * err * spec.control_dt, -i_max, i_max)
    return xp.where(hold, integral, grown)


def nearest_feasible(spec: ControllerSpec, twist: Any, xp: Any) -> Any:
    """The feasible twist nearest ``twist`` (..., 3) in the ``feedback`` metric."""
    m = spec.nearest
    d = xp.asarray(m.d)
    c = twist * d
    u = rows(m.P, c, xp) + xp.asarray(m.q)  # (..., K, 3): every candidate
    slack = (m.b + m.tol) - rows(m.Au, u, xp)
    feasible = xp.min(slack, axis=-1) >= 0.0
    diff = u - c[..., None, :]
    dist = xp.where(feasible, xp.sum(diff * diff, axis=-1), 1e30)  # finite: fast-math safe
    # the nearest candidate, picked by index (no float equality, which fusion can break)
    best = xp.argmin(dist, axis=-1)
    pick = xp.astype(xp.arange(len(m.q)) == best[..., None], twist.dtype)
    nearest = xp.sum(u * pick[..., None], axis=-2)
    inside = xp.min(xp.asarray(m.b) - rows(m.Au, c, xp), axis=-1, keepdims=True) >= 0.0
    return xp.where(inside, twist, nearest / d)


def baseline_rates(spec: ControllerSpec, command: Any, xp: Any) -> Any:
    """The analytic baseline: the nominal inverse model, scaled down uniformly until no
    wheel exceeds its rate limit."""
    rates = rows(spec.jacobian, command, xp)
    m = xp.asarray(spec.max_rates)
    excess = xp.max(xp.abs(rates) / m, axis=-1, keepdims=True)
    return rates / xp.maximum(excess, 1.0)


def feedback_rates(
    spec: ControllerSpec, command: Any, gyro_z: Any, integral: Any, gains: Any, xp: Any
) -> Any:
    """The ``feedback`` controller's wheel-rate setpoints."""
    twist, _ = feedback_twist(spec, command, gyro_z, integral, gains, xp)
    return rows(spec.jacobian, nearest_feasible(spec, twist, xp), xp)


def setpoints(
    spec: ControllerSpec,
    command: Any,
    action: Any,
    gyro_z: Any,
    integral: Any,
    gains: Any,
    xp: Any,
) -> Any:
    """Wheel-rate setpoints (rad/s) for an applied action: the base (analytic or
    ``feedback``) plus the correction, clipped to the rate limits."""
    m = xp.asarray(spec.max_rates)
    if not spec.residual:
        return xp.clip(action * m, -m, m)
    if spec.feedback_base:
        base = feedback_rates(spec, command, gyro_z, integral, gains, xp)
    else:
        base = baseline_rates(spec, command, xp)
    step = spec.residual_scale
    if spec.twist_residual:
        correction = rows(spec.jacobian, action * xp.asarray(step * spec.command_scale), xp)
    else:
        correction = action * xp.asarray(step * spec.max_rates)
    return xp.clip(base + correction, -m, m)


def gains(spec: ControllerSpec, xp: Any) -> Any:
    """The spec's ``(kp, ki, i_max)``."""
    fb = spec.feedback
    return xp.asarray([fb.kp, fb.ki, fb.i_max], dtype=xp.float32)


def act(
    spec: ControllerSpec, state: ControllerState, raw: Any, latency: Any, xp: Any
) -> tuple[Any, ControllerState]:
    """Setpoints for the network's output ``raw``, and the state after it (the action
    kept as the last action, the ``feedback`` integrator advanced)."""
    age = state.command_age[..., None]
    action = ramp_in(spec, shape_action(spec, raw, state.command, state.last_action, xp), age, xp)
    gyro = measured_yaw_rate(spec, state, latency, xp)
    integral = state.feedback_integral[..., None]
    rates = setpoints(spec, state.command, action, gyro, integral, state.feedback_gains, xp)
    if spec.feedback_base:
        integral = feedback_integral_step(
            spec, state.command, gyro, integral, state.feedback_gains, age, xp
        )
    return rates, state._replace(last_action=action, feedback_integral=integral[..., 0])


# --- from the sensors to the next observation ------------------------------------------------


def path_step(spec: ControllerSpec, error: Any, twist: Any, command: Any, xp: Any) -> Any:
    """The path error (x, y, heading) after a period that tracked ``command`` at the body
    twist ``twist`` (both (..., 3)), leaky with ``path_tau``: the position error in the
    commanded frame grows by the velocity error, rotated by the heading error, and turns
    with the commanded frame. ``path_integrator = "exact"`` turns it by the period's whole
    angle; ``"euler"`` (the shipped policy's) to first order, which lengthens the error by
    sqrt(1 + (ωz·dt)²) a period and outgrows the leak above ωz·dt ≈ 0.1 (5.8 rad/s at 50 Hz
    with τ = 3 s)."""
    dt = spec.control_dt
    ex, ey, eh = error[..., 0:1], error[..., 1:2], error[..., 2:3]
    c, s = xp.cos(eh), xp.sin(eh)
    vx, vy, wz = twist[..., 0:1], twist[..., 1:2], twist[..., 2:3]
    cx, cy, cz = command[..., 0:1], command[..., 1:2], command[..., 2:3]
    if spec.path_integrator == "exact":
        gx = ex + (c * vx - s * vy - cx) * dt
        gy = ey + (s * vx + c * vy - cy) * dt
        ct, st = xp.cos(cz * dt), xp.sin(cz * dt)
        turned = [ct * gx + st * gy, ct * gy - st * gx, eh + (wz - cz) * dt]
        return math.exp(-dt / spec.path_tau) * xp.concat(turned, axis=-1)
    grown = xp.concat(
        [
            ex + (c * vx - s * vy - cx + cz * ey) * dt,
            ey + (s * vx + c * vy - cy - cz * ex) * dt,
            eh + (wz - cz) * dt,
        ],
        axis=-1,
    )
    return math.exp(-dt / spec.path_tau) * grown


def sense(
    spec: ControllerSpec,
    state: ControllerState,
    new_frame: Any,
    command: Any,
    latency: Any,
    xp: Any,
) -> ControllerState:
    """The state after the period that ended: ``new_frame`` read at its end, ``command``
    the one to track next (a change restarts its age, and the ``feedback`` integrator
    where ``feedback.reset``)."""
    tracked = state.command
    changed = xp.any(command != tracked, axis=-1)
    age = xp.where(changed, 0, state.command_age + 1)
    integral = state.feedback_integral
    if spec.feedback.reset:
        integral = xp.where(changed, 0.0, integral)
    history = xp.concat([new_frame[None], state.history[:-1]], axis=0)
    out = state._replace(
        command=command,
        command_age=xp.astype(age, xp.int32),
        history=history,
        feedback_integral=integral,
    )
    now = observed_frame(out, latency, xp)
    gyro = now[..., spec.sensor("gyro_z")][..., 0] * float(spec.command_scale[2])
    if spec.yaw_integral_tau > 0:
        decay = math.exp(-spec.control_dt / spec.yaw_integral_tau)
        out = out._replace(
            yaw_integral=decay * state.yaw_integral + (tracked[..., 2] - gyro) * spec.control_dt
        )
    if spec.path_tau > 0:
        odometry = now[..., spec.sensor("odometry_twist")] * xp.asarray(spec.command_scale)
        measured = xp.concat([odometry[..., 0:2], gyro[..., None]], axis=-1)
        path = nearest_feasible(spec, tracked, xp) if spec.path_integrator == "exact" else tracked
        out = out._replace(path_error=path_step(spec, state.path_error, measured, path, xp))
    return out


def initial_state(
    spec: ControllerSpec, first_frame: Any, command: Any, frames: int, xp: Any
) -> ControllerState:
    """The state at a reset (the robot at rest): the history filled with the first frame,
    every integrator at 0, the last action 0."""
    zero = xp.zeros((), dtype=xp.float32)
    return ControllerState(
        command=command,
        command_age=xp.zeros((), dtype=xp.int32),
        last_action=xp.zeros((spec.action_size,), dtype=xp.float32),
        history=xp.broadcast_to(first_frame, (frames, first_frame.shape[-1])),
        yaw_integral=zero,
        feedback_integral=zero,
        feedback_gains=gains(spec, xp),
        path_error=xp.zeros((3,), dtype=xp.float32),
    )


__all__ = [
    "act",
    "baseline_rates",
    "feedback_integral_step",
    "feedback_rates",
    "feedback_twist",
    "frame",
    "gains",
    "initial_state",
    "measured_yaw_rate",
    "nearest_feasible",
    "observe",
    "observed_frame",
    "path_step",
    "rows",
    "sense",
    "setpoints",
    "shape_action",
    "soft_threshold",
]
