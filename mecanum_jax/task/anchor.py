"""Where the residual's base controller is already exact: the states and twist components on
which a training-time penalty (``ppo.anchor`` in train/learner/losses.py) asks the policy's
correction to be zero.

On the nominal robot (the description's friction, no payload, nominal radii, motors and
gains, no latency) the base holds, once the command is older than the feedback
controller's hold window (the transient is over):

- a pure translation or a stop (commanded ωz = 0) with a yaw rate of at most 0.003 rad/s
  (measured on the nominal robot's straight segments): the yaw component is exact;
- with ``translations``, a pure translation within reach: every component. The base's
  setpoints are ``analytic``'s there (its correction is of the yaw only, and a steady
  one is 0 on this robot, behind the deadband);
- a pure spin within reach, or a stop (commanded vx = vy = 0), with a linear speed of
  0.000 m/s and, for a spin, a yaw-rate error of 0.003–0.008 rad/s (`feedback` on 32
  nominal episodes of pure spins, 2026-11-26, docs/evaluation.md): every component is exact.

Any steady correction there is a bias the policy learned from other robots, which costs
tracking and energy on the robot it was not needed for. :func:`exact_components` marks,
per component (vx, vy, ωz), where that holds; ``spins=False`` and ``translations=False``
keep to the yaw component of no-yaw commands only.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from mecanum_jax.kinematics import limits
from mecanum_jax.task.constants import RobotConstants

if TYPE_CHECKING:
    from mecanum_jax.task.controller import TaskInfo

YAW = 2
"""Index of ωz in a twist-space residual (vx, vy, ωz)."""


def is_nominal(robot: RobotConstants, info: TaskInfo) -> jax.Array:
    """Whether one robot's ``info["params"]`` are the nominal robot's and it has no latency."""
    pairs = zip(jax.tree.leaves(info["params"]), jax.tree.leaves(robot.nominal_params), strict=True)
    same = [jnp.all(a == b) for a, b in pairs]
    return jnp.all(jnp.stack(same)) & (info["latency"] == 0)


def exact_components(
    robot: RobotConstants,
    info: TaskInfo,
    hold_steps: int,
    spins: bool = False,
    translations: bool = False,
) -> jax.Array:
    """(3,) float mask of one robot's state: 1.0 for each twist component (vx, vy, ωz) the
    base holds exactly (see the module), else 0.0. Steady: the command is at least
    ``hold_steps`` old, the feedback controller's hold window (every step counts without
    one). ``spins`` adds steady pure spins within reach and stops, on every component;
    ``translations`` steady pure translations within reach, on every component; without
    them only ωz of steady no-yaw commands."""
    command = info["command"]
    steady = info["command_age"] >= hold_steps if hold_steps > 0 else jnp.asarray(True)
    base = is_nominal(robot, info) & steady
    no_yaw = command[YAW] == 0.0
    yaw = base & no_yaw
    lin = jnp.asarray(False)
    within = limits.saturation(robot.geometry, command, robot.max_rates) <= 1.0  # in reach
    if spins:
        lin = base & jnp.all(command[:YAW] == 0.0) & within
        yaw = yaw | lin
    if translations:
        lin = lin | (base & no_yaw & within)
    return jnp.stack([lin, lin, yaw]).astype(jnp.float32)


__all__ = ["YAW", "exact_components", "is_nominal"]
