"""The kinematics reproduce the seeds' matrices, each spelled out by hand from the seed.

Seeds: 000 (eqs. 18-19, Table 2-1), 002 (O-type matrices, X-type discrepancy),
004 (eqs. 2.7-2.8, 2.14 and its code). Wheel order: LF, LB, RB, RF.
"""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax.kinematics import geometry, motors
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.kinematics.modes import SIX_MODES

R, RX, RY = 0.05, 0.10, 0.125
K = RX + RY


@pytest.fixture
def o_rect(x64):
    return geometry.o_rectangle(R, RX, RY, dtype=jnp.float64)


def test_seed000_eq18_inverse_matrix(o_rect):
    # seed 000 eq. 18: [w1..w4] = 1/R [[1, -1, -(rx+ry)], [1, 1, -(rx+ry)],
    #                                  [1, -1, rx+ry], [1, 1, rx+ry]] [vx, vy, w]
    eq18 = (1 / R) * np.array(
        [
            [1, -1, -(RX + RY)],
            [1, +1, -(RX + RY)],
            [1, -1, +(RX + RY)],
            [1, +1, +(RX + RY)],
        ]
    )
    np.testing.assert_allclose(kinematics.jacobian(o_rect), eq18, rtol=1e-12, atol=1e-12)
    twist = np.array([0.3, -0.2, 0.7])
    np.testing.assert_allclose(kinematics.inverse(o_rect, twist), eq18 @ twist, rtol=1e-12)


def test_seed000_eq19_forward_matrix(o_rect):
    # seed 000 eq. 19: [vx,vy,w] = R/4 [[1,1,1,1], [-1,1,-1,1], [-1/K,-1/K,1/K,1/K]] [w1..w4]
    eq19 = (R / 4) * np.array(
        [
            [1, 1, 1, 1],
            [-1, 1, -1, 1],
            [-1 / K, -1 / K, 1 / K, 1 / K],
        ]
    )
    np.testing.assert_allclose(kinematics.forward_matrix(o_rect), eq19, rtol=1e-12, atol=1e-15)
    rates = np.array([3.0, -1.0, 2.0, 5.0])
    np.testing.assert_allclose(kinematics.forward(o_rect, rates), eq19 @ rates, rtol=1e-12)


def test_seed000_eq11_eq17_single_wheels(o_rect):
    # eq. 11: w4 = (vx + vy + w (rx+ry)) / R ; eq. 17: w1 = (vx - vy - w (rx+ry)) / R
    vx, vy, w = 0.4, 0.1, -0.6
    rates = kinematics.inverse(o_rect, jnp.array([vx, vy, w]))
    assert float(rates[3]) == pytest.approx((vx + vy + w * K) / R, rel=1e-12)
    assert float(rates[0]) == pytest.approx((vx - vy - w * K) / R, rel=1e-12)


