"""The residual's state-dependent authority (mecanum_jax.task.authority): its config, the
gate and the averaged slip signals on hand values, and the bound in the environment."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax.config import ConfigError
from mecanum_jax.task import EnvConfig, FeedbackConfig, MecanumEnv
from mecanum_jax.task import authority as auth
from mecanum_jax.task import observations as obs_
from mecanum_jax.task.authority import AuthorityConfig

SLIP = AuthorityConfig(mode="slip")
TWIST = EnvConfig(residual_space="twist", residual_base="feedback")


@pytest.mark.parametrize(
    ("cfg", "message"),
    [
        (
            EnvConfig(authority=AuthorityConfig(mode="sometimes")),
            r"env\.authority\.mode = 'sometimes'",
        ),
        (EnvConfig(authority=AuthorityConfig(tau=0.0)), r"env\.authority\.tau = 0\.0: must be > 0"),
        (EnvConfig(authority=AuthorityConfig(yaw_slip=-1.0)), r"env\.authority\.yaw_slip = -1\.0"),
        (EnvConfig(authority=AuthorityConfig(floor=-0.1)), r"env\.authority\.floor = -0\.1"),
        (
            EnvConfig(residual_scale=0.1, authority=AuthorityConfig(mode="slip", floor=0.2)),
            r"env\.authority\.floor = 0\.2: must be <= residual_scale = 0\.1",
        ),
        (
            EnvConfig(residual=False, authority=SLIP),
            r"env\.authority\.mode = 'slip': needs residual = true",
        ),
    ],
)
def test_bad_authority_values_name_the_field(cfg, message):
    with pytest.raises(ConfigError, match=message):
        cfg.validate()


def test_the_gate_is_the_larger_signal_relative_to_its_threshold():
    cfg = AuthorityConfig(mode="slip", yaw_slip=0.2, servo_error=0.1)
    info = {"authority_yaw": jnp.asarray(-0.05), "authority_servo": jnp.asarray([0.02, -0.02])}
    assert float(auth.gate(cfg, info)) == pytest.approx(0.25)  # yaw 0.05/0.2 > servo 0.2
    info["authority_servo"] = jnp.asarray([0.06, -0.04])  # mean |.| 0.05: 0.5
    assert float(auth.gate(cfg, info)) == pytest.approx(0.5)
    info["authority_yaw"] = jnp.asarray(1.0)
    assert float(auth.gate(cfg, info)) == 1.0  # clipped
    floor = dataclasses.replace(cfg, floor=0.02)
    assert float(auth.bound(floor, 0.1, jnp.asarray(0.0))) == pytest.approx(0.02)
    assert float(auth.bound(floor, 0.1, jnp.asarray(0.5))) == pytest.approx(0.06)
    assert float(auth.bound(floor, 0.1, jnp.asarray(1.0))) == pytest.approx(0.1)


def test_the_averages_follow_the_observed_frame_and_the_setpoints():
    env = MecanumEnv(EnvConfig(authority=SLIP))
    c, n, dt, tau = env.constants, env.n_wheels, 0.02, 0.5
    cfg = dataclasses.replace(SLIP, tau=tau)
    # a frame: wheel rates at half their max, gyro 0.3 rad/s, odometry ωz 0.1 rad/s
    frame = np.zeros(env.sensor_size, np.float32)
    frame[:n] = 0.5
    frame[n] = 0.3 / float(c.command_scale[2])
    frame[n + 6] = 0.1 / float(c.command_scale[2])
    setpoints = 0.7 * np.asarray(c.max_rates)  # the servos lag by 0.2 of max
    info = {"authority_yaw": jnp.asarray(0.1), "authority_servo": jnp.full(n, -0.1)}
    out = auth.update(c, cfg, dt, info, jnp.asarray(frame), jnp.asarray(setpoints))
    a = np.exp(-dt / tau)
    np.testing.assert_allclose(out["authority_yaw"], a * 0.1 + (1 - a) * 0.2, rtol=1e-5)
    np.testing.assert_allclose(out["authority_servo"], a * -0.1 + (1 - a) * 0.2, rtol=1e-5)
    assert set(auth.initial(n)) == set(out)


def test_constant_mode_keeps_the_layout():
    slip = MecanumEnv(dataclasses.replace(TWIST, authority=SLIP))
    plain = MecanumEnv(TWIST)
    assert "authority" not in dict(plain.layout)
    assert [e for e in slip.layout if e[0] != "authority"] == list(plain.layout)
    assert slip.observation_size["state"][0] == plain.observation_size["state"][0] + 1
    assert plain.observation_size["state"][0] == sum(s for _, s in plain.layout)


@pytest.mark.parametrize("space", ["wheel", "twist"])
def test_a_floor_at_the_full_scale_is_the_constant_bound(space):
    base = dataclasses.replace(TWIST, residual_space=space)
    plain = MecanumEnv(base)
    full = MecanumEnv(
        dataclasses.replace(base, authority=dataclasses.replace(SLIP, floor=base.residual_scale))
    )
    state = full.reset(jax.random.PRNGKey(0))
    info = dict(state.info, authority_yaw=jnp.asarray(0.03))  # a gate between 0 and 1
    assert 0 < float(auth.gate(full.config.authority, info)) < 1
    cmd = jnp.asarray([0.3, -0.2, 0.8])
    action = jnp.linspace(-1.0, 1.0, plain.action_size)
    np.testing.assert_array_equal(
        full.wheel_setpoints(cmd, action, info), plain.wheel_setpoints(cmd, action, info)
    )
    # and a lower floor scales the correction down, not the base
    low = MecanumEnv(dataclasses.replace(base, authority=SLIP))
    zero = jnp.zeros(plain.action_size)
    np.testing.assert_array_equal(
        low.wheel_setpoints(cmd, zero, info), plain.wheel_setpoints(cmd, zero, info)
    )
    g = float(auth.gate(SLIP, info))
    bound = SLIP.floor + (base.residual_scale - SLIP.floor) * g
    np.testing.assert_allclose(
        low.wheel_setpoints(cmd, action, info) - low.wheel_setpoints(cmd, zero, info),
        (plain.wheel_setpoints(cmd, action, info) - plain.wheel_setpoints(cmd, zero, info))
        * bound
        / base.residual_scale,
        atol=1e-4,
    )


def test_the_gate_stays_small_on_the_nominal_robot_and_opens_on_a_slipping_spin():
    """Zero action (the feedback controller) on the nominal robot going straight within
    reach, and on a robot on a slippery floor commanded a fast spin; one compiled step."""
    env = MecanumEnv(dataclasses.replace(TWIST, authority=SLIP).nominal())
    nominal = env.nominal_params
    slippery = nominal._replace(friction=jnp.full_like(nominal.friction, 0.1))
    scale = env.command_scale
    robots = [
        (nominal, jnp.asarray([0.5, 0.0, 0.0]) * scale),
        (slippery, jnp.asarray([0.0, 0.0, 0.7]) * scale),
    ]
    states = []
    for params, cmd in robots:
        s = env.reset_to(jax.random.PRNGKey(1), params, jnp.asarray(0), env.noise_std())
        states.append(env.set_command(s, cmd))
    state = jax.tree.map(lambda *x: jnp.stack(x), *states)
    step = jax.jit(jax.vmap(env.step))
    zero = jnp.zeros((2, env.action_size))
    start = obs_.entry_start(env.layout, "authority")
    gates = []
    for _ in range(40):
        state = step(state, zero)
        gates.append(np.asarray(state.obs["state"][:, start]))
    gates = np.stack(gates)
    observed = jax.vmap(lambda info: auth.gate(env.config.authority, info))(state.info)
    np.testing.assert_allclose(gates[-1], observed, rtol=1e-6)  # what the policy observes
    # the nominal robot: the start's transient only (about 0.18 at 0.2 s), then it fades
    assert gates[:, 0].max() < 0.25, gates[:, 0]
    assert gates[-1, 0] < 0.1, gates[:, 0]
    assert gates[-1, 1] > 0.8, gates[:, 1]


def test_export_rejects_a_slip_scheduled_policy():
    """The deployed loop does not compute the slip signals: such a policy is not exported."""
    from types import SimpleNamespace

    from train.cli.export import check_exportable
    from train.store.checkpoint import CheckpointError

    cfg = SimpleNamespace(network=SimpleNamespace(teacher=False), env=EnvConfig(authority=SLIP))
    with pytest.raises(CheckpointError, match=r"env\.authority\.mode = 'slip'"):
        check_exportable(SimpleNamespace(cfg=cfg, run_dir="runs/x"))
    cfg.env = EnvConfig()
    check_exportable(SimpleNamespace(cfg=cfg, run_dir="runs/x"))  # constant: exported


def test_export_rejects_a_policy_held_off_in_transients():
    """The deployed loop does not hold the correction off after changes: not exported."""
    from types import SimpleNamespace

    from train.cli.export import check_exportable
    from train.store.checkpoint import CheckpointError

    env = EnvConfig(residual_in_transient=False, feedback=FeedbackConfig(hold_s=0.4))
    cfg = SimpleNamespace(network=SimpleNamespace(teacher=False), env=env)
    with pytest.raises(CheckpointError, match=r"env\.residual_in_transient = false"):
        check_exportable(SimpleNamespace(cfg=cfg, run_dir="runs/x"))
