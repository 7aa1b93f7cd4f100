"""mecanum_jax: batched, differentiable mecanum-wheel kinematics in JAX.

Public surface::

    from mecanum_jax import geometry, kinematics, motors, load_description
    geom = geometry.o_rectangle(radius=0.05, half_wheelbase=0.10, half_track=0.125)
    rates = kinematics.inverse(geom, twists)      # (..., 3) -> (..., 4) rad/s
    twists = kinematics.forward(geom, rates)      # (..., 4) -> (..., 3)
"""

from mecanum_jax import compat as _compat

_compat.install()

from mecanum_jax import (  # noqa: E402
    calibration,
    efficiency,
    geometry,
    kinematics,
    limits,
    motors,
    odometry,
    singularity,
)
from mecanum_jax._checks import InputError  # noqa: E402
from mecanum_jax.config import ConfigError  # noqa: E402
from mecanum_jax.description import RobotDescription, builtin_description, load_description  # noqa: E402
from mecanum_jax.geometry import (  # noqa: E402
    GeometryError,
    SingularLayoutError,
    SingularLayoutWarning,
    WheelGeometry,
)
from mecanum_jax.kinematics import forward, inverse, jacobian  # noqa: E402

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
