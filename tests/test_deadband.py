"""``env.residual_deadband``: the network's action is soft-thresholded before the stop rule
and the filter, in the environment, the NumPy policy and the ONNX graph alike."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from loops import constant
from tasks import PLAIN_FEEDBACK, WHEEL

from mecanum_jax.config import ConfigError, from_mapping
from mecanum_jax.deploy.policy import NumpyPolicy
from mecanum_jax.deploy.write import task_meta
from mecanum_jax.task import EnvConfig, FeedbackConfig, MecanumEnv, RandomizationConfig

DEADBAND = 0.5
FILTER = 0.5
BIAS = np.asarray([0.8, -0.6, 0.4], np.float32)  # tanh: 0.664, -0.537, 0.380
SHRUNK = np.asarray([np.tanh(0.8) - DEADBAND, -(np.tanh(0.6) - DEADBAND), 0.0], np.float32)


@pytest.fixture(scope="module")
def env():
    rand = RandomizationConfig(enabled=True, latency_steps=(0, 0), nominal_share=0.0)
    cfg = EnvConfig(
        **{**WHEEL, "residual_space": "twist", "residual_base": "feedback"}
        | {"residual_deadband": DEADBAND, "action_filter": FILTER},
        randomization=rand,
        feedback=FeedbackConfig(**{**PLAIN_FEEDBACK, "deadband": 0.02}),  # both deadbands
    )
    return MecanumEnv(dataclasses.replace(cfg, noise=dataclasses.replace(cfg.noise, scale=0.0)))


def test_numpy_onnx_and_environment_shrink_alike(env):
    """Within ±d a component becomes 0, beyond it moves d towards 0; then the filter. The
    NumPy policy, the ONNX graph (which holds the feedback controller's deadband too) and
    the environment's applied action agree, and so do the two exports' setpoints."""
    assert task_meta(env)["residual_deadband"] == DEADBAND
    policy = constant(env, BIAS)
    last = np.asarray([0.4, 0.2, -0.3], np.float32)
    obs = policy.observation(
        np.asarray([0.3, 0.0, 0.2]), np.zeros(4), 0.0, np.zeros(3), last, feedback_integral=0.0
    )
    expected = FILTER * last + (1 - FILTER) * SHRUNK
    np.testing.assert_allclose(policy.action(obs), expected, atol=1e-6)
    ort = pytest.importorskip("onnxruntime")
    from mecanum_jax.deploy.onnx import to_onnx

    session = ort.InferenceSession(
        to_onnx(policy).SerializeToString(), providers=["CPUExecutionProvider"]
    )
    onnx_action, onnx_rates = session.run(
        ["action", "wheel_setpoints"],
        {"observation": obs[None], "command_age": np.full((1, 1), 50.0, np.float32)},
    )
    np.testing.assert_allclose(onnx_action[0], expected, atol=1e-6)
    rates = policy.wheel_setpoints(np.asarray([0.3, 0.0, 0.2]), expected, obs)
    np.testing.assert_allclose(onnx_rates[0], rates, rtol=1e-5, atol=1e-4)
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    state = env.set_command(state, jnp.asarray([0.3, 0.0, 0.2]) * env.command_scale)
    applied = jax.jit(env.step)(state, jnp.asarray(np.tanh(BIAS))).info["last_action"]
    np.testing.assert_allclose(np.asarray(applied), (1 - FILTER) * SHRUNK, atol=1e-6)


def test_no_deadband_passes_the_action_unchanged(env):
    """At 0, and in exports from before the field, the network's action passes bit for bit."""
    base = constant(env, BIAS, action_filter=0)
    meta = {k: v for k, v in base.meta.items() if k != "residual_deadband"}
    older = NumpyPolicy(base.layers, base.mean, base.std, meta)
    for policy in (constant(env, BIAS, action_filter=0, residual_deadband=0.0), older):
        obs = np.zeros(policy.observation_size, np.float32)
        obs[0] = 0.1
        np.testing.assert_array_equal(policy.action(obs), np.tanh(BIAS))


@pytest.mark.parametrize(
    ("mapping", "message"),
    [
        (
            {**WHEEL, "residual": False, "residual_deadband": 0.1},
            r"env\.residual_deadband = 0\.1: needs",
        ),
        ({"residual_deadband": 1.0}, r"env\.residual_deadband = 1\.0: must be in \[0, 1\)"),
        ({"residual_deadband": -0.01}, r"env\.residual_deadband = -0\.01"),
    ],
)
def test_bad_values_name_the_field(mapping, message):
    with pytest.raises(ConfigError, match=message):
        from_mapping(EnvConfig, mapping, "env").validate()
