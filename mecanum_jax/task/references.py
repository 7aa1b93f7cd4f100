"""The reference controllers a learned policy is judged against (:data:`REFERENCES`).

- ``analytic``: the nominal inverse model, desaturated uniformly to the rate limits: the
  baseline the product is judged against;
- ``analytic_nearest``: the same with the nearest feasible twist instead;
- ``feedback``: inverse-model feedforward with a yaw-rate PI loop on the gyro and
  nearest-feasible desaturation onto (1 − margin) of the rate limits (:class:`FeedbackConfig`).

:func:`baseline_policy` puts ``analytic`` behind a learned policy's interface.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp

from mecanum_jax.config import require
from mecanum_jax.control import ControllerSpec
from mecanum_jax.control import step as ctl
from mecanum_jax.kinematics import limits
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.task.constants import RobotConstants
from mecanum_jax.task.controller import TaskInfo, allow_rank_promotion, control_state
from mecanum_jax.task.observations import command_from_obs

Policy = Callable[[dict[str, jax.Array], jax.Array], tuple[jax.Array, dict[str, jax.Array]]]


@dataclasses.dataclass(frozen=True)
class FeedbackConfig:
    """The feedback reference controller: inverse-model feedforward, a yaw-rate PI loop
    on the (noisy, delayed) gyro, and nearest-feasible desaturation.

    Yaw-rate correction u = kp·e + I with e = ωz_cmd − gyro and
    I ← clip(I + ki·e·dt, ±i_max); the integrator holds while the corrected twist is out
    of the wheels' reach (their rate limits themselves, not less the margin: judged
    against the shrunk limits no tuning figure moved by 0.5%) and e would drive it
    further (conditional-integration anti-windup), and, with hold_s > 0, for hold_s after
    each command change, while the servos' transient, not a steady bias, makes the error.
    With reset it restarts at 0 at each command change. The gains come from a sweep on
    training-distribution episodes (docs/evaluation.md): any proportional gain (even 0.02)
    raised the steady-state ωz error there, since the servos' own step response overshoots
    within one control step and the gyro arrives noisy and up to 2 steps late; integral
    gains above about 0.8/s oscillate.
    """

    kp: float = 0.0
    """Proportional gain, rad/s of yaw-rate correction per rad/s of error (>= 0)."""
    ki: float = 0.5
    """Integral gain, 1/s (>= 0)."""
    i_max: float = 1.5
    """Integrator clamp, rad/s (>= 0)."""
    omega_weight: float = 0.1
    """Nearest-feasible metric: (m/s)² per (rad/s)² of yaw-rate error (> 0)."""
    margin: float = 0.05
    """Headroom of the desaturation: the twist is projected onto the twists the wheels
    reach at (1 − margin) of their rate limits (0 <= margin < 1; 0: the limits). A target
    on the limits leaves the servos none to hold it with (docs/evaluation.md: at 0.05 it
    wins 10 tuning figures over the limits themselves and loses none)."""
    hold_s: float = 0.4
    """The integrator holds for this long after each command change, s (>= 0, whole control
    periods; 0: it integrates through the transient)."""
    reset: bool = True
    """The integrator restarts at 0 at each command change: it estimates the bias of the
    command it tracks, and a slippery floor's yaw deficit belongs to that command. Carried
    into the next one, it pushes a new spin or a stop the wrong way for seconds, bleeding
    off at ki (docs/evaluation.md, the settling of ωz on slippery floors)."""
    deadband: float = 0.02
    """The correction shrinks by this much towards 0, rad/s (>= 0; 0: none). The integrator
    grows through it, so a steady bias is still corrected in full, but the gyro noise's
    corrections of a few mrad/s vanish and a nominal robot's wheels get exactly
    analytic's setpoints: any asymmetry in them, however small, changes how a robot
    stopped from speed slides, and so how far the next command's start turns it
    (docs/evaluation.md, six_modes drift)."""

    def validate(self, where: str = "env.feedback") -> None:
        """Check values; raise :class:`ConfigError` naming the field."""
        fields = ("kp", "ki", "i_max", "hold_s", "deadband")
        require(self, where, fields, lambda v: v >= 0, "must be >= 0")
        require(self, where, ("omega_weight",), lambda v: v > 0, "must be > 0")
        require(self, where, ("margin",), lambda v: 0 <= v < 1, "must be in [0, 1)")
        require(self, where, ("reset",), lambda v: isinstance(v, bool), "must be true or false")

    def hold_steps(self, control_dt: float) -> int:
        """``hold_s`` in whole control periods of ``control_dt`` s."""
        return round(self.hold_s / control_dt)

    def gains(self) -> jax.Array:
        """``(kp, ki, i_max)`` as the array the state carries in ``info["feedback_gains"]``
        (so that a gain sweep compiles once)."""
        return jnp.asarray([self.kp, self.ki, self.i_max], jnp.float32)


def baseline_rates(robot: RobotConstants, command: jax.Array) -> jax.Array:
    """The analytic baseline: the nominal inverse model, desaturated to the rate limits."""
    twist, _ = limits.desaturate(robot.geometry, command, robot.max_rates)
    return kinematics.apply_rows(robot.jacobian, twist)


def nearest_rates(robot: RobotConstants, twist: jax.Array, omega_weight: float) -> jax.Array:
    """Wheel rates of the feasible twist nearest ``twist`` (nominal geometry; the metric's
    (m/s)² per (rad/s)², :attr:`FeedbackConfig.omega_weight`)."""
    feasible = limits.nearest_feasible(robot.geometry, twist, robot.max_rates, omega_weight)
    return kinematics.apply_rows(robot.jacobian, feasible)


def feasible_target(
    robot: RobotConstants, command: jax.Array, radius_scale: jax.Array, omega_weight: float
) -> jax.Array:
    """The nearest feasible twist to ``command`` (..., 3) for the robot as it really is
    (wheel radii scaled by ``radius_scale`` (n,), the rate limits), in the reference
    controllers' metric (``omega_weight``): the target of the steady-state error."""
    geom = robot.geometry.replace(radii=robot.geometry.radii * radius_scale)
    return limits.nearest_feasible(geom, command, robot.max_rates, omega_weight)


