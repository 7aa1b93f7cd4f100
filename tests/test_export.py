"""mecanum-export's files against the environment: the NumPy policy and its control loop,
the ONNX graph, the residual's setpoints, the action filter and the observed integrators;
the errors of bad exports."""

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from loops import network_free
from tasks import WHEEL

from mecanum_jax.deploy import policy as deploy
from mecanum_jax.task import EnvConfig, MecanumEnv
from train.cli import export
from train.learner.policy import load_policy


def test_export_round_trip_in_numpy_alone(full_run, tmp_path, learner):
    """The exported policy, run by NumPy in a process without JAX, MuJoCo or Brax,
    computes the JAX policy's actions."""
    run, _ = full_run
    path = tmp_path / "export" / "policy.npz"
    assert export.main([str(run.dir), str(path)]) == 0
    act, _ = load_policy(run.dir)
    rng = np.random.default_rng(3)
    obs = {
        k: (3 * rng.normal(size=(256, *shape))).astype(np.float32)
        for k, shape in learner.env.observation_size.items()
    }
    expected = np.asarray(act(obs))
    np.save(tmp_path / "obs.npy", obs["state"])
    script = textwrap.dedent(
        f"""
        import importlib.abc, importlib.util, sys
        import numpy as np

        class Block(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path, target=None):
                if name.split(".")[0] in ("jax", "jaxlib", "mujoco", "brax", "flax", "mecanum_jax"):
                    raise ImportError("blocked: " + name)

        sys.meta_path.insert(0, Block())
        sys.path.insert(0, {str(path.parent / "mecanum_robot.zip")!r})
        import mecanum_policy as mp
        policy = mp.load({str(path)!r})
        actions = policy.action(np.load({str(tmp_path / "obs.npy")!r}))
        np.save({str(tmp_path / "numpy_actions.npy")!r}, actions)
        assert not any(m.split(".")[0] in ("jax", "mujoco", "brax") for m in sys.modules)
        """
    )
    env = dict(os.environ, PYTHONPATH="")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr
    got = np.load(tmp_path / "numpy_actions.npy")
    assert np.abs(expected).max() > 1e-3  # a non-trivial policy
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)


@pytest.mark.full
def test_exported_control_loop_matches_the_environment(full_run, tmp_path, learner):
    run, _ = full_run
    path = tmp_path / "policy.npz"
    assert export.main([str(run.dir), str(path)]) == 0
    policy = deploy.load(path)
    env = learner.env
    rng = np.random.default_rng(5)
    for _ in range(20):
        command = rng.normal(size=3).astype(np.float32) * np.asarray(env.command_scale)
        action = rng.uniform(-1, 1, env.action_size).astype(np.float32)
        np.testing.assert_allclose(
            policy.wheel_setpoints(command, action),
            np.asarray(env.wheel_setpoints(jnp.asarray(command), jnp.asarray(action))),
            rtol=1e-5,
            atol=1e-4,
        )
    # the observation built from raw measurements is the environment's (noise-free, no lag)
    cfg = env.config.nominal()
    nominal = MecanumEnv(cfg)
    state = nominal.reset(jax.random.PRNGKey(1))
    state = nominal.step(state, jnp.full(nominal.n_wheels, 0.3))
    sens = nominal.robot.sensors(state.pipeline_state)
    obs = policy.observation(
        state.info["command"], sens.wheel_rate, sens.gyro_z, sens.accel, state.info["last_action"]
    )
    np.testing.assert_allclose(obs, np.asarray(state.obs["state"]), rtol=1e-5, atol=1e-5)


