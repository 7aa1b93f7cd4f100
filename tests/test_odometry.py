"""Odometry: exact SE(2) integration, world/body transforms, ICR."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax import InputError
from mecanum_jax.kinematics import geometry, odometry
from mecanum_jax.kinematics import model as kinematics


def circle(t, pose0, twist):
    """Closed-form pose after time t of a constant body twist (an arc), from pose0."""
    x0, y0, th0 = pose0
    vx, vy, w = twist
    th = th0 + w * t
    # body velocity rotates with heading; integrate R(θ(s)) v ds in closed form
    sx = (math.sin(th) - math.sin(th0)) / w
    cx = (math.cos(th0) - math.cos(th)) / w
    x = x0 + vx * sx - vy * cx
    y = y0 + vx * cx + vy * sx
    return np.array([x, y, th])


@pytest.mark.parametrize("dt", [0.01, 0.1, 0.5])
def test_exact_matches_circle_euler_and_ros2_do_not(x64, dt):
    pose0 = np.array([0.3, -0.2, 0.4])
    twist = np.array([0.8, 0.3, 1.2])
    steps = round(6.0 / dt)
    twists = jnp.broadcast_to(jnp.asarray(twist), (steps, 3))
    exact = np.asarray(odometry.integrate_twists(pose0, twists, dt))
    truth = np.stack([circle((k + 1) * dt, pose0, twist) for k in range(steps)])
    np.testing.assert_allclose(exact, truth, rtol=0, atol=1e-12)  # float64 precision

    def run(step):
        return jax.lax.scan(
            lambda p, t: (step(p, t, dt), step(p, t, dt)), jnp.asarray(pose0), twists
        )[1]

    for step in (odometry.euler_step, odometry.semi_implicit_step):
        err = np.max(np.linalg.norm(np.asarray(run(step))[:, :2] - truth[:, :2], axis=-1))
        assert err > 1e-4 * (dt / 0.01), (step.__name__, dt, err)  # first order: visibly off
    # and the first-order schemes converge linearly, so halving dt roughly halves the error
    if dt == 0.1:
        half = jnp.broadcast_to(jnp.asarray(twist), (2 * steps, 3))
        coarse = np.asarray(run(odometry.euler_step))[-1]
        fine = jax.lax.scan(
            lambda p, t: (odometry.euler_step(p, t, dt / 2),) * 2, jnp.asarray(pose0), half
        )[0]
        ratio = np.linalg.norm(coarse[:2] - truth[-1, :2]) / np.linalg.norm(
            np.asarray(fine)[:2] - truth[-1, :2]
        )
        assert 1.6 < ratio < 2.4


def test_float32_exact_integration_is_float_accurate():
    twist = jnp.array([0.8, 0.3, 1.2], jnp.float32)
    path = odometry.integrate_twists(jnp.zeros(3), jnp.broadcast_to(twist, (100, 3)), 0.05)
    truth = circle(5.0, (0.0, 0.0, 0.0), (0.8, 0.3, 1.2))
    np.testing.assert_allclose(path[-1], truth, atol=2e-5)


def test_straight_line_has_no_zero_division(x64):
    for w in (0.0, 1e-12, 1e-8, 1e-5, -1e-4):
        path = odometry.integrate_twists(jnp.zeros(3), jnp.array([[1.0, 0.5, w]] * 10), 0.1)
        assert bool(jnp.all(jnp.isfinite(path)))
        if w != 0.0:
            np.testing.assert_allclose(path[-1], circle(1.0, (0, 0, 0), (1.0, 0.5, w)), atol=1e-12)
        else:
            np.testing.assert_allclose(path[-1], [1.0, 0.5, 0.0], atol=1e-15)
    # the gradient through the series branch is finite too
    g = jax.grad(
        lambda w: odometry.integrate_twists(jnp.zeros(3), jnp.array([[1.0, 0.0, w]]), 1.0)[-1, 1]
    )(0.0)
    assert float(g) == pytest.approx(0.5)  # y ≈ v·ω·t²/2


def test_batched_over_robots_time_major():
    T, B = 20, 7
    tw = jax.random.normal(jax.random.PRNGKey(0), (T, B, 3))
    pose0 = jax.random.normal(jax.random.PRNGKey(1), (B, 3))
    path = odometry.integrate_twists(pose0, tw, 0.05)
    assert path.shape == (T, B, 3)
    one = odometry.integrate_twists(pose0[3], tw[:, 3], 0.05)
    np.testing.assert_allclose(path[:, 3], one, rtol=1e-5, atol=1e-6)
    final = odometry.integrate_twists(pose0, tw, 0.05, return_path=False)
    np.testing.assert_allclose(final, path[-1], rtol=1e-6)


def test_wheel_odometry_from_encoder_increments(x64):
    geom = geometry.o_rectangle(0.05, 0.1, 0.125, dtype=jnp.float64)
    twist = np.array([0.4, -0.2, 0.7])
    dt, T = 0.02, 300
    inc = jnp.broadcast_to(kinematics.inverse(geom, twist) * dt, (T, 4))
    path = odometry.wheel_odometry(geom, jnp.zeros(3), inc)
    np.testing.assert_allclose(path[-1], circle(T * dt, (0, 0, 0), twist), atol=1e-12)


def test_world_body_transforms_are_seed001_rotation(x64):
    theta = 0.7
    R = np.asarray(odometry.rotation_world_to_body(theta))
    c, s = math.cos(theta), math.sin(theta)
    np.testing.assert_allclose(R, [[c, s, 0], [-s, c, 0], [0, 0, 1]])
    xi_world = np.array([0.3, -0.5, 0.2])
    np.testing.assert_allclose(odometry.world_to_body(theta, xi_world), R @ xi_world, atol=1e-15)
    np.testing.assert_allclose(odometry.body_to_world(theta, R @ xi_world), xi_world, atol=1e-15)


def test_bad_series_rejected():
    with pytest.raises(InputError, match=r"zero-length"):
        odometry.integrate_twists(jnp.zeros(3), jnp.zeros((0, 3)), 0.1)
    with pytest.raises(InputError, match=r"twists\[2, 1\] = nan"):
        odometry.integrate_twists(
            jnp.zeros(3), jnp.array([[0.0] * 3, [0.0] * 3, [0.0, jnp.nan, 0.0]]), 0.1
        )
    with pytest.raises(InputError, match=r"dt = -0\.1"):
        odometry.integrate_twists(jnp.zeros(3), jnp.zeros((4, 3)), -0.1)
    with pytest.raises(InputError, match=r"initial_pose: shape \(5, 3\) does not match"):
        odometry.integrate_twists(jnp.zeros((5, 3)), jnp.zeros((4, 2, 3)), 0.1)
    geom = geometry.o_rectangle(0.05, 0.1, 0.125)
    with pytest.raises(InputError, match=r"wheel_increments: shape \(4, 3\)"):
        odometry.wheel_odometry(geom, jnp.zeros(3), jnp.zeros((4, 3)))
    with pytest.raises(InputError, match=r"expected \(T, \.\.\., 3\), time first"):
        odometry.integrate_twists(jnp.zeros(3), jnp.zeros(3), 0.1)


def test_icr(x64):
    # seed 000 eq. 20: |R_c| = |v|/|ω|, perpendicular to v, on its left when ω > 0
    out = kinematics.icr(
        jnp.array(
            [[1.0, 0.0, 0.5], [0.0, 0.0, 2.0], [0.3, 0.4, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, -0.5]]
        )
    )
    np.testing.assert_allclose(out.point[0], [0.0, 2.0])  # left of forward motion
    np.testing.assert_allclose(out.point[1], [0.0, 0.0])  # pure spin: the centre
    np.testing.assert_allclose(out.point[4], [0.0, -2.0])  # right when turning clockwise
    assert list(np.asarray(out.translating)) == [False, False, True, False, False]
    assert list(np.asarray(out.stationary)) == [False, False, False, True, False]
    assert bool(jnp.all(jnp.isnan(out.point[2])))
    assert bool(jnp.all(jnp.isnan(out.point[3])))
    # the ICR really is the point at rest: v + ω × p = 0
    t = np.array([0.3, -0.7, 1.3])
    p = np.asarray(kinematics.icr(t).point)
    np.testing.assert_allclose([t[0] - t[2] * p[1], t[1] + t[2] * p[0]], 0.0, atol=1e-15)
