"""mecanum_jax: batched, differentiable mecanum-wheel kinematics in JAX.

Public surface::

    from mecanum_jax import geometry, kinematics, motors, load_description
    geom = geometry.o_rectangle(radius=0.05, half_wheelbase=0.10, half_track=0.125)
    rates = kinematics.inverse(geom, twists)      # (..., 3) -> (..., 4) rad/s
    twists = kinematics.forward(geom, rates)      # (..., 4) -> (..., 3)

Importing it changes nothing outside the package: the JAX shim Brax's trainer needs
(:mod:`mecanum_jax.compat`) is installed by the trainer (:mod:`train`), not here.
"""

from mecanum_jax import (
    calibration,
    efficiency,
    geometry,
    kinematics,
    limits,
    motors,
    odometry,
    singularity,
)
from mecanum_jax._checks import InputError
from mecanum_jax.config import ConfigError
from mecanum_jax.description import RobotDescription, builtin_description, load_description
from mecanum_jax.geometry import (
    GeometryError,
    SingularLayoutError,
    SingularLayoutWarning,
    WheelGeometry,
)
from mecanum_jax.kinematics import forward, inverse, jacobian

__all__ = [
    "ConfigError",
    "GeometryError",
    "InputError",
    "RobotDescription",
    "SingularLayoutError",
    "SingularLayoutWarning",
    "WheelGeometry",
    "builtin_description",
    "calibration",
    "efficiency",
    "forward",
    "geometry",
    "inverse",
    "jacobian",
    "kinematics",
    "limits",
    "load_description",
    "motors",
    "odometry",
    "singularity",
]