def test_exported_file_errors(tmp_path):
    with pytest.raises(deploy.ExportError, match="no such file"):
        deploy.load(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(deploy.ExportError, match="unreadable"):
        deploy.load(tmp_path / "junk.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(deploy.ExportError, match="not an export"):
        deploy.load(tmp_path / "other.npz")
    assert export.main(["baseline", str(tmp_path / "p.txt")]) == 2


def test_exported_twist_residual_setpoints_match_the_environment():
    """The NumPy control loop applies a twist-space residual as the environment does."""
    env = MecanumEnv(EnvConfig(**{**WHEEL, "residual_space": "twist"}))
    policy = network_free(env)
    rng = np.random.default_rng(3)
    for _ in range(20):
        command = rng.normal(size=3).astype(np.float32) * np.asarray(env.command_scale)
        action = rng.uniform(-1, 1, 3).astype(np.float32)
        np.testing.assert_allclose(
            policy.wheel_setpoints(command, action),
            np.asarray(env.wheel_setpoints(jnp.asarray(command), jnp.asarray(action))),
            rtol=1e-5,
            atol=1e-4,
        )


@pytest.mark.full  # compiles an environment of its own
def test_exported_action_filter_matches_the_environment_in_numpy_and_onnx():
    """action_filter = f: the NumPy policy and its ONNX graph return f·last_action (read
    from the observation) + (1 − f)·network, the action the environment applies."""
    f = 0.8
    env = MecanumEnv(EnvConfig(**{**WHEEL, "action_filter": f}).nominal())
    policy = network_free(env)  # no hidden layer: network = tanh(first entries)
    rng = np.random.default_rng(6)
    obs = rng.normal(size=(64, env.observation_size["state"][0])).astype(np.float32)
    names = [name for name, _ in env.layout]
    start = sum(size for _, size in env.layout[: names.index("last_action")])
    last = obs[:, start : start + env.action_size]
    network = np.tanh(obs[:, : env.action_size])
    expected = f * last + (1 - f) * network
    np.testing.assert_allclose(policy.action(obs), expected, rtol=1e-5, atol=1e-6)
    # the environment applies the same blend of its last action and a new one
    state = env.reset(jax.random.PRNGKey(0))
    state = state.replace(info={**state.info, "last_action": jnp.asarray(last[0])})
    stepped = env.step(state, jnp.asarray(network[0]))
    np.testing.assert_allclose(stepped.info["last_action"], expected[0], rtol=1e-5, atol=1e-6)
    ort = pytest.importorskip("onnxruntime")
    from mecanum_jax.deploy.onnx import to_onnx

    session = ort.InferenceSession(
        to_onnx(policy).SerializeToString(), providers=["CPUExecutionProvider"]
    )
    held = np.full((len(obs), 1), 50.0, np.float32)  # a command held long
    (action,) = session.run(["action"], {"observation": obs, "command_age": held})
    np.testing.assert_allclose(action, expected, rtol=1e-5, atol=1e-6)


@pytest.mark.full
def test_yaw_error_integral_observation_matches_the_control_loop():
    """yaw_integral_tau > 0: the environment integrates the measured yaw-rate error as a
    robot-side loop would (deploy.yaw_integral_step), and observes it last."""
    env = MecanumEnv(EnvConfig(**WHEEL, yaw_integral_tau=0.5).nominal())
    assert env.layout[-1] == ("yaw_error_integral", 1)
    policy = network_free(env)
    state = env.reset(jax.random.PRNGKey(2))
    state = env.set_command(state, jnp.array([0.2, 0.0, 1.5]))
    integral = 0.0
    step = jax.jit(env.step)
    for k in range(6):
        tracked = np.asarray(state.info["command"])
        action = jnp.full(env.action_size, 0.01 * (-1) ** k)
        state = step(state, action)
        sens = env.robot.sensors(state.pipeline_state)
        integral = policy.yaw_integral_step(integral, tracked, float(sens.gyro_z))
        assert float(state.info["yaw_integral"]) == pytest.approx(integral, rel=1e-4, abs=1e-6)
        obs = policy.observation(
            tracked, sens.wheel_rate, sens.gyro_z, sens.accel, np.asarray(action), integral
        )
        np.testing.assert_allclose(obs, np.asarray(state.obs["state"]), rtol=1e-5, atol=1e-5)
    assert abs(integral) > 1e-4  # the spin-up from rest left a measurable yaw error
    with pytest.raises(ValueError, match="yaw_integral = None"):
        policy.observation(tracked, sens.wheel_rate, sens.gyro_z, sens.accel, np.asarray(action))


def test_onnx_export_matches_the_jax_policy_and_the_control_loop(full_run, tmp_path, learner):
    """``mecanum-export --format onnx``: onnxruntime maps raw observations to the JAX
    policy's actions, and to the NumPy control loop's wheel-rate setpoints."""
    ort = pytest.importorskip("onnxruntime")
    run, _ = full_run
    path = tmp_path / "policy.onnx"
    assert export.main([str(run.dir), str(path), "--format", "onnx"]) == 0
    assert export.main([str(run.dir), str(tmp_path / "p.npz")]) == 0
    act, _ = load_policy(run.dir)
    rng = np.random.default_rng(5)
    obs = {
        k: (3 * rng.normal(size=(128, *shape))).astype(np.float32)
        for k, shape in learner.env.observation_size.items()
    }
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    action, setpoints = session.run(
        ["action", "wheel_setpoints"],
        {"observation": obs["state"], "command_age": np.full((128, 1), 50.0, np.float32)},
    )
    expected = np.asarray(act(obs))
    assert np.abs(expected).max() > 1e-3  # a non-trivial policy
    np.testing.assert_allclose(action, expected, rtol=1e-5, atol=1e-5)
    numpy_policy = deploy.load(tmp_path / "p.npz")
    commands = obs["state"][:, :3] * numpy_policy.command_scale
    loop = numpy_policy.wheel_setpoints(commands, action)  # batched over rows
    assert np.abs(loop).max() >= numpy_policy.max_rates.max() * 0.999  # saturation exercised
    np.testing.assert_allclose(setpoints, loop, rtol=1e-5, atol=1e-4)
    # the file carries its own description of the observation layout
    meta = json.loads({p.key: p.value for p in _onnx_props(path)}["mecanum_policy_meta"])
    assert meta["observation_layout"] == [list(x) for x in learner.env.layout]
    # wrong suffix: refused naming the field and the value, nothing written
    assert export.main([str(run.dir), str(tmp_path / "x.npz"), "--format", "onnx"]) == 2
    assert not (tmp_path / "x.npz").exists()


def _onnx_props(path):
    import onnx

    return onnx.load(str(path)).metadata_props
