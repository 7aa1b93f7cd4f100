"""``env.obs_history``: a policy (a student) observes the sensor frames before the one it
sees now, newest first, and the robot-side loop (NumPy and ONNX) builds the same
observation from the readings it keeps."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from loops import network_free
from tasks import PLAIN_FEEDBACK, WHEEL

from mecanum_jax.config import ConfigError
from mecanum_jax.control import ControllerState, policy_layout
from mecanum_jax.control import step as ctl
from mecanum_jax.deploy.loop import Controller
from mecanum_jax.task import EnvConfig, FeedbackConfig, MecanumEnv, RandomizationConfig


@pytest.mark.parametrize("value", [-1, 51])
def test_a_bad_history_length_names_the_field(value):
    with pytest.raises(ConfigError, match=rf"env\.obs_history.*{value}"):
        EnvConfig(obs_history=value).validate()


def test_the_history_is_the_frames_before_the_observed_one_newest_first():
    """With a latency of 1 the observed frame is one period old; the history is the
    frames before it, each as delayed."""
    history = jnp.arange(6 * 2, dtype=jnp.float32).reshape(6, 2)  # frame k = [2k, 2k+1]
    state = ControllerState(*(None,) * 3, history, *(None,) * 4)
    latency = jnp.asarray(1, jnp.int32)
    np.testing.assert_array_equal(ctl.observed_frame(state, latency, jnp), [2.0, 3.0])
    past = jnp.take(history, latency + 1 + jnp.arange(3), axis=0).reshape(-1)
    np.testing.assert_array_equal(past, [4, 5, 6, 7, 8, 9])
    layout = policy_layout(4, 3, False, True, history=3)
    assert layout[-2:] == (("feedback_integral", 1), ("sensor_history", 3 * 11))
    assert policy_layout(4, 3, False, True)[-1] == ("feedback_integral", 1)


def _student_env(history: int) -> MecanumEnv:
    # wheels 5% small and no latency: the robot-side loop reads the newest frames
    rand = RandomizationConfig(
        enabled=True, radius_scale=(0.95, 0.95), latency_steps=(0, 0), nominal_share=0.0
    )
    twist = {**WHEEL, "residual_space": "twist", "residual_base": "feedback"}
    cfg = EnvConfig(
        **twist,
        randomization=rand,
        obs_history=history,
        feedback=FeedbackConfig(**PLAIN_FEEDBACK),
    )
    return MecanumEnv(dataclasses.replace(cfg, noise=dataclasses.replace(cfg.noise, scale=0.0)))


@pytest.mark.full  # an environment of its own to compile: tens of seconds on 2 cores
def test_environment_numpy_and_onnx_loops_observe_the_same_history():
    """The NumPy and the ONNX control loops drive the environment tick by tick through
    command changes: at every tick their observation, history included, is the
    environment's, and their setpoints agree."""
    env = _student_env(3)
    assert env.layout[-1] == ("sensor_history", 3 * env.sensor_size)
    policy = network_free(env)
    assert policy.obs_history == 3
    ort = pytest.importorskip("onnxruntime")
    from mecanum_jax.deploy.onnx import to_onnx

    session = ort.InferenceSession(
        to_onnx(policy).SerializeToString(), providers=["CPUExecutionProvider"]
    )
    loops = Controller(policy), Controller(policy, session)
    step = jax.jit(env.step)
    state = jax.jit(env.reset)(jax.random.PRNGKey(6))
    scale = np.asarray(env.command_scale)
    commands = [np.asarray(c) * scale for c in ([0.3, 0.0, 0.7], [0.0, 0.4, -0.5])]
    frames = []
    for k in range(16):
        if k % 8 == 0:
            state = env.set_command(state, jnp.asarray(commands[k // 8], jnp.float32))
        sens = env.robot.sensors(state.pipeline_state)
        reading = (sens.wheel_rate, sens.gyro_z, sens.accel)
        frames.insert(0, policy.sensor_frame(*reading))
        out = [c.step(state.info["command"], *reading) for c in loops]
        for c in loops:
            np.testing.assert_allclose(c.observation, state.obs["state"], rtol=1e-5, atol=1e-5)
        past = np.asarray((frames[1:] + [frames[-1]] * 3)[:3])  # after a reset: the first
        seen = loops[0].observation[-past.size :].reshape(past.shape)
        np.testing.assert_allclose(seen, past, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(out[1][0], out[0][0], rtol=1e-4, atol=2e-3)
        state = step(state, jnp.asarray(out[0][1]))
    assert np.ptp(np.asarray(frames)[:, 0]) > 0.1  # the history saw the wheels move
    with pytest.raises(ValueError, match=r"sensor_history: shape None, expected \(3, 11\)"):
        policy.observation(np.zeros(3), np.zeros(4), 0.0, np.zeros(3), np.zeros(3), None, 0.0)
