"""``env.residual_at_stop = false``: the learned correction is off while the command is a
stop, in the environment, the NumPy policy and the ONNX graph alike."""

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

FILTER = 0.5
BIAS = np.asarray([0.8, -0.6, 0.5], np.float32)  # the constant network's pre-tanh output


@pytest.fixture(scope="module")
def env():
    rand = RandomizationConfig(
        enabled=True, radius_scale=(0.97, 0.97), latency_steps=(0, 0), nominal_share=0.0
    )
    cfg = EnvConfig(
        **{**WHEEL, "residual_space": "twist", "residual_base": "feedback"}
        | {"residual_at_stop": False, "action_filter": FILTER},
        randomization=rand,
        feedback=FeedbackConfig(**PLAIN_FEEDBACK),
    )
    return MecanumEnv(dataclasses.replace(cfg, noise=dataclasses.replace(cfg.noise, scale=0.0)))


def constant_policy(env: MecanumEnv, at_stop: bool = False) -> NumpyPolicy:
    """An export of ``env``'s task whose network answers ``tanh(BIAS)`` to any observation."""
    return constant(env, BIAS, residual_at_stop=at_stop)


def _observation(policy: NumpyPolicy, command, last_action) -> np.ndarray:
    return policy.observation(
        command, np.zeros(4), 0.0, np.zeros(3), last_action, feedback_integral=0.0
    )


def test_the_export_records_the_rule(env):
    assert task_meta(env)["residual_at_stop"] is False
    assert constant_policy(env).residual_at_stop is False
    older = {k: v for k, v in task_meta(env).items() if k != "residual_at_stop"}
    older["activation"] = "tanh"
    size = env.observation_size["state"][0]
    assert NumpyPolicy([], np.zeros(size), np.ones(size), older).residual_at_stop  # older exports


def test_numpy_and_onnx_drop_the_correction_at_a_stop_only(env):
    """At a stop command the network's action is taken as 0 before the filter: what is
    applied is the last action, faded by the filter; at any other command (even a tiny one)
    the network's action passes; with the rule off it passes at a stop too."""
    policy, free = constant_policy(env), constant_policy(env, at_stop=True)
    ort = pytest.importorskip("onnxruntime")
    from mecanum_jax.deploy.onnx import to_onnx

    session = ort.InferenceSession(
        to_onnx(policy).SerializeToString(), providers=["CPUExecutionProvider"]
    )
    last = np.asarray([0.4, 0.2, -0.3], np.float32)
    net = np.tanh(BIAS)
    for command, expected in (
        ([0.0, 0.0, 0.0], FILTER * last),
        ([0.3, 0.0, 0.0], FILTER * last + (1 - FILTER) * net),
        ([0.0, 0.0, 1e-4], FILTER * last + (1 - FILTER) * net),
    ):
        obs = _observation(policy, np.asarray(command), last)
        np.testing.assert_allclose(policy.action(obs), expected, atol=1e-6)
        onnx_action, onnx_rates = session.run(
            ["action", "wheel_setpoints"],
            {"observation": obs[None], "command_age": np.full((1, 1), 50.0, np.float32)},
        )[:2]
        np.testing.assert_allclose(onnx_action[0], expected, atol=1e-6)
        np.testing.assert_allclose(
            onnx_rates[0], policy.wheel_setpoints(command, onnx_action[0], obs), atol=2e-3
        )
    stop = _observation(free, np.zeros(3), last)
    np.testing.assert_allclose(free.action(stop), FILTER * last + (1 - FILTER) * net, atol=1e-6)


@pytest.mark.full  # an environment of its own to compile: tens of seconds on 2 cores
def test_the_environment_applies_what_the_numpy_policy_computes(env):
    """Step by step through a move, a stop and a move again: the action the environment
    applies (its ``last_action``) is the NumPy policy's for the same observation, the
    correction fades during the stop, and the setpoints follow."""
    policy = constant_policy(env)
    step = jax.jit(env.step)
    state = jax.jit(env.reset)(jax.random.PRNGKey(2))
    scale = np.asarray(env.command_scale)
    commands = [
        np.asarray([0.4, 0.1, 0.0]) * scale,
        np.zeros(3),
        np.asarray([0.0, 0.3, 0.5]) * scale,
    ]
    # the network's output, before the rule and the filter (what PPO samples around)
    network = jnp.asarray(np.tanh(BIAS))
    faded = []
    for k in range(30):
        if k % 10 == 0:
            state = env.set_command(state, jnp.asarray(commands[k // 10], jnp.float32))
        obs = np.asarray(state.obs["state"])
        action = policy.action(obs)
        command = np.asarray(state.info["command"])
        expected = env.wheel_setpoints(jnp.asarray(command), jnp.asarray(action), state.info)
        np.testing.assert_allclose(
            policy.wheel_setpoints(command, action, obs), np.asarray(expected), atol=2e-3
        )
        nxt = step(state, network)
        np.testing.assert_allclose(np.asarray(nxt.info["last_action"]), action, atol=1e-6)
        if 10 <= k < 20:
            faded.append(float(np.max(np.abs(action))))
        state = nxt
    # the stop's correction fades by the filter's factor each period, from the move's
    np.testing.assert_allclose(faded, faded[0] * FILTER ** np.arange(10), rtol=1e-4)
    assert faded[0] > 0.1


@pytest.mark.parametrize(
    ("mapping", "message"),
    [
        (
            {**WHEEL, "residual": False, "residual_at_stop": False},
            r"env\.residual_at_stop = False: needs residual = true",
        ),
        ({"residual_at_stop": 1}, r"env\.residual_at_stop = 1"),
    ],
)
def test_bad_values_name_the_field(mapping, message):
    with pytest.raises(ConfigError, match=message):
        from_mapping(EnvConfig, mapping, "env").validate()
