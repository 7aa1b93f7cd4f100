"""Hypothesis strategies for random general wheel geometries.

They draw plain NumPy float64 arrays; a test builds the JAX geometry with :func:`build`
inside its own dtype context (float64 tests run under ``jax.enable_x64``).
"""

import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from hypothesis import assume
from hypothesis import strategies as st

from mecanum_jax.kinematics import geometry


class Layout(NamedTuple):
    positions: np.ndarray
    drive_angles: np.ndarray
    roller_angles: np.ndarray
    radii: np.ndarray


def build(layout: Layout, dtype=jnp.float64) -> geometry.WheelGeometry:
    return geometry.make_geometry(*layout, dtype=dtype, warn_singular=False)


def numpy_jacobian(layout: Layout) -> np.ndarray:
    """The reference inverse matrix in plain NumPy (the same maths, written independently)."""
    a = layout.drive_angles + layout.roller_angles
    x, y = layout.positions[:, 0], layout.positions[:, 1]
    scale = 1.0 / (layout.radii * np.cos(layout.roller_angles))
    return np.stack([np.cos(a), np.sin(a), x * np.sin(a) - y * np.cos(a)], -1) * scale[:, None]


@st.composite
def layouts(draw, min_wheels=3, max_wheels=8, max_condition=1e3):
    """Random layouts: n wheels, arbitrary positions, drive and roller angles, radii; only
    well-conditioned (non-singular) ones when ``max_condition`` is set."""
    n = draw(st.integers(min_wheels, max_wheels))
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    layout = Layout(
        positions=rng.uniform(-0.6, 0.6, (n, 2)),
        drive_angles=rng.uniform(-math.pi, math.pi, n),
        roller_angles=rng.uniform(math.radians(10), math.radians(80), n)
        * rng.choice([-1.0, 1.0], n),
        radii=rng.uniform(0.02, 0.2, n),
    )
    if max_condition is not None:
        assume(np.linalg.cond(numpy_jacobian(layout)) < max_condition)
    return layout


finite = st.floats(-5.0, 5.0, allow_nan=False, allow_infinity=False)
twists = st.tuples(finite, finite, finite).map(np.asarray)
