"""The accelerometer-odometry velocity observer (``env.velocity_observer_tau``) and the
accelerometer's bias (``env.noise.accel_bias``), on the environment's own physics."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.control.spec import entry_slice
from mecanum_jax.deploy.plant import Measurement, SensorChannel
from mecanum_jax.task import EnvConfig, MecanumEnv
from mecanum_jax.task.observations import NoiseConfig
from mecanum_jax.task.references import REFERENCES


def _env(**overrides) -> MecanumEnv:
    task = dataclasses.replace(EnvConfig(), physics_impl="jax", path_tau=0.0, **overrides)
    return MecanumEnv(task.validate("env"))


def test_on_ice_the_observer_sees_the_slip_the_odometry_misses():
    """A start and a turning drive on a floor of friction 0.1, exact sensors, no
    latency, with the `feedback` controller: the observer's planar velocity stays near the
    true one while the wheels spin far ahead of it (the turn term's sign included: the
    wrong one drifts 0.5 m/s in the turn; without it, 0.27)."""
    env = _env(velocity_observer_tau=10.0)
    params = env.nominal_params._replace(friction=jnp.full(4, 0.1))
    state = env.reset_to(jax.random.PRNGKey(0), params, jnp.asarray(0), jnp.zeros(4))
    feedback = jnp.asarray(REFERENCES.index("feedback"))
    n, scale = env.control.n_wheels, np.asarray(env.control.command_scale)
    step = jax.jit(env.step)
    at = entry_slice(env.privileged_layout, "true_twist")
    errors: dict[str, list[np.ndarray]] = {"observer": [], "odometry": []}
    for t in range(100):
        command = jnp.asarray([1.2, 0.0, 0.0] if t < 50 else [0.8, 0.4, 1.5])
        state = step(env.set_command(state, command), jnp.zeros(3), feedback)
        true = np.asarray(state.obs["privileged_state"][at])
        odometry = np.asarray(state.info["history"][0, n + 4 : n + 6]) * scale[:2]
        errors["observer"].append(
            np.asarray(state.info["velocity_estimate"]) - true[:2] * scale[:2]
        )
        errors["odometry"].append(odometry - true[:2] * scale[:2])
    rms = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in errors.items()}
    assert rms["odometry"] > 0.3  # the wheels slip: there is something to see
    assert rms["observer"] < 0.1 * rms["odometry"], rms


def test_the_bias_is_constant_in_an_episode_and_leaves_the_other_noise_alone():
    env = _env()
    key, params, latency = jax.random.PRNGKey(3), env.nominal_params, jnp.asarray(0)
    std = np.asarray(NoiseConfig().std())
    plain = env.reset_to(key, params, latency, jnp.asarray(std))
    biased = env.reset_to(key, params, latency, jnp.asarray([*std[:3], 0.1]))
    assert np.all(np.asarray(plain.info["accel_bias"]) == 0.0)
    bias = np.asarray(biased.info["accel_bias"])
    assert 0.0 < np.abs(bias).max() < 0.5
    step = jax.jit(env.step)
    n = env.control.n_wheels
    for _ in range(5):
        plain, biased = step(plain, jnp.zeros(3)), step(biased, jnp.zeros(3))
        a, b = np.asarray(plain.info["history"][0]), np.asarray(biased.info["history"][0])
        np.testing.assert_array_equal(a[: n + 1], b[: n + 1])  # encoders and gyro
        np.testing.assert_allclose((b - a)[n + 1 : n + 4] * env.control.gravity, bias, atol=1e-5)
    assert np.array_equal(np.asarray(biased.info["accel_bias"]), bias)


def test_the_robot_side_channel_draws_a_bias_only_when_asked():
    zero = np.zeros(3)
    m = Measurement(np.zeros(4), 0.0, np.array([0.0, 0.0, 9.81]), np.zeros(4), zero, zero)
    three, four_zero = (
        SensorChannel((0.3, 0.02, 0.3), seed=1),
        SensorChannel((0.3, 0.02, 0.3, 0.0), seed=1),
    )
    for ch in (three, four_zero):
        ch.reset(m)
    np.testing.assert_array_equal(three.read(m)[2], four_zero.read(m)[2])  # the same stream
    biased = SensorChannel((0.0, 0.0, 0.0, 0.1), seed=1)
    first = biased.reset(m)[2]
    assert np.abs(first - m.accel).max() > 0.0
    np.testing.assert_allclose(biased.read(m)[2], first)  # constant through the episode
