"""What the robot-side controller keeps between control ticks: :class:`ControllerState`.

A ``NamedTuple``, so a pytree under JAX: the training environment keeps one per robot
(its fields are keys of the Brax state's ``info``), the robot's loop keeps one in NumPy.
Depends on the standard library only (copied beside exports).
"""

from __future__ import annotations

from typing import Any, NamedTuple


class ControllerState(NamedTuple):
    """The controller's state; every field an array of the backend in use."""

    command: Any
    """(3,) the command being tracked: the one the next action answers."""
    command_age: Any
    """() int32: control periods since the tracked command changed (0: its first)."""
    last_action: Any
    """(action_size,) the last applied action (filtered, after the deadband)."""
    history: Any
    """(frames, sensor_size) scaled sensor frames, newest first."""
    yaw_integral: Any
    """() the leaky yaw-rate error integral the policy observes, rad."""
    feedback_integral: Any
    """() the ``feedback`` controller's integrator, rad/s."""
    feedback_gains: Any
    """(3,) the ``feedback`` controller's ``(kp, ki, i_max)``."""
    path_error: Any
    """(3,) the leaky path error measured against the commanded path, in the commanded
    frame: position x, y (m) and heading (rad), the robot's minus the command's."""


FIELDS = ControllerState._fields

__all__ = ["FIELDS", "ControllerState"]
