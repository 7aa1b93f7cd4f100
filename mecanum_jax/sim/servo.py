"""The wheels' speed servos, as on seed 004's robot: each wheel has a speed servo with a
torque limit.

The proportional part is MuJoCo's velocity actuator (``kv``), which the implicit
integrator treats implicitly, so stiff gains stay stable at a 2 ms step; the integral part
adds ``ki/kp · ∫(setpoint − ω) dt`` to the actuator's setpoint, with the integral clamped
so the I-term alone never exceeds the torque limit (anti-windup). Commands are wheel-rate
setpoints in rad/s, slewed at ``max_accel`` rad/s² when that is > 0
(:func:`servo_control`).

A saturated servo is integrated as a chord (:func:`chord_servo`), not as MJX's tangent,
which would add ``kp·dt`` to the wheel's inertia (docs/physics_model.md).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mecanum_jax.sim.state import RobotParams

if TYPE_CHECKING:
    from mujoco import mjx

ServoModel = Literal["chord", "mjx"]
"""How a saturated servo is integrated: ``"chord"`` (default, see :func:`chord_servo`) or
``"mjx"`` (MJX's own, with the spurious ``−kp·Δω``)."""

CHORD_WARP_RANGE = 2.0
"""Under ``warp``, the chord servo's actuators get this multiple of the torque limit as
their force range (see :meth:`mecanum_jax.sim.robot_model.RobotModel.model_for`)."""


def servo_control(
    setpoint: jax.Array,
    integral: jax.Array,
    command: jax.Array,
    rate: jax.Array,
    params: RobotParams,
    dt: float,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """One step of the servos' controllers: the setpoint slewed toward ``command``, the
    integrated rate error (clamped: anti-windup) and the actuators' control, each (n,)."""
    slew = params.max_accel * dt
    delta = command - setpoint
    setpoint = jnp.where(slew > 0, setpoint + jnp.clip(delta, -slew, slew), command)
    has_i = params.ki > 0
    bound = jnp.where(has_i, params.torque_limit / jnp.where(has_i, params.ki, 1.0), 0.0)
    integral = jnp.clip(integral + (setpoint - rate) * dt, -bound, bound)
    ctrl = setpoint + jnp.where(has_i, params.ki / params.kp, 0.0) * integral
    return setpoint, integral, ctrl


def chord_servo(
    model: mjx.Model,
    acts: jax.Array,
    error: jax.Array,
    params: RobotParams,
    dt: float,
    axle_inv_inertia: jax.Array,
) -> mjx.Model:
    """The servo for this step, linearised so that a saturated one stays at its limit.

    A velocity servo's torque is ``f(Δω) = clip(kp·(e − Δω), ±limit)`` for a rate error
    ``e`` and a change ``Δω`` over the step. The implicit integrator uses the tangent
    ``f(0) − kp·Δω``; MJX keeps that ``−kp·Δω`` even when ``f(0)`` is clamped (C MuJoCo
    drops it), so a saturated wheel spins up as if its inertia were ``I + kp·dt``,
    11-22x the hub's, while its contact still drives the chassis (docs/physics_model.md).

    Here a saturated servo gets the chord of ``f`` from ``Δω = 0`` to ``D``, the most its
    wheel can gain in one step (the limit torque on the free wheel, ``limit·dt/I``, at
    most ``e``): the force starts at exactly the limit, stays at it while the servo
    would stay saturated for the whole step (slope 0: a constant torque), and bends
    toward ``kp``'s line only when the step may reach the setpoint. ``f`` is concave on
    ``[0, e]``, so the chord lies under it: no step exceeds the limit or overshoots the
    setpoint. Unsaturated servos keep the tangent ``kp``. Written into the actuator's
    gain and bias (``force = g·ctrl + b₀ − g·ω``), so MJX integrates the slope
    implicitly.

    ``acts`` are the wheels' actuators, ``error`` their rate errors (n,), ``dt`` the
    physics step and ``axle_inv_inertia`` (n,) :func:`axle_inverse_inertia`.
    """
    limit, kp = params.torque_limit, params.kp
    mag = jnp.abs(error)
    saturated = kp * mag > limit
    reach = jnp.minimum(limit * dt * axle_inv_inertia, mag)
    reach = jnp.where(saturated, reach, 1.0)
    at_reach = jnp.minimum(limit, kp * jnp.maximum(mag - reach, 0.0))
    slope = (limit - at_reach) / reach
    gain = jnp.where(saturated, slope, kp)
    offset = jnp.where(saturated, jnp.sign(error) * limit - slope * error, 0.0)
    return model.replace(
        actuator_gainprm=model.actuator_gainprm.at[acts, 0].set(gain),
        actuator_biasprm=model.actuator_biasprm.at[acts, 0].set(offset).at[acts, 2].set(-gain),
    )


def axle_inverse_inertia(m: mujoco.MjModel, axle_dof: np.ndarray) -> np.ndarray:
    """``(M⁻¹)[a, a]`` per axle at the reset pose: how fast a torque spins the free wheel."""
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    inv = np.linalg.inv(full)
    return inv[axle_dof, axle_dof]


__all__ = [
    "CHORD_WARP_RANGE",
    "ServoModel",
    "axle_inverse_inertia",
    "chord_servo",
    "servo_control",
]