@allow_rank_promotion
def feedback_rates(spec: ControllerSpec, info: TaskInfo) -> jax.Array:
    """The ``feedback`` reference's wheel-rate setpoints for the state's ``info`` (the
    robot-side controller's, :func:`mecanum_jax.control.step.feedback_rates`)."""
    s = control_state(info)
    gyro = ctl.measured_yaw_rate(spec, s, info["latency"], jnp)
    integral = s.feedback_integral[..., None]
    return ctl.feedback_rates(spec, s.command, gyro, integral, s.feedback_gains, jnp)


def reference_rates(
    robot: RobotConstants,
    reference: int | jax.Array,
    info: TaskInfo,
    fb: FeedbackConfig,
    spec: ControllerSpec,
) -> jax.Array:
    """Wheel-rate setpoints of reference controller ``reference`` (an index into
    :data:`REFERENCES`; a Python int computes only that one) for the state's ``info``
    (``fb``: the feedback controller's settings; ``spec``: the controller it runs as)."""
    candidates = [
        functools.partial(rates, robot, info, fb, spec) for rates in REFERENCE_RATES.values()
    ]
    if isinstance(reference, int):
        return candidates[reference]()
    index = jnp.clip(jnp.asarray(reference), 0, len(candidates) - 1)
    return jnp.select([index == i for i in range(len(candidates))], [c() for c in candidates])


RatesOf = Callable[[RobotConstants, TaskInfo, FeedbackConfig, ControllerSpec], jax.Array]

REFERENCE_RATES: dict[str, RatesOf] = {
    "analytic": lambda robot, info, fb, spec: baseline_rates(robot, info["command"]),
    "analytic_nearest": lambda robot, info, fb, spec: nearest_rates(
        robot, info["command"], fb.omega_weight
    ),
    "feedback": lambda robot, info, fb, spec: feedback_rates(spec, info),
}
"""The reference controllers, one entry each, in their index order: the analytic inverse
model with uniform desaturation (the baseline), the same with nearest-feasible
desaturation, and :class:`FeedbackConfig`'s closed loop; each gives its wheel-rate
setpoints for a state's ``info``."""

REFERENCES = tuple(REFERENCE_RATES)
"""The reference controllers' names, by index (:data:`REFERENCE_RATES`)."""


def baseline_policy(robot: RobotConstants, residual: bool, action_size: int) -> Policy:
    """The analytic baseline behind the learned-policy interface ``(obs, key) -> (action, {})``.

    With ``residual`` actions (``action_size`` of them) it is the zero residual; otherwise it
    outputs the desaturated nominal inverse model's wheel rates divided by the rate limits.
    """

    def policy(obs: dict[str, jax.Array], key: jax.Array) -> tuple[jax.Array, dict[str, jax.Array]]:
        del key
        command = command_from_obs(robot, obs)
        if residual:
            return jnp.zeros((*command.shape[:-1], action_size)), {}
        rates = baseline_rates(robot, command)
        return rates / robot.max_rates.reshape((1,) * (rates.ndim - 1) + (-1,)), {}

    return policy


__all__ = [
    "REFERENCES",
    "REFERENCE_RATES",
    "FeedbackConfig",
    "Policy",
    "baseline_policy",
    "baseline_rates",
    "feasible_target",
    "feedback_rates",
    "nearest_rates",
    "reference_rates",
]
