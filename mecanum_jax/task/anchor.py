"""Where the residual's base controller is already exact: the states on which a training-time
penalty (``ppo.anchor`` in train/losses.py) asks the policy's yaw correction to be zero.

On the nominal robot (the description's friction, no payload, nominal radii, motors and
gains, no latency) a pure translation or a stop (commanded ωz = 0) is held by the analytic
inverse model with a yaw rate of at most 0.003 rad/s (experiments/straight_line_residual.py):
any steady yaw correction there is a bias the policy learned from other robots, which the
feedback integrator then has to undo. :func:`base_exact` marks those states once the command
is older than the feedback controller's hold window (the transient is over).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp

if TYPE_CHECKING:
    from mecanum_jax.task.protocol import TaskEnv

YAW = 2
"""Index of ωz in a twist-space residual (vx, vy, ωz)."""


def is_nominal(env: TaskEnv, info: dict[str, Any]) -> jax.Array:
    """Whether one robot's ``info["params"]`` are the nominal robot's and it has no latency."""
    pairs = zip(jax.tree.leaves(info["params"]), jax.tree.leaves(env.nominal_params), strict=True)
    same = [jnp.all(a == b) for a, b in pairs]
    return jnp.all(jnp.stack(same)) & (info["latency"] == 0)


def base_exact(env: TaskEnv, info: dict[str, Any]) -> jax.Array:
    """1.0 where one robot's state is a steady no-yaw command on the nominal robot (see the
    module), else 0.0. Without a hold window every step of such a command counts."""
    steady = jnp.asarray(True)
    hold = env.config.feedback.hold_steps(env.config.control_dt)
    if hold > 0:
        steady = info["command_age"] >= hold
    no_yaw = info["command"][YAW] == 0.0
    return (is_nominal(env, info) & no_yaw & steady).astype(jnp.float32)


__all__ = ["YAW", "base_exact", "is_nominal"]
