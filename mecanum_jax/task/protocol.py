"""What the task's parts read of the environment: the :class:`TaskEnv` protocol.

The commands, randomization, observations and reference controllers are functions of the
environment, and the environment (:class:`~mecanum_jax.task.env.MecanumEnv`) is built from
them. They name it through this protocol, which lists exactly what they read, so none of
them imports ``env.py``. ``MecanumEnv`` satisfies it (mypy checks each call that passes
one); so does any stand-in with these attributes.
"""

from __future__ import annotations

from typing import Any, Protocol

import jax

from mecanum_jax.kinematics.geometry import WheelGeometry
from mecanum_jax.sim.physics import RobotParams


class TaskSettings(Protocol):
    """The task settings those functions read (:class:`~mecanum_jax.task.config.EnvConfig`
    has them).

    The sections are typed ``Any`` here: their classes (``CommandConfig``,
    ``RandomizationConfig``, ``FeedbackConfig``) are defined beside the functions that use
    this protocol, and naming them would import those modules back.
    """

    @property
    def control_dt(self) -> float: ...
    @property
    def yaw_integral_tau(self) -> float: ...
    @property
    def residual(self) -> bool: ...
    @property
    def obs_history(self) -> int: ...
    @property
    def commands(self) -> Any: ...  # commands.CommandConfig
    @property
    def randomization(self) -> Any: ...  # randomization.RandomizationConfig
    @property
    def feedback(self) -> Any: ...  # references.FeedbackConfig


class TaskEnv(Protocol):
    """The environment as the task's functions see it: the robot's kinematics, its scales
    and limits, and the settings."""

    @property
    def config(self) -> TaskSettings: ...
    @property
    def geometry(self) -> WheelGeometry: ...  # the nominal wheel geometry
    @property
    def n_wheels(self) -> int: ...
    @property
    def max_rates(self) -> jax.Array: ...  # (n,) wheel rate limits, rad/s
    @property
    def command_scale(self) -> jax.Array: ...  # (3,) largest feasible pure vx, vy, ωz
    @property
    def jacobian(self) -> jax.Array: ...  # (n, 3) nominal inverse model
    @property
    def forward_matrix(self) -> jax.Array: ...  # (3, n) nominal forward model
    @property
    def nominal_params(self) -> RobotParams: ...
    @property
    def yaw_decay(self) -> float: ...  # per-step decay of the yaw-error integral
    @property
    def feedback_base(self) -> bool: ...  # the residual corrects the feedback controller
    @property
    def action_size(self) -> int: ...


__all__ = ["TaskEnv", "TaskSettings"]
