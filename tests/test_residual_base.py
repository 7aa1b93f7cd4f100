"""A residual on the ``feedback`` controller: its zero action is that controller, and the
policy observes the controller's integrator."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from loops import network_free
from tasks import PLAIN_FEEDBACK, WHEEL

from mecanum_jax.config import ConfigError
from mecanum_jax.deploy.loop import Controller
from mecanum_jax.task import EnvConfig, FeedbackConfig, MecanumEnv, RandomizationConfig

FEEDBACK = jnp.asarray(2)  # index of "feedback" in REFERENCES
POLICY = jnp.asarray(-1)  # no reference: the policy's action (the same compiled step)
DT = EnvConfig().control_dt


@pytest.fixture(scope="module")
def env():
    # wheels 4% small: the yaw rate falls short, so the integrator has work to do
    rand = RandomizationConfig(
        enabled=True, radius_scale=(0.96, 0.96), latency_steps=(1, 1), nominal_share=0.0
    )
    twist = {**WHEEL, "residual_space": "twist", "residual_base": "feedback"}
    cfg = EnvConfig(**twist, randomization=rand, feedback=FeedbackConfig(**PLAIN_FEEDBACK))
    return MecanumEnv(cfg)


@pytest.fixture(scope="module")
def step(env):
    """``env.step`` with a reference index, traced: one program for the policy (index
    -1) and the references. Training's step (no index) differs from it only by that
    ``where``; tests/test_env.py and the full tier's tests run it."""
    return jax.jit(env.step)


@pytest.fixture(scope="module")
def reset(env):
    """``env.reset``, traced, its state's weakly typed scalars (reward, metrics, the
    integrator) made strong, as ``step`` returns them: ``step`` then compiles once, not
    once for a reset state and again for its own."""
    traced = jax.jit(env.reset)

    def strong(x):
        return x.astype(x.dtype) if getattr(x, "weak_type", False) else x

    return lambda key: jax.tree.map(strong, traced(key))


def test_the_zero_residual_is_the_feedback_controller(env, reset, step):
    state = reset(jax.random.PRNGKey(3))
    state = env.set_command(state, jnp.asarray([0.3, 0.1, 1.5]))
    ref = state
    zero = jnp.zeros(env.action_size)
    for _ in range(40):
        state = step(state, zero, POLICY)
        ref = step(ref, zero, FEEDBACK)
        np.testing.assert_allclose(
            state.pipeline_state.data.qpos, ref.pipeline_state.data.qpos, atol=1e-6
        )
        np.testing.assert_allclose(
            state.info["feedback_integral"], ref.info["feedback_integral"], rtol=1e-5, atol=1e-6
        )
    assert abs(float(state.info["feedback_integral"])) > 0.02  # it integrated something


def test_the_policy_observes_the_integrator(env, reset, step):
    names = [name for name, _ in env.layout]
    assert names[-1] == "feedback_integral"
    state = reset(jax.random.PRNGKey(0))
    state = env.set_command(state, jnp.asarray([0.0, 0.0, 2.0]))
    for _ in range(10):
        state = step(state, jnp.zeros(env.action_size), POLICY)
    observed = float(state.obs["state"][-1]) * float(env.command_scale[2])
    assert observed == pytest.approx(float(state.info["feedback_integral"]), rel=1e-5)
    assert observed != 0.0


