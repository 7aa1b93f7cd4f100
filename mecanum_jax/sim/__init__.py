"""The simulated robot: descriptions (:mod:`.description`), the MJCF model (:mod:`.mjcf`),
the batched MJX robot (:mod:`.physics`, built by :mod:`.robot_model`) with its parameters
and state (:mod:`.state`), wheel servos (:mod:`.servo`) and CPU batching
(:mod:`.batching`), validation against the kinematics (:mod:`.validation`) and rendering
(:mod:`.render`).

Descriptions import eagerly; the names that need MJX import on first use.
"""

from typing import TYPE_CHECKING

from mecanum_jax._lazy import exports
from mecanum_jax.sim.description import (
    IMPLS,
    RobotDescription,
    builtin_description,
    fingerprint,
    load_description,
    parse_description,
    require_impl,
    resolve_description,
)

if TYPE_CHECKING:
    from mecanum_jax.sim.physics import Robot, steady_twist
    from mecanum_jax.sim.state import RobotParams, Sensors, SimState

__getattr__, __dir__ = exports(
    __name__,
    {
        **{name: ".physics" for name in ("Robot", "steady_twist")},
        **{name: ".state" for name in ("RobotParams", "Sensors", "SimState")},
    },
)

__all__ = [
    "IMPLS",
    "Robot",
    "RobotDescription",
    "RobotParams",
    "Sensors",
    "SimState",
    "builtin_description",
    "fingerprint",
    "load_description",
    "parse_description",
    "require_impl",
    "resolve_description",
    "steady_twist",
]
