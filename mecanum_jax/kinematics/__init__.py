"""Kinematics of roller-wheel robots: pure JAX, no physics.

The functions of :mod:`.model` (``inverse``, ``forward``, ``jacobian``, ...) are available
here directly, so ``kinematics.inverse(geom, twists)`` reads as before. The other modules
build on them: the wheel layout (:mod:`.geometry`), dead reckoning (:mod:`.odometry`),
wheel-rate limits and desaturation (:mod:`.limits`), singular layouts
(:mod:`.singularity`), efficiency and slip (:mod:`.efficiency`), calibration
(:mod:`.calibration`), motor curves (:mod:`.motors`), the six named motions
(:mod:`.modes`) and the other drives of the lecture (:mod:`.drives`, with their geometries
in :mod:`.drive_geometry` and descriptions in :mod:`.drive_description`).
"""

from mecanum_jax.kinematics import (
    calibration,
    drive_description,
    drive_geometry,
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
from mecanum_jax.kinematics.model import (
    ICR,
    apply_rows,
    condition_number,
    consistency_residual,
    forward,
    forward_matrix,
    icr,
    inverse,
    inverse_soa,
    is_singular,
    jacobian,
    jacobian_rank,
    null_twists,
    require_full_rank,
    roller_axes,
    singular_values,
)

__all__ = [
    "ICR",
    "GeometryError",
    "SingularLayoutError",
    "SingularLayoutWarning",
    "WheelGeometry",
    "apply_rows",
    "calibration",
    "condition_number",
    "consistency_residual",
    "drive_description",
    "drive_geometry",
    "drives",
    "efficiency",
    "forward",
    "forward_matrix",
    "geometry",
    "icr",
    "inverse",
    "inverse_soa",
    "is_singular",
    "jacobian",
    "jacobian_rank",
    "limits",
    "modes",
    "motors",
    "null_twists",
    "odometry",
    "require_full_rank",
    "roller_axes",
    "singular_values",
    "singularity",
]
