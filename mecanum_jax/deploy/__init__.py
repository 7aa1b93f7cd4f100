"""Running a trained policy outside the trainer: the NumPy policy and its file format
(:mod:`.policy`, written by :mod:`.write`), ONNX export (:mod:`.onnx`, needs the ``onnx``
extra) and ROS 2 ``mecanum_drive_controller`` parameters (:mod:`.ros2`)."""

from mecanum_jax.deploy.policy import ExportError, NumpyPolicy, load
from mecanum_jax.deploy.write import save

__all__ = ["ExportError", "NumpyPolicy", "load", "save"]