def test_seed002_o_type_matrices(o_rect):
    # seed 002, "O型安装方法": forward then inverse, wheels (lf, lb, rb, rf).
    forward_o = (R / 4) * np.array(
        [
            [1, 1, 1, 1],
            [-1, 1, -1, 1],
            [-1 / (RX + RY), -1 / (RX + RY), 1 / (RX + RY), 1 / (RX + RY)],
        ]
    )
    inverse_o = (1 / R) * np.array(
        [[1, -1, -(RX + RY)], [1, 1, -(RX + RY)], [1, -1, (RX + RY)], [1, 1, (RX + RY)]]
    )
    np.testing.assert_allclose(kinematics.forward_matrix(o_rect), forward_o, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(kinematics.jacobian(o_rect), inverse_o, rtol=1e-12)
    # seed 002's single-wheel decomposition for the right-front wheel:
    # v_i = (vcx + w ry, vcy + w rx);  v_par = (√2/2)(vcx + vcy + w (rx + ry)) = w_i R cos 45°
    vcx, vcy, w = 0.2, -0.3, 0.9
    v_par = math.sqrt(2) / 2 * (vcx + vcy + w * (RX + RY))
    w_rf = float(kinematics.inverse(o_rect, jnp.array([vcx, vcy, w]))[3])
    assert w_rf * R * math.cos(math.radians(45)) == pytest.approx(v_par, rel=1e-12)


def test_seed004_eq27_general_matrix(x64):
    # seed 004 eq. 2.6/2.7: row n = [1, tan θn, Xn tan θn − Yn], θ1 = θ3 = −45°, θ2 = θ4 = +45°,
    # for any wheel coordinates (Xn, Yn), here deliberately asymmetric.
    X = np.array([0.21, -0.19, -0.22, 0.18])
    Y = np.array([0.16, 0.14, -0.15, -0.13])
    theta = np.radians([-45.0, 45.0, -45.0, 45.0])
    geom = geometry.make_geometry(np.stack([X, Y], -1), 0.0, theta, R, dtype=jnp.float64)
    eq27 = (1 / R) * np.array(
        [
            [1, -1, -X[0] - Y[0]],
            [1, 1, X[1] - Y[1]],
            [1, -1, -X[2] - Y[2]],
            [1, 1, X[3] - Y[3]],
        ]
    )
    np.testing.assert_allclose(kinematics.jacobian(geom), eq27, rtol=1e-12, atol=1e-12)


def test_seed004_eq28_and_forward_matrix(o_rect):
    # eq. 2.8: R = [[1,-1,-K],[1,1,-K],[1,-1,K],[1,1,K]], Ω = R V / r
    eq28 = np.array([[1, -1, -K], [1, 1, -K], [1, -1, K], [1, 1, K]])
    np.testing.assert_allclose(kinematics.jacobian(o_rect) * R, eq28, rtol=1e-12)
    # forward: V = F Ω r, F = [[1/4]*4, [-1/4, 1/4, -1/4, 1/4], [-1/(4K), -1/(4K), 1/(4K), 1/(4K)]]
    F = np.array(
        [
            [1 / 4, 1 / 4, 1 / 4, 1 / 4],
            [-1 / 4, 1 / 4, -1 / 4, 1 / 4],
            [-1 / (4 * K), -1 / (4 * K), 1 / (4 * K), 1 / (4 * K)],
        ]
    )
    np.testing.assert_allclose(kinematics.forward_matrix(o_rect), F * R, rtol=1e-12, atol=1e-15)
    # eq. 2.14 literally: F = (RᵀR)⁻¹Rᵀ
    np.testing.assert_allclose(np.linalg.inv(eq28.T @ eq28) @ eq28.T, F, rtol=1e-12, atol=1e-15)


def test_seed004_code_motor_rpm(o_rect):
    # seed 004's command code: v1 = x - y - K w, v2 = x + y - K w, v3 = -(x - y + K w),
    # v4 = -(x + y + K w); then v / (2 R π) * ratio * 60 = motor rpm (the seed forgets v4's
    # last line; physics needs it).
    ratio = 19.0
    x, y, w = 0.5, -0.2, 0.8
    v = np.array([x - y - K * w, x + y - K * w, -(x - y + K * w), -(x + y + K * w)])
    seed_rpm = v / (2.0 * R * math.pi) * ratio * 60
    rates = kinematics.inverse(o_rect, jnp.array([x, y, w]))
    ours = motors.wheel_rates_to_motor_rpm(rates, jnp.array([1, 1, -1, -1]), ratio)
    np.testing.assert_allclose(ours, seed_rpm, rtol=1e-12)
    # and back: encoder rpm -> wheel rates -> the commanded twist
    back = kinematics.forward(
        o_rect, motors.motor_rpm_to_wheel_rates(ours, jnp.array([1, 1, -1, -1]), ratio)
    )
    np.testing.assert_allclose(back, [x, y, w], rtol=1e-12, atol=1e-15)


def test_seed004_odometry_code_needs_motor_signs(o_rect):
    # seed 004's odometry code: linear_x = 0.25 (v1 + v2 + v3 + v4) with v_i from raw motor rpm.
    # Its command code mirrors motors 3 and 4, so for straight-forward driving the raw rpm
    # cancel and the seed's formula reports no motion: the signs must be undone first.
    ratio = 19.0
    rates = kinematics.inverse(o_rect, jnp.array([0.5, 0.0, 0.0]))
    rpm = np.asarray(motors.wheel_rates_to_motor_rpm(rates, jnp.array([1, 1, -1, -1]), ratio))
    v = rpm / ratio / 60.0 * R * math.pi * 2
    seed_linear_x = 0.25 * v[0] + 0.25 * v[1] + 0.25 * v[2] + 0.25 * v[3]
    assert abs(seed_linear_x) < 1e-12  # the seed's literal formula: wrong
    ours = kinematics.forward(
        o_rect, motors.motor_rpm_to_wheel_rates(rpm, jnp.array([1, 1, -1, -1]), ratio)
    )
    assert float(ours[0]) == pytest.approx(0.5, rel=1e-12)


@pytest.mark.parametrize("mode", list(SIX_MODES))
def test_seed000_table_2_1_six_modes(o_rect, mode):
    _, twist, pattern = SIX_MODES[mode]
    rates = np.asarray(kinematics.inverse(o_rect, jnp.asarray(twist)))
    scale = np.max(np.abs(rates))
    for i, sign in enumerate(pattern):
        if sign == 0:
            assert abs(rates[i]) < 1e-12 * scale, (mode, i, rates)
        else:
            assert np.sign(rates[i]) == sign, (mode, i, rates)
    # seed 000: "the four motor speeds have the same magnitude" (among moving wheels)
    moving = np.abs(rates[np.asarray(pattern) != 0])
    np.testing.assert_allclose(moving, moving[0], rtol=1e-12)


def test_six_modes_match_table_when_driven_forward(o_rect):
    # The converse: driving the table's sign patterns gives the named motion (mode d goes LEFT,
    # as seed 000's figure caption and eq. 18 say, not right as its text says).
    for name, (_, twist, pattern) in SIX_MODES.items():
        got = np.asarray(kinematics.forward(o_rect, jnp.asarray(pattern, jnp.float64)))
        cos = got @ np.asarray(twist) / (np.linalg.norm(got) * np.linalg.norm(twist))
        assert cos == pytest.approx(1.0, abs=1e-12), (name, got)


def test_seed002_x_type_discrepancy_resolved_by_physics(x64):
    """Seed 002's X-type matrix keeps the spin column ±(rx+ry), so an X-square could spin,
    contradicting the seed's own statement. Physics (the rigid-body constraint) gives the
    lever arm rx − ry: an X-square cannot spin, an X-rectangle spins through |rx − ry|."""
    seed002_x = (1 / R) * np.array([[1, 1, -K], [1, -1, -K], [1, -1, K], [1, 1, K]])
    xsq = geometry.x_square(R, 0.15, dtype=jnp.float64, warn_singular=False)
    J = np.asarray(kinematics.jacobian(xsq))
    # the physical property: a pure spin needs no hub motion, and the hubs can't produce one
    np.testing.assert_allclose(J[:, 2], 0.0, atol=1e-12)
    assert kinematics.jacobian_rank(xsq) == 2
    assert not np.allclose(
        J, (1 / R) * np.array([[1, 1, -0.3], [1, -1, -0.3], [1, -1, 0.3], [1, 1, 0.3]])
    )
    assert np.linalg.matrix_rank(seed002_x) == 3  # the seed's matrix claims spin is possible
    # X-rectangle: rows [1, ±1, ±(rx − ry)] from the rigid-body constraint, spelled out
    xr = geometry.x_rectangle(R, 0.2, 0.1, dtype=jnp.float64)
    d = 0.2 - 0.1
    expected = (1 / R) * np.array([[1, 1, d], [1, -1, d], [1, 1, -d], [1, -1, -d]])
    np.testing.assert_allclose(kinematics.jacobian(xr), expected, rtol=1e-12, atol=1e-12)


def _rigid_body_hub_rate(p, psi, gamma, r, twist):
    """Independent derivation: split the contact velocity into hub rolling (along the drive
    direction d) plus free roller rolling (perpendicular to the roller axis u), solve for ω."""
    vx, vy, w = twist
    v = np.array([vx - w * p[1], vy + w * p[0]])
    d = np.array([math.cos(psi), math.sin(psi)])
    u = np.array([math.cos(psi + gamma), math.sin(psi + gamma)])
    n = np.array([-u[1], u[0]])  # the roller rolls freely along n
    A = np.stack([r * d, n], axis=1)  # v = (r ω) d + s n
    omega, _ = np.linalg.solve(A, v)
    return omega


def test_inverse_matches_independent_velocity_decomposition(x64):
    rng = np.random.default_rng(0)
    for _ in range(20):
        n = int(rng.integers(3, 7))
        pos = rng.uniform(-0.5, 0.5, (n, 2))
        psi = rng.uniform(-np.pi, np.pi, n)
        gamma = rng.uniform(0.2, 1.3, n) * rng.choice([-1, 1], n)
        radii = rng.uniform(0.02, 0.2, n)
        geom = geometry.make_geometry(
            pos, psi, gamma, radii, dtype=jnp.float64, warn_singular=False
        )
        twist = rng.normal(size=3)
        expected = [
            _rigid_body_hub_rate(pos[i], psi[i], gamma[i], radii[i], twist) for i in range(n)
        ]
        np.testing.assert_allclose(kinematics.inverse(geom, twist), expected, rtol=1e-9, atol=1e-9)
