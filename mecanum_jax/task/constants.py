"""What the task's parts know of the robot: :class:`RobotConstants`.

The commands, randomization, observations, reference controllers and the anchor's mask
are functions of the nominal robot's kinematics, scales and limits, and of the settings
they are given as plain arguments. :class:`~mecanum_jax.task.env.MecanumEnv` builds these
constants once (``env.constants``) and hands them to those functions.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.kinematics import limits, singularity
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.kinematics.geometry import WheelGeometry
from mecanum_jax.sim.description import RobotDescription
from mecanum_jax.sim.state import RobotParams


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RobotConstants:
    """The nominal robot as the task's functions see it (a pytree of arrays)."""

    geometry: WheelGeometry
    """The nominal wheel geometry."""
    max_rates: jax.Array
    """(n,) wheel rate limits, rad/s."""
    command_scale: jax.Array
    """(3,) the largest feasible pure vx, vy, ωz: each command axis's scale."""
    jacobian: jax.Array
    """(n, 3) the nominal inverse model."""
    forward_matrix: jax.Array
    """(3, n) the nominal forward model (the pseudo-inverse for a rank-deficient layout)."""
    reachable: jax.Array
    """(3, 3) the projector onto the twists the layout can drive (the identity for rank 3);
    commands are projected with it (:mod:`mecanum_jax.kinematics.singularity`)."""
    nominal_params: RobotParams
    """The nominal robot's physical parameters."""

    @property
    def n_wheels(self) -> int:
        return self.geometry.n_wheels


def robot_constants(
    desc: RobotDescription, geometry: WheelGeometry, nominal_params: RobotParams
) -> RobotConstants:
    """The constants of the robot ``desc`` describes, built as ``geometry``: rank 3, or a
    rank-deficient layout that still drives every translation (an X-square, which cannot
    spin: its spin axis gets the scale ``min(vx, vy scale) / max wheel distance``, finite)."""
    singularity.require_usable(geometry, desc.robot.name)
    max_rates = desc.max_wheel_rates(geometry).astype(jnp.float32)
    axes = np.eye(3, dtype=np.float32)
    command_scale = np.array(limits.max_speed(geometry, axes, max_rates))
    if not np.isfinite(command_scale[2]):  # a lost spin has no reach
        reach = float(np.max(np.linalg.norm(np.asarray(geometry.positions), axis=-1)))
        command_scale[2] = np.min(command_scale[:2]) / reach
    jacobian = jnp.asarray(kinematics.jacobian(geometry), jnp.float32)
    return RobotConstants(
        geometry=geometry,
        max_rates=max_rates,
        command_scale=jnp.asarray(command_scale, jnp.float32),
        jacobian=jacobian,
        forward_matrix=jnp.asarray(singularity.reachable_forward_matrix(geometry), jnp.float32),
        reachable=jnp.asarray(singularity.reachable_projector(geometry), jnp.float32),
        nominal_params=nominal_params,
    )


__all__ = ["RobotConstants", "robot_constants"]
