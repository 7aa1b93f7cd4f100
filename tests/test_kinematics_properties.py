"""Properties of inverse/forward over random general geometries (hypothesis)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from strategies import build, finite, layouts, numpy_jacobian, twists

from mecanum_jax.kinematics import geometry
from mecanum_jax.kinematics import model as kinematics


@given(layouts(), twists)
def test_forward_inverts_inverse(layout, twist):
    with jax.enable_x64(True):
        geom = build(layout)
        rates = kinematics.inverse(geom, twist)
        np.testing.assert_allclose(rates, numpy_jacobian(layout) @ twist, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(kinematics.forward(geom, rates), twist, rtol=1e-9, atol=1e-9)
        # the wheel rates of a rigid motion are self-consistent: no wheel fights the others
        np.testing.assert_allclose(kinematics.consistency_residual(geom, rates), 0.0, atol=1e-8)


@given(layouts(), twists, twists, finite)
def test_inverse_is_linear(layout, t1, t2, a):
    with jax.enable_x64(True):
        geom = build(layout)
        lhs = kinematics.inverse(geom, a * t1 + t2)
        rhs = a * kinematics.inverse(geom, t1) + kinematics.inverse(geom, t2)
        np.testing.assert_allclose(lhs, rhs, rtol=1e-9, atol=1e-9)


@given(layouts(), twists, st.floats(-np.pi, np.pi))
def test_rotating_the_layout_rotates_the_twist(layout, twist, phi):
    """Turning the whole chassis by φ in the body frame: a twist turned by φ needs the same
    wheel rates, and forward reports the turned twist."""
    with jax.enable_x64(True):
        geom = build(layout)
        turned = geometry.rotated(geom, phi)
        c, s = np.cos(phi), np.sin(phi)
        t_rot = np.array([c * twist[0] - s * twist[1], s * twist[0] + c * twist[1], twist[2]])
        np.testing.assert_allclose(
            kinematics.inverse(turned, t_rot), kinematics.inverse(geom, twist), rtol=1e-9, atol=1e-9
        )
        rates = kinematics.inverse(geom, twist)
        np.testing.assert_allclose(kinematics.forward(turned, rates), t_rot, rtol=1e-9, atol=1e-9)


def _loss(params, geom, twist, target):
    """A loss through both maps, of all geometry parameters packed in one vector."""
    n = geom.n_wheels
    g = geom.replace(
        radii=params[:n],
        roller_angles=params[n : 2 * n],
        positions=params[2 * n :].reshape(n, 2),
    )
    rates = kinematics.inverse(g, twist)
    return jnp.sum((kinematics.forward(g, rates * 1.1 + 0.3) - target) ** 2) + jnp.sum(rates**2)


@jax.jit
def _grad_and_finite_differences(params, geom, twist, target):
    h = 1e-6
    grad = jax.grad(_loss)(params, geom, twist, target)
    basis = jnp.eye(params.shape[0], dtype=params.dtype) * h
    plus = jax.vmap(lambda e: _loss(params + e, geom, twist, target))(basis)
    minus = jax.vmap(lambda e: _loss(params - e, geom, twist, target))(basis)
    return grad, (plus - minus) / (2 * h)


@given(layouts(max_wheels=5, max_condition=200.0), twists)
def test_grad_matches_finite_differences(layout, twist):
    with jax.enable_x64(True):
        geom = build(layout)
        params = jnp.concatenate([geom.radii, geom.roller_angles, geom.positions.ravel()])
        grad, fd = _grad_and_finite_differences(
            params, geom, jnp.asarray(twist), jnp.asarray([0.1, -0.2, 0.3])
        )
        assert bool(jnp.all(jnp.isfinite(grad)))
        np.testing.assert_allclose(
            grad, fd, rtol=1e-5, atol=1e-5 * float(jnp.max(jnp.abs(fd))) + 1e-8
        )


def test_grad_wrt_twist_is_the_jacobian(x64):
    geom = geometry.o_rectangle(0.05, 0.1, 0.125, dtype=jnp.float64)
    jac = jax.jacfwd(lambda t: kinematics.inverse(geom, t))(jnp.array([0.1, 0.2, 0.3]))
    np.testing.assert_allclose(jac, kinematics.jacobian(geom), rtol=1e-12)
    jac_f = jax.jacrev(lambda w: kinematics.forward(geom, w))(jnp.ones(4))
    np.testing.assert_allclose(jac_f, kinematics.forward_matrix(geom), rtol=1e-12)


@pytest.mark.parametrize("shape", [(), (7,), (2, 3), (2, 1, 5)])
def test_batched_over_any_leading_axes(shape):
    geom = geometry.o_rectangle(0.05, 0.1, 0.125)
    t = jax.random.normal(jax.random.PRNGKey(0), (*shape, 3))
    rates = kinematics.inverse(geom, t)
    assert rates.shape == (*shape, 4)
    back = kinematics.forward(geom, rates)
    assert back.shape == (*shape, 3)
    flat = kinematics.inverse(geom, t.reshape(-1, 3)).reshape(*shape, 4)
    np.testing.assert_allclose(rates, flat, rtol=1e-6)
    np.testing.assert_allclose(back, t, rtol=1e-4, atol=1e-5)


def test_jit_and_vmap_agree_with_eager():
    geom = geometry.o_rectangle(0.05, 0.1, 0.125)
    t = jax.random.normal(jax.random.PRNGKey(1), (16, 3))
    eager = kinematics.inverse(geom, t)
    np.testing.assert_allclose(jax.jit(kinematics.inverse)(geom, t), eager, rtol=1e-6, atol=1e-5)
    vmapped = jax.vmap(kinematics.inverse, (None, 0))(geom, t)
    np.testing.assert_allclose(vmapped, eager, rtol=1e-6, atol=1e-5)
    w = jax.jit(kinematics.forward)(geom, eager)
    np.testing.assert_allclose(w, t, rtol=1e-4, atol=1e-5)


def test_vmap_over_geometries():
    """A batch of geometries (e.g. randomized radii) passes through vmap as a pytree."""
    base = geometry.o_rectangle(0.05, 0.1, 0.125)
    radii = jnp.linspace(0.04, 0.06, 5)[:, None] * jnp.ones((1, 4))
    geoms = jax.vmap(lambda r: base.replace(radii=r))(radii)
    rates = jax.vmap(kinematics.inverse, (0, None))(geoms, jnp.array([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(rates[:, 0], 1.0 / radii[:, 0], rtol=1e-6)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_dtypes_preserved(dtype):
    with jax.enable_x64(dtype == "float64"):
        geom = geometry.o_rectangle(0.05, 0.1, 0.125, dtype=dtype)
        t = jnp.asarray([[0.3, 0.1, -0.2]], dtype=dtype)
        rates = kinematics.inverse(geom, t)
        assert rates.dtype == jnp.dtype(dtype)
        assert kinematics.forward(geom, rates).dtype == jnp.dtype(dtype)
        tol = 1e-6 if dtype == "float32" else 1e-14
        np.testing.assert_allclose(kinematics.forward(geom, rates), t, rtol=tol, atol=tol)


def test_no_recompilation_for_new_values():
    geom = geometry.o_rectangle(0.05, 0.1, 0.125)
    f = jax.jit(kinematics.inverse)
    f(geom, jnp.zeros((8, 3)))
    size = f._cache_size()
    f(geometry.o_rectangle(0.06, 0.2, 0.1), jnp.ones((8, 3)))
    assert f._cache_size() == size


def test_centripetal_three_wheels_full_rank(x64):
    geom = geometry.centripetal(0.05, 0.15, dtype=jnp.float64)
    assert geom.n_wheels == 3
    assert kinematics.jacobian_rank(geom) == 3
    # every hub axle passes through the centre: drive direction ⟂ position vector
    d = np.stack([np.cos(geom.drive_angles), np.sin(geom.drive_angles)], -1)
    np.testing.assert_allclose(np.sum(d * np.asarray(geom.positions), -1), 0.0, atol=1e-12)
    # a pure spin turns all three hubs equally, at centre_distance / radius
    np.testing.assert_allclose(kinematics.inverse(geom, [0.0, 0.0, 1.0]), 0.15 / 0.05, rtol=1e-12)
