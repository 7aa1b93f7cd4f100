"""The robot-side controller, written once: a frozen :class:`ControllerSpec`, a typed
:class:`ControllerState` and the step functions of :mod:`.step`, for every array backend
(JAX in training, NumPy on the robot, an ONNX graph traced from the same code).

Pure: NumPy and the standard library; nothing here imports JAX, MuJoCo or the task, so
the export packs this package beside a policy as ``mecanum_control/`` (in
``mecanum_robot.zip``).
"""

from .spec import (
    ControllerSpec,
    FeedbackSpec,
    Layout,
    NearestMaps,
    entry_slice,
    policy_layout,
    sensor_size,
)
from .state import ControllerState

__all__ = [
    "ControllerSpec",
    "ControllerState",
    "FeedbackSpec",
    "Layout",
    "NearestMaps",
    "entry_slice",
    "policy_layout",
    "sensor_size",
]
