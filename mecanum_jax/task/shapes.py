"""A task's shapes without its physics: :class:`TaskShapes`.

What a policy of an environment config reads and writes (the policy's and the critic's
observation layouts and sizes, the action size), and the robot description a checkpoint
is checked against, come from the config and the robot description alone: no MJCF or MJX
model is built for them, nor the robot's constants (their kinematics cost some hundred
eager JAX operations, each compiled on its first use in a process) unless read: the
controller spec (:func:`~mecanum_jax.task.controller.controller_spec`) and a symmetric
policy's mirrors read them. :class:`~mecanum_jax.task.env.MecanumEnv` takes its own from
:func:`task_shapes`, so a restored policy (``train.learner.policy``), which needs nothing
more, sees exactly the environment's.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Protocol

from mecanum_jax.control import ControllerSpec, Layout
from mecanum_jax.host import on_host
from mecanum_jax.kinematics.geometry import WheelGeometry
from mecanum_jax.sim.description import RobotDescription
from mecanum_jax.sim.state import nominal_params
from mecanum_jax.task.config import EnvConfig
from mecanum_jax.task.constants import RobotConstants, robot_constants
from mecanum_jax.task.controller import controller_spec, policy_shape
from mecanum_jax.task.observations import privileged_layout


class Shaped(Protocol):
    """What the networks, a training state's template and a checkpoint's check read of a
    task: a :class:`~mecanum_jax.task.env.MecanumEnv` or its :class:`TaskShapes`."""

    @property
    def desc(self) -> RobotDescription: ...
    @property
    def control(self) -> ControllerSpec: ...
    @property
    def layout(self) -> Layout: ...
    @property
    def observation_size(self) -> dict[str, tuple[int, ...]]: ...
    @property
    def action_size(self) -> int: ...


@dataclasses.dataclass(frozen=True)
class TaskShapes:
    """The task of one config as its policy sees it (:func:`task_shapes`). The robot's
    constants and the controller spec, whose kinematics cost some hundred eager JAX
    operations, are built when first read (the symmetric policy's mirrors read them)."""

    config: EnvConfig
    desc: RobotDescription
    """The task's robot description (:meth:`EnvConfig.description`)."""
    geometry: WheelGeometry
    """The nominal wheel geometry."""
    action_size: int
    layout: Layout
    """The policy's observation (:func:`~mecanum_jax.task.controller.policy_shape`: the
    controller spec's)."""
    privileged_layout: Layout
    """The critic's observation (:func:`~mecanum_jax.task.observations.privileged_layout`)."""

    @property
    def observation_size(self) -> dict[str, tuple[int, ...]]:
        """Brax's observation sizes: the policy's ``state``, the critic's ``privileged_state``."""
        return {
            "state": (sum(s for _, s in self.layout),),
            "privileged_state": (sum(s for _, s in self.privileged_layout),),
        }

    @functools.cached_property
    def constants(self) -> RobotConstants:
        """The nominal robot's kinematics, scales and limits (on the CPU, mecanum_jax.host)."""
        n = self.geometry.n_wheels
        with on_host():
            return robot_constants(self.desc, self.geometry, nominal_params(self.desc, n))

    @functools.cached_property
    def control(self) -> ControllerSpec:
        """The robot-side controller (:func:`~mecanum_jax.task.controller.controller_spec`;
        with ``symmetric``, an asymmetric robot is refused here)."""
        with on_host():
            return controller_spec(self.config, self.desc, self.constants)


def task_shapes(config: EnvConfig) -> TaskShapes:
    """The shapes of the task a validated ``config`` describes, from its robot description
    alone."""
    desc = config.description()
    with on_host():
        geometry = desc.build_geometry(warn_singular=False)
    n = geometry.n_wheels
    action_size, layout = policy_shape(config, n)
    privileged = privileged_layout(layout, n, config.path_tau > 0)
    return TaskShapes(config, desc, geometry, action_size, layout, privileged)


__all__ = ["Shaped", "TaskShapes", "task_shapes"]