def test_a_residual_changes_the_setpoints_around_the_feedback_controller(env, reset):
    state = reset(jax.random.PRNGKey(1))
    cmd = jnp.asarray([0.2, 0.0, 0.5])
    base = env.wheel_setpoints(cmd, jnp.zeros(3), state.info)
    up = env.wheel_setpoints(cmd, jnp.asarray([0.0, 0.0, 0.5]), state.info)
    assert not np.allclose(base, up)
    with pytest.raises(ValueError, match="needs the state"):
        env.wheel_setpoints(cmd, jnp.zeros(3))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"residual_base": "pid"}, r"env\.residual_base = 'pid'"),
        (
            {**WHEEL, "residual_base": "feedback", "residual": False},
            r"env\.residual_base = 'feedback'",
        ),
    ],
)
def test_bad_residual_base_is_rejected(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        EnvConfig(**kwargs).validate()


def test_numpy_nearest_feasible_matches_the_library(env):
    """The controller's nearest feasible twist, in NumPy and jitted JAX over a 500-row
    batch, is the library's (kinematics.limits) on twists beyond the reach (within the
    limits less the default headroom, ``feedback.margin``)."""
    from mecanum_jax.control import step as ctl
    from mecanum_jax.kinematics import limits

    spec = env.control
    w = env.config.feedback.omega_weight
    rng = np.random.default_rng(0)
    twists = (rng.normal(size=(500, 3)) * 1.5 * np.asarray(env.command_scale)).astype(np.float32)
    reach = env.max_rates * (1.0 - env.config.feedback.margin)
    expected = limits.nearest_feasible(env.geometry, jnp.asarray(twists), reach, w)
    assert np.mean(np.any(np.abs(twists - np.asarray(expected)) > 1e-3, axis=1)) > 0.3
    np.testing.assert_allclose(
        ctl.nearest_feasible(spec, twists, np), expected, rtol=1e-4, atol=1e-4
    )
    with jax.numpy_rank_promotion("allow"):
        jitted = jax.jit(lambda t: ctl.nearest_feasible(spec, t, jnp))(jnp.asarray(twists))
    np.testing.assert_allclose(jitted, expected, rtol=1e-4, atol=1e-4)


def test_a_margin_projects_onto_the_limits_shrunk_by_it():
    """``feedback.margin``: the twist the wheels reach at (1 − margin) of their limits,
    read back from the export's metadata, on twists beyond and within the reach."""
    from mecanum_jax.control import step as ctl
    from mecanum_jax.kinematics import limits

    cfg = EnvConfig(feedback=FeedbackConfig(margin=0.1))
    menv = MecanumEnv(cfg)
    spec = menv.control  # built from the metadata an export carries
    assert spec.feedback.margin == 0.1
    rng = np.random.default_rng(1)
    twists = (rng.normal(size=(500, 3)) * np.asarray(menv.command_scale)).astype(np.float32)
    w = cfg.feedback.omega_weight
    shrunk = limits.nearest_feasible(menv.geometry, jnp.asarray(twists), 0.9 * menv.max_rates, w)
    full = limits.nearest_feasible(menv.geometry, jnp.asarray(twists), menv.max_rates, w)
    assert np.mean(np.any(np.abs(np.asarray(shrunk) - np.asarray(full)) > 1e-3, axis=1)) > 0.3
    np.testing.assert_allclose(ctl.nearest_feasible(spec, twists, np), shrunk, rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"hold_s": -0.1}, r"env\.feedback\.hold_s = -0\.1: must be >= 0"),
        ({"ki": -1.0}, r"env\.feedback\.ki = -1\.0: must be >= 0"),
        ({"deadband": -0.01}, r"env\.feedback\.deadband = -0\.01: must be >= 0"),
        ({"reset": 1}, r"env\.feedback\.reset = 1: must be true or false"),
        ({"margin": 1.0}, r"env\.feedback\.margin = 1\.0: must be in \[0, 1\)"),
        ({"margin": -0.05}, r"env\.feedback\.margin = -0\.05: must be in \[0, 1\)"),
    ],
)
def test_bad_feedback_settings_name_the_field(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        EnvConfig(feedback=FeedbackConfig(**kwargs)).validate()


def _sensed(spec, commands, integral=0.2):
    """The controller state after each command of ``commands`` (NumPy, at rest), starting
    from ``integral`` in the ``feedback`` integrator; each state's integrator is then set
    to 0.1, as if it had integrated."""
    from mecanum_jax.control import step as ctl

    frame = np.zeros(spec.n_wheels + 7, np.float32)
    state = ctl.initial_state(spec, frame, commands[0], 1, np)
    state = state._replace(feedback_integral=np.float32(integral))
    out = [state]
    for command in commands[1:]:
        state = ctl.sense(spec, state, frame, command, 0, np)
        out.append(state)
        state = state._replace(feedback_integral=np.float32(0.1))
    return out


def test_the_command_age_counts_steps_since_a_change_and_holds_the_integrator(env):
    """The controller's command age is 0 at a reset and at a change, one more per period;
    the integrator holds while the age is below ``hold_s`` in control periods (3 here),
    then integrates; without ``reset`` a change keeps it."""
    from mecanum_jax.control import step as ctl

    spec = dataclasses.replace(
        env.control, feedback=dataclasses.replace(env.control.feedback, hold_steps=3)
    )
    a, b = np.asarray([0.3, 0.0, 0.0], np.float32), np.asarray([0.3, 0.0, 0.5], np.float32)
    states = _sensed(spec, [a, a, a, b, b, b, b, b])
    assert [int(s.command_age) for s in states] == [0, 1, 2, 0, 1, 2, 3, 4]
    assert float(states[3].feedback_integral) == pytest.approx(0.1)  # carried: no reset
    gyro, gains = np.zeros(1, np.float32), ctl.gains(spec, np)
    for s in states[3:]:
        age = np.asarray(s.command_age)[..., None]
        integral = np.asarray([0.1], np.float32)
        after = ctl.feedback_integral_step(spec, s.command, gyro, integral, gains, age, np)
        held = float(after[0]) == pytest.approx(0.1)
        assert held == (int(s.command_age) < 3), int(s.command_age)


def test_the_integrator_restarts_at_each_command_change_with_reset(env):
    """``feedback.reset``: the integrator is 0 after a change, kept while the command
    stays, with or without the hold."""
    a, b = np.asarray([0.3, 0.0, 0.0], np.float32), np.asarray([0.3, 0.0, 0.5], np.float32)
    for hold in (0, 3):
        fb = dataclasses.replace(env.control.feedback, hold_steps=hold, reset=True)
        states = _sensed(dataclasses.replace(env.control, feedback=fb), [a, a, b, b, a])
        values = [float(s.feedback_integral) for s in states]
        assert values == pytest.approx([0.2, 0.2, 0.0, 0.1, 0.0])


def _hold_env(hold_s: float, deadband: float = 0.0, reset: bool = False) -> MecanumEnv:
    rand = RandomizationConfig(  # a floor from PRNGKey(4) on which the integrator works
        enabled=True,
        friction=(0.1, 1.2),
        radius_scale=(0.95, 0.95),
        latency_steps=(0, 0),
        nominal_share=0.0,
    )
    cfg = EnvConfig(
        **{**WHEEL, "residual_space": "twist", "residual_base": "feedback"},
        randomization=rand,
        feedback=FeedbackConfig(hold_s=hold_s, deadband=deadband, reset=reset),
    )
    return MecanumEnv(dataclasses_replace_noise_off(cfg))


@pytest.mark.full  # an environment of its own to compile: tens of seconds on 2 cores
@pytest.mark.parametrize(
    ("hold_s", "deadband", "restart"),
    [(0.0, 0.0, False), (0.1, 0.0, False), (0.1, 0.02, False), (0.1, 0.0, True)],
)
def test_environment_numpy_and_onnx_agree_step_by_step(hold_s, deadband, restart):
    """Setpoints, the integrator and the observation, step by step, through a command
    change and commands beyond the wheels' reach (the anti-windup and the projection), and
    with the integrator held for ``hold_s`` after each change (the caller holds the ONNX
    graph's integrator, which cannot know the command's age), and the correction's
    ``deadband``, and restarted at each change (``restart``, ``feedback.reset``: the
    observation the NumPy policy reads it from restarts with it)."""
    env = _hold_env(hold_s, deadband, restart)
    hold_steps = round(hold_s / env.config.control_dt)
    policy = network_free(env)
    assert policy.feedback_hold_steps == hold_steps
    assert policy.feedback_reset == restart
    ort = pytest.importorskip("onnxruntime")
    from mecanum_jax.deploy.onnx import to_onnx

    session = ort.InferenceSession(
        to_onnx(policy).SerializeToString(), providers=["CPUExecutionProvider"]
    )
    step = jax.jit(env.step)
    state = jax.jit(env.reset)(jax.random.PRNGKey(4))
    scale = np.asarray(env.command_scale)
    commands = [np.asarray([0.2, 0.0, 0.6]) * scale, np.asarray([1.1, 0.0, 0.9]) * scale]
    rng = np.random.default_rng(1)
    integral, seen_hold = 0.0, False
    for k in range(30):
        if k % 15 == 0:
            state = env.set_command(state, jnp.asarray(commands[k // 15], jnp.float32))
            if restart:  # restarted, in the state and in what the policy observes
                assert float(state.info["feedback_integral"]) == 0.0
                assert k == 0 or abs(integral) > 0.05
                assert float(policy.feedback_twist(np.asarray(state.obs["state"]))[2]) == 0.0
        obs = np.asarray(state.obs["state"])
        action = rng.uniform(-0.3, 0.3, env.action_size).astype(np.float32)
        command = np.asarray(state.info["command"])
        expected = np.asarray(env.wheel_setpoints(jnp.asarray(command), action, state.info))
        np.testing.assert_allclose(
            policy.wheel_setpoints(command, action, obs), expected, rtol=1e-4, atol=2e-3
        )
        nxt = step(state, jnp.asarray(action))
        before, age = float(state.info["feedback_integral"]), k % 15
        integral = float(policy.feedback_integral_step(obs, age))
        # (NumPy reads the integrator back from the float32 observation: equal to ~1e-7)
        if age < hold_steps:
            assert integral == pytest.approx(before, abs=1e-6)  # held through the transient
        else:
            seen_hold |= abs(integral - before) < 1e-6 and k % 15 > 0
        assert integral == pytest.approx(float(nxt.info["feedback_integral"]), abs=1e-5)
        sens = env.robot.sensors(nxt.pipeline_state)
        rebuilt = policy.observation(
            nxt.info["command"], sens.wheel_rate, sens.gyro_z, sens.accel, action,
            feedback_integral=integral,
        )  # fmt: skip
        np.testing.assert_allclose(rebuilt, np.asarray(nxt.obs["state"]), rtol=1e-5, atol=1e-5)
        # ONNX: the action of a network-free graph is tanh of the first entries; feed the
        # graph's own action back through NumPy's loop for the setpoints
        onnx_action, onnx_setpoints, onnx_integral = session.run(
            ["action", "wheel_setpoints", "feedback_integral"],
            {"observation": obs[None], "command_age": np.full((1, 1), age, np.float32)},
        )
        np.testing.assert_allclose(
            onnx_setpoints[0], policy.wheel_setpoints(command, onnx_action[0], obs), atol=2e-3
        )
        assert float(onnx_integral[0, 0]) == pytest.approx(integral, abs=1e-5)
        state = nxt
    # the correction got through any deadband (with restart: grew again after the change)
    assert abs(integral) > (0.02 if restart else 0.05 + deadband)
    assert seen_hold  # beyond reach, the anti-windup held the integrator at least once


def dataclasses_replace_noise_off(cfg: EnvConfig) -> EnvConfig:
    import dataclasses

    return dataclasses.replace(cfg, noise=dataclasses.replace(cfg.noise, scale=0.0))


@pytest.mark.full  # an environment of its own to compile: tens of seconds on 2 cores
@pytest.mark.parametrize("restart", [False, True])
def test_the_control_loop_holds_the_integrator_as_the_environment_does(restart):
    """The robot-side loop (NumPy) drives the environment tick by tick through command
    changes, with the integrator held for 0.1 s after each, and restarted at each with
    ``restart`` (``feedback.reset``): its observation, integrator included, is the
    environment's at every tick."""
    env = _hold_env(0.1, reset=restart)
    ctrl = Controller(network_free(env))
    step = jax.jit(env.step)
    state = jax.jit(env.reset)(jax.random.PRNGKey(5))
    scale = np.asarray(env.command_scale)
    commands = [np.asarray(c) * scale for c in ([0.3, 0.0, 0.7], [0.0, 0.4, -0.5], [0.5, 0, 0])]
    held, carried = 0, []
    for k in range(36):
        if k % 12 == 0:
            carried.append(float(state.info["feedback_integral"]))
            state = env.set_command(state, jnp.asarray(commands[k // 12], jnp.float32))
        sens = env.robot.sensors(state.pipeline_state)
        _, action = ctrl.step(state.info["command"], sens.wheel_rate, sens.gyro_z, sens.accel)
        np.testing.assert_allclose(ctrl.observation, state.obs["state"], rtol=1e-5, atol=1e-5)
        if k % 12 == 0:  # what the new command starts from
            start = float(state.info["feedback_integral"])
            assert start == (0.0 if restart else pytest.approx(carried[-1]))
        nxt = step(state, jnp.asarray(action))
        held += float(nxt.info["feedback_integral"]) == float(state.info["feedback_integral"])
        state = nxt
    assert held >= 3 * 5  # five periods after each of the three changes
    assert min(abs(c) for c in carried[1:]) > 0.01  # there was something to restart
    assert abs(float(state.info["feedback_integral"])) > 0.01
