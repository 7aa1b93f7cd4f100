"""The environment's config: a bad one is refused naming the field, and one is checked once."""

import dataclasses

import pytest
from tasks import WHEEL

from mecanum_jax.config import ConfigError, from_mapping
from mecanum_jax.task import EnvConfig, MecanumEnv


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"randomization": {"nominal_share": 1.5}}, "env.randomization.nominal_share = 1.5"),
        ({"control_dt": 0.021}, "env.control_dt = 0.021"),
        ({"episode_length": 0}, "env.episode_length = 0"),
        ({"randomization": {"friction": [1.0, 0.5]}}, "env.randomization.friction"),
        ({"randomization": {"friction": [0.0, 0.5]}}, "must be > 0"),
        ({"commands": {"p_zero": -1}}, "env.commands.p_zero = -1"),
        ({"reward": {"sigma_lin": 0}}, "env.reward.sigma_lin = 0"),
        ({"reward": {"energy": -1}}, "env.reward.energy = -1"),
        ({"reward": {"target": "goal"}}, "env.reward.target = 'goal'"),
        ({"robot": "no_such_robot"}, "env.robot = 'no_such_robot'"),
        ({"noise": {"gyro": "big"}}, "env.noise.gyro = 'big'"),
        ({"action_filter": 1.0}, "env.action_filter = 1.0"),
        ({"action_filter": -0.1}, "env.action_filter = -0.1"),
        ({"residual_scale": 1e9}, "env.residual_scale = 1000000000.0: must be in"),
        ({"residual_scale": 0.0}, "env.residual_scale = 0.0: must be in"),
        ({"physics_timestep": 1e-7}, "env.physics_timestep = 1e-07: 200000 physics steps"),
        ({"control_dt": 100.0}, "env.physics_timestep = 0.005: 20000 physics steps"),
        ({"colour": "red"}, "env.colour = 'red': unknown key"),
        (
            {"robot": "centripetal3", "symmetric": True},
            "env.symmetric = True: robot 'centripetal3' is not mirror-symmetric",
        ),
    ],
)
def test_bad_env_config_names_field(table, message):
    with pytest.raises(ConfigError, match=message.replace(".", r"\.").replace("[", r"\[")):
        from_mapping(EnvConfig, table, "env").validate()


def test_a_mirror_averaged_policy_takes_every_mirror_symmetric_layout():
    """O and X layouts, rectangular or square (the X-square rank-deficient), have the mirror
    group; centripetal3 and custom_six are refused above, before anything is built."""
    for robot in ("o_rectangle", "o_square", "x_rectangle", "x_square"):
        EnvConfig(robot=robot, symmetric=True).validate()


def test_twist_residual_needs_residual_actions():
    with pytest.raises(ConfigError, match=r"env\.residual_space"):
        EnvConfig(residual=False, residual_space="twist").validate()
    with pytest.raises(ConfigError, match=r"env\.residual_space = 'joint'"):
        EnvConfig(residual_space="joint").validate()


def test_direct_rates_on_the_defaults_name_every_residual_setting_at_once():
    """The defaults are a twist residual on feedback: residual = false alone is refused
    with every setting it must also turn back, not one per attempt; the plain direct task
    validates."""
    with pytest.raises(ConfigError) as err:
        EnvConfig(residual=False).validate()
    message = str(err.value)
    assert message.startswith("env.residual_space = 'twist': needs residual = true")
    assert "residual_deadband = 0.02" in message
    assert "residual_base = 'feedback'" in message
    EnvConfig(**{**WHEEL, "residual": False}).validate()


def test_a_config_is_validated_once(monkeypatch):
    """The layers a config passes through each ask for it to be valid; it is checked once.
    A changed copy is checked anew, and a bad config is refused at every ask."""
    checks = []
    real = EnvConfig._validate_timing
    monkeypatch.setattr(
        EnvConfig, "_validate_timing", lambda self, where: checks.append(1) or real(self, where)
    )
    cfg = EnvConfig(obs_history=2)
    assert cfg.validate() is cfg
    assert cfg.validate("elsewhere") is cfg
    assert len(checks) == 1
    dataclasses.replace(cfg, obs_history=3).validate()
    assert len(checks) == 2
    bad = EnvConfig(residual_space="joint")
    for _ in range(2):
        with pytest.raises(ConfigError, match=r"env\.residual_space = 'joint'"):
            MecanumEnv(bad)
