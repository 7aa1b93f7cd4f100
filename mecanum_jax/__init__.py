"""mecanum_jax: batched, differentiable mecanum-wheel kinematics, MJX physics and the
velocity-tracking task, in JAX.

The sub-packages follow the pipeline, each importing only those before it:

- :mod:`mecanum_jax.kinematics`: wheel layouts, inverse and forward models, odometry,
  limits, singularities, efficiency, calibration, motors, other drives (pure JAX);
- :mod:`mecanum_jax.sim`: robot descriptions, the MJCF model, the batched MJX robot,
  physics validation, rendering;
- :mod:`mecanum_jax.task`: the velocity-tracking environment (commands, randomization,
  observations, reward) and the reference controllers;
- :mod:`mecanum_jax.evaluation`: scenarios, rollouts, metrics and paired statistics,
  plots, velocity spaces;
- :mod:`mecanum_jax.deploy`: the NumPy policy, ONNX export, ROS 2 parameters.

Public surface::

    from mecanum_jax import geometry, kinematics, motors, load_description
    geom = geometry.o_rectangle(radius=0.05, half_wheelbase=0.10, half_track=0.125)
    rates = kinematics.inverse(geom, twists)      # (..., 3) -> (..., 4) rad/s
    twists = kinematics.forward(geom, rates)      # (..., 4) -> (..., 3)

Importing it changes nothing outside the package and does not import MJX.
"""

from mecanum_jax import kinematics
from mecanum_jax._checks import InputError
from mecanum_jax.config import ConfigError
from mecanum_jax.kinematics import (
    calibration,
    drives,
    efficiency,
    geometry,
    limits,
    modes,
    motors,
    odometry,
    singularity,
)
from mecanum_jax.kinematics.geometry import (
    GeometryError,
    SingularLayoutError,
    SingularLayoutWarning,
    WheelGeometry,
)
from mecanum_jax.kinematics.model import forward, inverse, jacobian
from mecanum_jax.sim.description import (
    RobotDescription,
    builtin_description,
    load_description,
    resolve_description,
)

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
    "drives",
    "efficiency",
    "forward",
    "geometry",
    "inverse",
    "jacobian",
    "kinematics",
    "limits",
    "load_description",
    "modes",
    "motors",
    "odometry",
    "resolve_description",
    "singularity",
]
