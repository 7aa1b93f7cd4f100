"""``mecanum-eval --play``: a trained policy played with fields of its task changed (a
probe), on top of a model's own ``played_with``; the config.json check skips only them."""

from __future__ import annotations

import pytest

from mecanum_jax.config import ConfigError
from mecanum_jax.task.config import EnvConfig, changed_env
from train.cli.eval_args import play_changes
from train.cli.eval_target import check_config_task
from train.cli.paths import shipped_dir
from train.learner.policy import restore_policy

MODEL = shipped_dir() / "o_rectangle"


def test_items_are_read_as_toml_values():
    changes = play_changes(("residual_deadband=0.02", "symmetric=true", "feedback.hold_s=1"))
    assert changes == {"residual_deadband": 0.02, "symmetric": True, "feedback.hold_s": 1}


def test_a_sections_field_changes_alone():
    env = changed_env(EnvConfig(), {"feedback.margin": 0.1}, "--play")
    assert env.feedback.margin == 0.1
    assert env.feedback.hold_s == EnvConfig().feedback.hold_s
    with pytest.raises(ConfigError, match=r"--play.robot.x = 1: 'robot' is not a section"):
        changed_env(EnvConfig(), {"robot.x": 1}, "--play")


def test_the_restored_policy_plays_the_changed_task():
    shipped = restore_policy(MODEL)
    assert shipped.cfg.env.residual_deadband == 0.02  # as it was trained
    probed = restore_policy(MODEL, play={"residual_deadband": 0.03, "feedback.margin": 0.1})
    assert probed.cfg.env.residual_deadband == 0.03
    assert probed.cfg.env.feedback.margin == 0.1
    assert probed.cfg.env.feedback.hold_s == shipped.cfg.env.feedback.hold_s
    check_config_task(probed, ignore=("residual_deadband", "feedback.margin"))
    with pytest.raises(ConfigError, match=r"env.feedback.margin = 0.05 \(trained: 0.1\)"):
        check_config_task(probed, ignore=("residual_deadband",))
