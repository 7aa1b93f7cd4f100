"""Bad input fails fast with a message naming the field and the value."""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax import InputError
from mecanum_jax.kinematics import geometry
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.kinematics.geometry import (
    GeometryError,
    SingularLayoutError,
    SingularLayoutWarning,
)

POS4 = [[0.1, 0.1], [-0.1, 0.1], [-0.1, -0.1], [0.1, -0.1]]
GAMMA4 = [-math.pi / 4, math.pi / 4, -math.pi / 4, math.pi / 4]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"radii": [0.05, -0.05, 0.05, 0.05]}, r"radii\[1\] = -0\.05.*'wheel_1'.*> 0"),
        ({"radii": [0.05, 0.05, 0.0, 0.05]}, r"radii\[2\] = 0 .*> 0"),
        ({"roller_angles": [0.0, 0.5, 0.5, 0.5]}, r"roller_angles\[0\] = 0 rad \(0°\)"),
        ({"roller_angles": [0.5, math.pi / 2, 0.5, 0.5]}, r"roller_angles\[1\] = 1\.57.*\(90°\)"),
        ({"roller_angles": [0.5, 0.5, -2.0, 0.5]}, r"roller_angles\[2\] = -2 rad"),
        ({"positions": POS4[:2], "radii": 0.05}, r"2 wheel\(s\).*at least 3"),
        ({"positions": [[0.1, 0.1, 0.0]] * 4}, r"positions: shape \(4, 3\)"),
        ({"radii": [0.05, float("nan"), 0.05, 0.05]}, r"radii\[1\] = nan.*finite"),
        ({"positions": [[0.1, float("inf")], *POS4[1:]]}, r"positions\[0, 1\] = inf.*finite"),
        ({"drive_angles": [0.0, 0.0, float("nan"), 0.0]}, r"drive_angles\[2\] = nan"),
        ({"radii": [0.05, 0.05, 0.05]}, r"radii: shape \(3,\) is invalid; expected \(4,\)"),
        ({"names": ["a", "a", "b", "c"]}, r"names .* unique"),
    ],
)
def test_bad_geometry_is_rejected(kwargs, match):
    args = {"positions": POS4, "drive_angles": 0.0, "roller_angles": GAMMA4, "radii": 0.05}
    args.update(kwargs)
    with pytest.raises(GeometryError, match=match):
        geometry.make_geometry(**args)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: geometry.o_rectangle(-0.05, 0.1, 0.1), r"radius = -0\.05: must be > 0"),
        (lambda: geometry.o_rectangle(0.05, 0.0, 0.1), r"half_wheelbase = 0\.0"),
        (lambda: geometry.x_square(0.05, float("nan")), r"half_track = nan|half_wheelbase = nan"),
        (lambda: geometry.four_wheel("Q", 0.05, 0.1, 0.1), r"shape = 'Q'"),  # type: ignore[arg-type]
        (lambda: geometry.centripetal(0.05, 0.15, n_wheels=2), r"n_wheels = 2"),
        (lambda: geometry.o_square(0.05, 0.1, roller_angle=math.pi / 2), r"roller_angles\[0\]"),
    ],
)
def test_bad_constructor_arguments(call, match):
    with pytest.raises(GeometryError, match=match):
        call()


def test_twist_and_rates_shapes():
    geom = geometry.o_rectangle(0.05, 0.1, 0.125)
    with pytest.raises(InputError, match=r"twist: shape \(5, 2\).*last axis must have size 3"):
        kinematics.inverse(geom, jnp.zeros((5, 2)))
    with pytest.raises(InputError, match=r"twist: shape \(\).*size 3"):
        kinematics.inverse(geom, 1.0)
    with pytest.raises(InputError, match=r"wheel_rates: shape \(2, 3\).*size 4"):
        kinematics.forward(geom, jnp.zeros((2, 3)))
    # shape errors are static, so they raise under jit too
    with pytest.raises(InputError, match="twist"):
        jax.jit(kinematics.inverse)(geom, jnp.zeros((5, 4)))


