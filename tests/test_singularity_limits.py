"""Singular directions, velocity limits, feasible set, desaturation, efficiency."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax import InputError
from mecanum_jax.kinematics import efficiency, geometry, limits, singularity
from mecanum_jax.kinematics import model as kinematics


@pytest.fixture
def o_rect(x64):
    return geometry.o_rectangle(0.05, 0.1, 0.125, dtype=jnp.float64)


def test_singular_wheels_diagonal(o_rect):
    diag = jnp.array([1.0, 1.0, 0.0])  # seed 000 mode (c): LF and RB still
    assert list(np.asarray(singularity.singular_wheels(o_rect, diag))) == [True, False, True, False]
    assert not bool(jnp.any(singularity.singular_wheels(o_rect, jnp.array([1.0, 0.0, 0.0]))))
    assert not bool(jnp.any(singularity.singular_wheels(o_rect, jnp.zeros(3))))


def test_singular_directions_of_standard_and_centripetal_layouts(o_rect):
    dirs = singularity.singular_directions(o_rect)
    assert [round(math.degrees(d.heading), 6) for d in dirs] == [45.0, 135.0]
    assert dirs[0].wheels == ("left_front", "right_back")
    assert set(dirs[1].wheels) == {"left_back", "right_front"}
    # seed 003 §3.1: odd centripetal layouts have at most one singular wheel per direction
    assert singularity.singular_directions(geometry.centripetal(0.05, 0.15, 3)) == []
    four = geometry.centripetal(0.05, 0.15, 4)
    assert all(len(d.wheels) == 2 for d in singularity.singular_directions(four))


def test_avoidance_turn_is_smallest_and_clears_margin(o_rect):
    margin = math.radians(10)
    heading = math.radians(45 + 3)  # 3° off the LF/RB singular diagonal
    delta = float(singularity.avoidance_turn(o_rect, heading, margin))
    assert abs(delta) == pytest.approx(math.radians(7), abs=1e-9)  # turn 7° more, not 13°
    assert float(singularity.heading_margin(o_rect, heading - delta)) >= margin - 1e-9
    # already clear: no turn
    assert float(singularity.avoidance_turn(o_rect, 0.3, margin)) == 0.0
    # brute force over a fine grid agrees for many headings
    grid = np.radians(np.linspace(-60, 60, 24001))
    for h in np.radians([0.0, 44.0, 45.0, 50.0, 130.0, 137.0, -40.0]):
        ok = np.asarray(singularity.heading_margin(o_rect, h - grid)) >= margin - 1e-9
        best = np.min(np.abs(grid[ok]))
        got = abs(float(singularity.avoidance_turn(o_rect, h, margin)))
        assert got == pytest.approx(best, abs=2e-4)
    # impossible margin (singular headings are 90° apart): NaN
    assert math.isnan(float(singularity.avoidance_turn(o_rect, 0.0, math.radians(50))))


def test_desaturation_keeps_direction_clipping_bends_path(o_rect):
    m = 20.0  # rad/s per wheel
    twist = jnp.array([1.5, 0.3, 2.0])
    assert not bool(limits.is_feasible(o_rect, twist, m))
    scaled, scale = limits.desaturate(o_rect, twist, m)
    assert float(limits.saturation(o_rect, scaled, m)) == pytest.approx(1.0)
    np.testing.assert_allclose(np.asarray(scaled) / float(scale), twist)
    # naive clipping: the achieved twist (least squares) turns away from the command
    clipped = limits.clip_wheel_rates(kinematics.inverse(o_rect, twist), m)
    achieved = np.asarray(kinematics.forward(o_rect, clipped))
    cos = achieved @ np.asarray(twist) / (np.linalg.norm(achieved) * np.linalg.norm(twist))
    assert math.degrees(math.acos(min(cos, 1.0))) > 2.0
    # path curvature ω/|v| changes with clipping but not with desaturation
    curv = lambda t: t[2] / np.hypot(t[0], t[1])  # noqa: E731
    assert curv(np.asarray(scaled)) == pytest.approx(curv(np.asarray(twist)))
    assert abs(curv(achieved) - curv(np.asarray(twist))) > 0.05
    # feasible twists pass unchanged
    small = jnp.array([0.1, 0.1, 0.1])
    np.testing.assert_allclose(limits.desaturate(o_rect, small, m)[0], small)


def test_feasible_set_vertices_and_slice(o_rect):
    m = 20.0
    V = limits.feasible_vertices(o_rect, m)
    assert len(V) > 0
    # every vertex is feasible and saturates at least 3 wheel limits
    sat = np.abs(np.asarray(kinematics.inverse(o_rect, V))) / m
    assert np.all(sat <= 1 + 1e-9)
    assert np.all(np.sum(np.isclose(sat, 1.0), axis=1) >= 3)
    # the polytope's extent: forward top speed m·r, spin top speed m·r/K
    assert V[:, 0].max() == pytest.approx(m * 0.05)
    assert V[:, 2].max() == pytest.approx(m * 0.05 / 0.225)
    poly = limits.feasible_slice(o_rect, m, wz=0.0)
    # with 45° rollers the (vx, vy) slice at ωz = 0 is a square diamond with corners at ±m r
    assert len(poly) == 4
    np.testing.assert_allclose(sorted(np.abs(poly).max(axis=1)), [1.0] * 4, atol=1e-12)
    # spinning shrinks it; too much spin empties it
    assert len(limits.feasible_slice(o_rect, m, wz=0.5 * m * 0.05 / 0.225)) == 4
    assert len(limits.feasible_slice(o_rect, m, wz=1.1 * m * 0.05 / 0.225)) == 0
    A, b = limits.feasible_facets(o_rect, m)
    assert A.shape == (8, 3)
    assert b.shape == (8,)
    d = jnp.array([0.0, 1.0, 0.0])
    assert float(limits.max_speed(o_rect, d, m)) == pytest.approx(1.0)


@pytest.mark.parametrize("layout", ["o_rectangle", "x_square", "centripetal3"])
@pytest.mark.parametrize("omega_weight", [1.0, 0.1])
def test_nearest_feasible_is_the_optimum(x64, layout, omega_weight):
    """Certified by the optimality (KKT) conditions, independently of how it is computed:
    feasible, and the weighted error c - t is a non-negative combination of the normals of
    the limits it touches. Also never worse than uniform scaling in the same metric."""
    from scipy.optimize import nnls

    g = {
        "o_rectangle": lambda: geometry.o_rectangle(0.05, 0.1, 0.125, dtype=jnp.float64),
        "x_square": lambda: geometry.x_square(0.05, 0.1, dtype=jnp.float64),  # singular
        "centripetal3": lambda: geometry.centripetal(0.05, 0.15, 3, dtype=jnp.float64),
    }[layout]()
    m = 20.0
    far = np.random.default_rng(3).normal(size=(200, 3)) * [1.5, 1.5, 15.0]
    near = 0.9 * np.asarray(limits.desaturate(g, far[:50], m)[0])  # within reach
    twists = np.concatenate([far, near])
    got = np.asarray(jax.jit(lambda t: limits.nearest_feasible(g, t, m, omega_weight))(twists))
    sat = np.asarray(limits.saturation(g, got, m))
    assert np.all(sat <= 1 + 1e-9)
    inside = np.asarray(limits.saturation(g, twists, m)) <= 1
    np.testing.assert_array_equal(got[inside], twists[inside])  # feasible: unchanged
    assert (~inside).sum() > 100
    assert inside.sum() >= 50
    d = np.array([1.0, 1.0, math.sqrt(omega_weight)])
    A, b = (np.asarray(x) for x in limits.feasible_facets(g, m))
    scaled = np.asarray(limits.desaturate(g, twists, m)[0])
    for c, t, s in zip(twists[~inside], got[~inside], scaled[~inside], strict=True):
        active = np.abs(A @ t - b) < 1e-9 * m
        assert active.any()
        normals = (A[active] / d).T  # in the weighted coordinates u = d t
        _, residual = nnls(normals, (c - t) * d)
        assert residual < 1e-9 * max(1.0, float(np.linalg.norm((c - t) * d)))
        assert np.sum(((t - c) * d) ** 2) <= np.sum(((s - c) * d) ** 2) + 1e-12
    # the weight trades ω error for v error, as documented
    if omega_weight == 1.0 and layout == "o_rectangle":
        light = np.asarray(jax.jit(lambda t: limits.nearest_feasible(g, t, m, 0.01))(twists))
        v_err = lambda t: np.hypot(*(t - twists)[:, :2].T).mean()  # noqa: E731
        w_err = lambda t: np.abs(t - twists)[:, 2].mean()  # noqa: E731
        assert v_err(light) < v_err(got)
        assert w_err(light) > w_err(got)


def test_nearest_feasible_rejects_bad_weight(o_rect):
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match="omega_weight"):
            limits.nearest_feasible(o_rect, jnp.ones(3), 20.0, bad)


def test_limits_reject_bad_input(o_rect):
    with pytest.raises(InputError, match=r"max_rates\[2\] = -1"):
        limits.saturation(o_rect, jnp.zeros(3), jnp.array([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(InputError, match=r"max_rates: shape \(3,\)"):
        limits.saturation(o_rect, jnp.zeros(3), jnp.ones(3))
    with pytest.raises(InputError, match=r"max_linear_accel = 0"):
        limits.limit_acceleration(jnp.zeros(3), jnp.ones(3), 0.02, 0, 1.0)


def test_acceleration_limiter(o_rect):
    prev = jnp.array([[0.0, 0.0, 0.0]])
    tgt = jnp.array([[3.0, 4.0, 10.0]])
    out = np.asarray(limits.limit_acceleration(prev, tgt, 0.1, 1.0, 2.0))[0]
    np.testing.assert_allclose(out, [0.06, 0.08, 0.2])  # |Δv| = 0.1, direction kept


def test_efficiency_lateral_costs_more(o_rect):
    eff = efficiency.efficiency(o_rect, jnp.array([0.0, math.pi / 2, math.pi / 4]))
    fwd, lat, diag = (np.asarray(x) for x in zip(*eff, strict=True))
    assert fwd[0] == pytest.approx(1.0)
    assert lat[0] == pytest.approx(1.0)
    assert diag[0] == pytest.approx(1 / math.sqrt(2))  # diagonal: two wheels at √2 v
    assert fwd[1] == pytest.approx(0.0, abs=1e-12)  # rollers still when going straight
    assert lat[1] == pytest.approx(math.sqrt(2))  # sideways: rollers spin at √2 v
    assert fwd[2] == pytest.approx(1 / math.sqrt(2))
    assert lat[2] == pytest.approx(1 / math.sqrt(2))
    assert diag[2] == pytest.approx(1.0)  # the driving wheels push straight along the diagonal
