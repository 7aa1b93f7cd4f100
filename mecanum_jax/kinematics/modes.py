"""The six motion modes of seed 000 (Table 2-1), as body twists.

Each mode is a unit-speed twist; seed 000's table gives the sign pattern of the wheel
rates (left-front, left-back, right-back, right-front) for the O layout, which
``tests/test_seed_matrices.py`` checks against :func:`mecanum_jax.kinematics.model.inverse`.
"""

from __future__ import annotations

import math

# name -> (description, twist (vx m/s, vy m/s, wz rad/s), seed 000 sign pattern)
SIX_MODES: dict[str, tuple[str, tuple[float, float, float], tuple[int, int, int, int]]] = {
    "a_forward": ("forward", (1.0, 0.0, 0.0), (1, 1, 1, 1)),
    "b_backward": ("backward", (-1.0, 0.0, 0.0), (-1, -1, -1, -1)),
    "c_diagonal": ("diagonal, front-left", (math.sqrt(0.5), math.sqrt(0.5), 0.0), (0, 1, 0, 1)),
    "d_lateral": ("lateral, to the left", (0.0, 1.0, 0.0), (-1, 1, -1, 1)),
    "e_spin_cw": ("spin clockwise", (0.0, 0.0, -1.0), (1, 1, -1, -1)),
    "f_spin_ccw": ("spin counter-clockwise", (0.0, 0.0, 1.0), (-1, -1, 1, 1)),
}