def test_non_finite_inputs_rejected_eagerly():
    geom = geometry.o_rectangle(0.05, 0.1, 0.125)
    with pytest.raises(InputError, match=r"twist\[1, 2\] = nan"):
        kinematics.inverse(geom, jnp.array([[0.0, 0.0, 0.0], [0.0, 0.0, jnp.nan]]))
    with pytest.raises(InputError, match=r"wheel_rates\[3\] = inf"):
        kinematics.forward(geom, jnp.array([0.0, 0.0, 0.0, jnp.inf]))
    bad = geom.replace(radii=geom.radii.at[0].set(jnp.nan))  # bypassing the constructor
    with pytest.raises(InputError, match=r"geometry\.radii\[0\] = nan"):
        kinematics.inverse(bad, jnp.zeros(3))


def test_nan_under_jit_stays_per_robot():
    """Inside jit nothing can raise: a NaN twist poisons only its own robot's wheel rates."""
    geom = geometry.o_rectangle(0.05, 0.1, 0.125)
    t = jnp.array([[0.1, 0.2, 0.3], [jnp.nan, 0.0, 0.0], [0.3, 0.2, 0.1]])
    rates = jax.jit(kinematics.inverse)(geom, t)
    assert bool(jnp.all(jnp.isnan(rates[1])))
    assert bool(jnp.all(jnp.isfinite(rates[0])))
    assert bool(jnp.all(jnp.isfinite(rates[2])))
    back = jax.jit(kinematics.forward)(geom, rates)
    assert bool(jnp.all(jnp.isnan(back[1])))
    assert bool(jnp.all(jnp.isfinite(back[jnp.array([0, 2])])))
    # a NaN in the geometry makes every output NaN
    bad = geom.replace(radii=geom.radii.at[0].set(jnp.nan))
    assert bool(jnp.all(jnp.isnan(jax.jit(kinematics.inverse)(bad, t)[:, 0])))


def test_x_square_is_singular_and_reported():
    with pytest.warns(SingularLayoutWarning, match=r"rank 2 < 3"):
        geom = geometry.x_square(0.05, 0.15)
    assert kinematics.jacobian_rank(geom) == 2
    assert math.isinf(float(kinematics.condition_number(geom)))
    null = np.asarray(kinematics.null_twists(geom))
    np.testing.assert_allclose(np.abs(null), [[0.0, 0.0, 1.0]], atol=1e-6)  # the spin
    with pytest.raises(SingularLayoutError, match=r"rank 2 < 3.*\[\[0\.0, 0\.0, [-]?1\.0\]\]"):
        kinematics.forward(geom, jnp.ones(4))
    # under jit it cannot raise: the forward map is NaN, never a silent pseudo-inverse
    assert bool(jnp.all(jnp.isnan(jax.jit(kinematics.forward)(geom, jnp.ones(4)))))
    # the inverse is still defined (the X-square can be simulated): spin needs no hub motion
    np.testing.assert_allclose(kinematics.inverse(geom, jnp.array([0.0, 0.0, 1.0])), 0.0, atol=1e-6)


def test_rollers_all_one_way_is_singular():
    # all floor rollers parallel: the hubs can't tell vx from vy along the rollers' normal
    with pytest.warns(SingularLayoutWarning):
        geom = geometry.make_geometry(POS4, 0.0, math.pi / 4, 0.05)
    assert kinematics.jacobian_rank(geom) == 2
    with pytest.raises(SingularLayoutError):
        kinematics.forward(geom, jnp.ones(4))


def test_regular_layouts_do_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for geom in (
            geometry.o_rectangle(0.05, 0.1, 0.125),
            geometry.o_square(0.05, 0.1),
            geometry.x_rectangle(0.05, 0.2, 0.1),
            geometry.centripetal(0.05, 0.15),
        ):
            assert kinematics.jacobian_rank(geom) == 3
            assert 1.0 <= float(kinematics.condition_number(geom)) < 100


def test_traceable_singularity_test_agrees_with_rank():
    with pytest.warns(SingularLayoutWarning):
        xsq = geometry.x_square(0.05, 0.15)
    assert bool(jax.jit(kinematics.is_singular)(xsq))
    assert not bool(jax.jit(kinematics.is_singular)(geometry.o_rectangle(0.05, 0.1, 0.125)))
    # nearly square X-rectangle: badly conditioned (lever 1 mm) but still rank 3
    near = geometry.x_rectangle(0.05, 0.151, 0.15)
    assert kinematics.jacobian_rank(near) == 3
    assert not bool(kinematics.is_singular(near))
    np.testing.assert_allclose(
        kinematics.forward(near, kinematics.inverse(near, jnp.array([0.1, 0.2, 0.3]))),
        [0.1, 0.2, 0.3],
        rtol=2e-3,
    )
