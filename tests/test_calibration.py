"""Calibration recovers radii and lever arms from noisy synthetic logs, within 1%."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax import InputError
from mecanum_jax.kinematics import calibration, geometry, odometry
from mecanum_jax.kinematics import model as kinematics

TRUE_RADII = np.array([0.0506, 0.0496, 0.0503, 0.0493])  # a few % off the nominal 0.05
TRUE_SCALE = 1.03  # lever arm K 3% longer than drawn


def true_geometry(nominal):
    return nominal.replace(radii=jnp.asarray(TRUE_RADII), positions=nominal.positions * TRUE_SCALE)


def twist_log(rng, T, rotate=True):
    t = rng.uniform(-1, 1, (T, 3)) * np.array([0.8, 0.8, 2.0 if rotate else 0.0])
    return t


@pytest.fixture
def nominal(x64):
    return geometry.o_rectangle(0.05, 0.1, 0.125, dtype=jnp.float64)


def test_recovers_radii_and_lever_arm_from_twists(nominal):
    rng = np.random.default_rng(0)
    truth = true_geometry(nominal)
    t = twist_log(rng, 3000)
    rates = np.asarray(kinematics.inverse(truth, t)) + rng.normal(
        0, 0.05, (3000, 4)
    )  # encoder noise
    measured = t + rng.normal(0, 1, (3000, 3)) * np.array([0.01, 0.01, 0.03])  # mocap noise
    res = calibration.calibrate_from_twists(nominal, rates, measured)
    np.testing.assert_allclose(res.params["radii"], TRUE_RADII, rtol=0.01)
    assert res.params["lever_scale"] == pytest.approx(TRUE_SCALE, rel=0.01)
    # the reported uncertainty is honest: errors within 4 sigma, and small
    assert np.all(np.abs(res.params["radii"] - TRUE_RADII) < 4 * res.std["radii"])
    assert abs(res.params["lever_scale"] - TRUE_SCALE) < 4 * res.std["lever_scale"]
    assert np.all(res.std["radii"] / TRUE_RADII < 0.005)
    np.testing.assert_allclose(res.residual_rms, [0.01, 0.01, 0.03], rtol=0.15)
    assert res.correlation.shape == (5, 5)
    assert res.names[-1] == "lever_scale"
    # the calibrated geometry is a geometry: the forward map uses it directly
    assert res.geometry.radii.shape == (4,)


def test_recovers_per_wheel_levers(nominal):
    rng = np.random.default_rng(1)
    truth = true_geometry(nominal)
    t = twist_log(rng, 4000)
    rates = np.asarray(kinematics.inverse(truth, t)) + rng.normal(0, 0.02, (4000, 4))
    measured = t + rng.normal(0, 1, (4000, 3)) * np.array([0.005, 0.005, 0.01])
    res = calibration.calibrate_from_twists(nominal, rates, measured, fit="radii+levers")
    u = np.asarray(kinematics.roller_axes(truth))
    p = np.asarray(truth.positions)
    true_levers = p[:, 0] * u[:, 1] - p[:, 1] * u[:, 0]
    np.testing.assert_allclose(res.params["radii"], TRUE_RADII, rtol=0.01)
    np.testing.assert_allclose(res.params["levers"], true_levers, rtol=0.01)


def test_recovers_from_poses(nominal):
    rng = np.random.default_rng(2)
    truth = true_geometry(nominal)
    T, dt = 1500, 0.02
    # a smooth, turning drive: random walk in the twist
    t = np.cumsum(rng.normal(0, 0.05, (T, 3)), axis=0)
    t = np.clip(t, -1, 1) * np.array([0.6, 0.6, 1.5])
    inc = np.asarray(kinematics.inverse(truth, t)) * dt
    poses = np.asarray(odometry.integrate_increments(jnp.zeros(3), kinematics.forward(truth, inc)))
    poses = np.concatenate([np.zeros((1, 3)), poses])
    noisy = poses + rng.normal(0, 1, poses.shape) * np.array([0.003, 0.003, 0.003])
    res = calibration.calibrate_from_poses(nominal, inc, noisy)
    np.testing.assert_allclose(res.params["radii"], TRUE_RADII, rtol=0.01)
    assert res.params["lever_scale"] == pytest.approx(TRUE_SCALE, rel=0.01)


def test_no_rotation_means_lever_arm_unidentifiable(nominal):
    rng = np.random.default_rng(3)
    truth = true_geometry(nominal)
    t = twist_log(rng, 2000, rotate=False)
    rates = np.asarray(kinematics.inverse(truth, t)) + rng.normal(0, 0.05, (2000, 4))
    measured = t + rng.normal(0, 0.01, (2000, 3))
    with pytest.raises(
        calibration.UnidentifiableError, match=r"lever arm: not identifiable.*rotation"
    ):
        calibration.calibrate_from_twists(nominal, rates, measured)
    # the radii alone are still fine from that log
    res = calibration.calibrate_from_twists(nominal, rates, measured, fit="radii")
    np.testing.assert_allclose(res.params["radii"], TRUE_RADII, rtol=0.01)


def test_bad_logs_rejected(nominal):
    with pytest.raises(InputError, match=r"twists: 5 rows do not match wheel_rates's 6"):
        calibration.calibrate_from_twists(nominal, np.zeros((6, 4)), np.zeros((5, 3)))
    with pytest.raises(InputError, match=r"zero-length"):
        calibration.calibrate_from_twists(nominal, np.zeros((0, 4)), np.zeros((0, 3)))
    bad = np.zeros((3, 4))
    bad[1, 2] = np.nan
    with pytest.raises(InputError, match=r"wheel_rates\[1, 2\] = nan"):
        calibration.calibrate_from_twists(nominal, bad, np.zeros((3, 3)))
    with pytest.raises(
        InputError, match=r"poses: 4 rows do not match wheel_increments's 4 \(expected 5\)"
    ):
        calibration.calibrate_from_poses(nominal, np.zeros((4, 4)), np.zeros((4, 3)))
    with pytest.raises(calibration.UnidentifiableError):
        calibration.calibrate_from_twists(nominal, np.zeros((10, 4)), np.zeros((10, 3)))


def test_jax_is_importable_without_x64_for_float32_calibration():
    nominal = geometry.o_rectangle(0.05, 0.1, 0.125)
    rng = np.random.default_rng(4)
    t = twist_log(rng, 2000)
    truth = true_geometry(nominal)
    rates = np.asarray(kinematics.inverse(truth, t.astype(np.float32)))
    measured = t + rng.normal(0, 0.01, (2000, 3))
    res = calibration.calibrate_from_twists(nominal, rates, measured)
    assert res.geometry.dtype == jnp.float32
    np.testing.assert_allclose(res.params["radii"], TRUE_RADII, rtol=0.01)
    assert jax.numpy.isfinite(res.params["lever_scale"])
